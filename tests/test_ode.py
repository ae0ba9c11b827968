"""Continuous-time models sampled by System.from_ode."""

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from uiest import Box, ModelError, OptionError, System
from uiest.ode import input_integral


def _pendulum(**kwargs):
    def rhs(x, u, w):
        return [x[1], -9.81 * np.sin(x[0]) - 0.5 * x[1] + u[0] + w[0]]

    spec = {"x_bounds": ((-1.0, -3.0), (1.0, 3.0)), "u_bounds": (-1.0, 1.0), "v_bounds": (-1e-3, 1e-3)}
    return System.from_ode(rhs, lambda x, v: [x[0] + v[0]], nx=2, nu=1, nw=1, nv=1, **{**spec, **kwargs})


def _fine_flow(x, u, w, dt, steps=2000):
    """Zero-order-hold flow by many small RK4 steps (the reference)."""
    system = _pendulum(dt=dt / steps, input_channel="rk4")
    for _ in range(steps):
        x = system.step(x, u, w)
    return x


def test_linear_model_with_an_input_channel_is_sampled_exactly():
    A = np.array([[0.0, 1.0], [-2.0, -0.3]])
    G = np.array([[0.0], [1.0]])
    system = System.from_ode(lambda x, u, w: A @ x + G @ w, lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1, dt=0.1,
                             substeps=4, x_bounds=(-1.0, 1.0))  # fmt: skip
    lin = system.linearize(np.zeros(2))
    np.testing.assert_allclose(lin.B_w, input_integral(A, G, 0.1), rtol=1e-12)
    np.testing.assert_allclose(lin.B_w[:, 0], [0.1**2 / 2, 0.1], rtol=0.02)
    assert system.dt == 0.1


def test_input_channel_error_is_linear_in_w_and_of_order_dt_cubed_when_the_channel_column_is_constant():
    x, u = np.array([0.8, 2.0]), np.array([0.3])
    errors = {}
    for dt in (0.04, 0.02):
        for w in (1.0, 10.0):
            sampled = _pendulum(dt=dt).step(x, u, [w])
            errors[dt, w] = np.linalg.norm(sampled - _fine_flow(x, u, [w], dt))
    # linear in |w|; here (A(x) - A_ref) G = 0 (w drives the velocity, whose column of A is constant), so the
    # dt^2 term of the documented error vanishes and the dt^3 term, ~ dt^3 / 6 |A|^2 |G w|, is what is left
    assert errors[0.04, 10.0] / errors[0.04, 1.0] == pytest.approx(10.0, rel=0.2)
    assert errors[0.04, 10.0] / errors[0.02, 10.0] == pytest.approx(8.0, rel=0.2)
    assert errors[0.04, 10.0] < 0.04**3 / 6 * 10.0**2 * 10.0


def test_rk4_channel_keeps_w_inside_the_stages_and_bad_options_are_refused():
    x, u, w = np.array([0.8, 2.0]), np.array([0.3]), np.array([10.0])
    assert np.linalg.norm(_pendulum(dt=0.04, input_channel="rk4").step(x, u, w) - _fine_flow(x, u, w, 0.04)) < 1e-6
    with pytest.raises(OptionError, match="input_channel"):
        _pendulum(dt=0.1, input_channel="euler")
    with pytest.raises(OptionError, match="substeps"):
        _pendulum(dt=0.1, substeps=0)
    with pytest.raises(ModelError, match="dt"):
        _pendulum(dt=-1.0)
    with pytest.raises(ModelError, match="constant G"):
        System.from_ode(lambda x, u, w: [x[0] * w[0]], lambda x, v: [x[0] + v[0]], nx=1, nw=1, nv=1, dt=0.1,
                        input_channel="integral")  # fmt: skip


def test_rk4_sampling_matches_solve_ivp_over_a_horizon():
    # the reactor of examples/reactor.py with u and w held per sample, 100 samples: RK4 with 10 substeps
    # against scipy's adaptive solver at tight tolerances
    from scipy.integrate import solve_ivp

    from uiest.models import load

    entry = load(Path(__file__).resolve().parents[1] / "examples" / "reactor.py")
    system, module = entry.build(), sys.modules["uiest_user_model_reactor"]
    fine = System.from_ode(module.rhs, lambda x, v: [x[1] + v[0]], nx=2, nu=1, nw=1, nv=1, dt=system.dt, substeps=10,
                           input_channel="rk4", x_bounds=system.x.bounds)  # fmt: skip
    x = np.array([0.6696, 1.0826])
    sampled, reference = x.copy(), x.copy()
    for k in range(100):
        u, w = np.array([0.2 * (k >= 50)]), np.array([-0.25 * np.sin(0.1 * k)])
        sampled = fine.step(sampled, u, w)
        flow = solve_ivp(lambda t, z, u=u, w=w: module.rhs(z, u, w), (0.0, system.dt), reference, rtol=1e-12,
                         atol=1e-14)  # fmt: skip
        reference = flow.y[:, -1]
        np.testing.assert_allclose(sampled, reference, rtol=1e-8)


def test_collocation_is_stable_on_a_stiff_model_where_rk4_is_not():
    import scipy.linalg

    A = np.array([[-1000.0, 0.0], [1.0, -1.0]])  # a fast mode at -1000 and a slow one at -1

    def build(method):
        return System.from_ode(lambda x, u, w: A @ x + np.array([[1.0], [0.0]]) @ w, lambda x, v: [x[1] + v[0]],
                               nx=2, nw=1, nv=1, dt=0.1, method=method, x_bounds=(-10, 10))  # fmt: skip

    exact = scipy.linalg.expm(A * 0.1)
    x_rk4 = x_col = x_exact = np.array([1.0, 1.0])
    with pytest.warns(UserWarning, match=r"from_ode: RK4 with step 0.1 grows where the ODE decays: .* h lambda = -100"):
        rk4 = build("rk4")
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)  # L-stable: nothing to warn about
        collocation = build("collocation")
    for _ in range(20):
        x_rk4, x_col, x_exact = rk4.step(x_rk4, None, [0.0]), collocation.step(x_col, None, [0.0]), exact @ x_exact
    assert abs(x_rk4[0]) > 1e100  # RK4 at dt = 0.1 is far outside its stability region for -1000
    np.testing.assert_allclose(x_col, x_exact, rtol=1e-3, atol=1e-12)
    with pytest.raises(OptionError, match="method"):
        build("euler")


def test_collocation_matches_solve_ivp_on_the_nonlinear_reactor():
    from scipy.integrate import solve_ivp

    from uiest.models import load

    entry = load(Path(__file__).resolve().parents[1] / "examples" / "reactor.py")
    module = sys.modules["uiest_user_model_reactor"]
    system = entry.build()
    options = {"substeps": 4, "method": "collocation", "input_channel": "rk4", "x_bounds": system.x.bounds}
    colloc = System.from_ode(module.rhs, lambda x, v: [x[1] + v[0]], nx=2, nu=1, nw=1, nv=1, dt=system.dt, **options)
    x = reference = np.array([0.6696, 1.0826])
    for k in range(40):
        u, w = np.array([0.2 * (k >= 20)]), np.array([-0.25])
        x = colloc.step(x, u, w)
        flow = solve_ivp(lambda t, z, u=u, w=w: module.rhs(z, u, w), (0.0, system.dt), reference, rtol=1e-12,
                         atol=1e-14)  # fmt: skip
        reference = flow.y[:, -1]
    np.testing.assert_allclose(x, reference, rtol=1e-6)


def test_an_input_integral_that_varies_over_x_puts_w_inside_the_integrator_unless_asked_to_keep_it():
    # dx/dt = (x0 x1, w - x1): Gamma = int exp(A s) ds G, A = [[x1, x0], [0, -1]], is (0, 0.095) at X's centre and
    # grows without bound towards x1 = 100 (exp(10)): the integral channel fixed at the centre misstates w's effect
    def rhs(x, u, w):
        return [x[0] * x[1], w[0] - x[1]]

    def sampled(**options):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            system = System.from_ode(rhs, lambda x, v: [x[1] + v[0]], nx=2, nw=1, nv=1, dt=0.1,
                                     x_bounds=(-100.0, 100.0), v_bounds=(-0.01, 0.01), **options)  # fmt: skip
        return system, [str(c.message) for c in caught if "per-sample integral" in str(c.message)]

    from scipy.integrate import solve_ivp

    chosen, (said,) = sampled()
    assert chosen.sampled_from.input_channel == "rk4" and "so w enters inside the integrator" in said  # spread >> 1
    x, w = np.array([2.0, 5.0]), np.array([1.0])  # away from X's centre: w's effect as the ODE's, not the centre's
    flow = solve_ivp(lambda t, z: rhs(z, None, w), (0.0, 0.1), x, rtol=1e-12, atol=1e-12).y[:, -1]
    rest = solve_ivp(lambda t, z: rhs(z, None, [0.0]), (0.0, 0.1), x, rtol=1e-12, atol=1e-12).y[:, -1]
    effect = chosen.step(x, None, w) - chosen.step(x, None, [0.0])
    np.testing.assert_allclose(effect, flow - rest, rtol=0.02)
    kept, (said,) = sampled(input_channel="integral")
    assert kept.sampled_from.input_channel == "integral" and "input_channel='rk4' keeps w inside" in said
    assert not sampled(input_channel="rk4")[1]


def _runaway_cstr(**options):
    """Seborg's exothermic CSTR (minutes, mol/L, K) over a wide domain: thermal runaway at high T and C_A."""

    def rhs(x, u, w):
        rate = 7.2e10 * np.exp(-8750.0 / x[1]) * x[0]
        return [1.0 - x[0] - rate, 350.0 - x[1] + 209.2 * rate + 2.092 * (u[0] + w[0] - x[1])]

    spec = {"x_bounds": Box(lower=(0.0, 300.0), upper=(10.0, 500.0)), "u_bounds": (280.0, 320.0),
            "v_bounds": (-0.1, 0.1), "dt": 0.05}  # fmt: skip
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        System.from_ode(rhs, lambda x, v: [x[1] + v[0]], nx=2, nu=1, nw=1, nv=1, **{**spec, **options})
    return [str(c.message) for c in caught]


def test_collocation_whose_newton_iterations_do_not_converge_somewhere_in_x_is_warned_of():
    # at (C_A, T) = (5, 400) the reaction runs away within a sample: six Newton iterations from zero stage
    # derivatives leave the stage equations unsolved (the sampled step gave T = 714 K where the flow reaches 1295 K)
    said = [m for m in _runaway_cstr(method="collocation", input_channel="rk4") if "Newton" in m]
    assert len(said) == 1 and "leave its stage equations unsolved at x = [" in said[0] and "more substeps" in said[0]
    # where they converge (the same reactor away from the runaway: C_A <= 1, T <= 330 K) it is silent
    mild = Box(lower=(0.0, 300.0), upper=(1.0, 330.0))
    assert not [m for m in _runaway_cstr(method="collocation", input_channel="rk4", x_bounds=mild) if "Newton" in m]


def test_an_input_integral_that_overflows_in_x_is_warned_of_not_raised():
    # over the runaway region exp(A dt) overflows: the spread was a numpy LinAlgError ("SVD did not converge")
    said = [m for m in _runaway_cstr(method="collocation") if "per-sample integral" in m]
    assert len(said) == 1 and "more than doubles can hold" in said[0]


def test_the_collocation_check_does_not_depend_on_the_states_units():
    # dx/dt = -100 x^3 / s^2 over X = [-s, s], one step of 1: the Newton iterations stall (the step lands at -0.25 s
    # where the flow reaches 0.07 s) in whatever unit s the state is written
    def said(s):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            spec = {"x_bounds": (-s, s), "v_bounds": (-0.01 * s, 0.01 * s), "dt": 1.0, "method": "collocation"}
            System.from_ode(lambda x, u, w: [-(100.0 / s**2) * x[0] ** 3 + w[0]], lambda x, v: [x[0] + v[0]], nx=1,
                            nw=1, nv=1, **spec)  # fmt: skip
        return [str(c.message).split(" (")[1].split(",")[0] for c in caught if "Newton" in str(c.message)]

    assert said(1.0) == said(1e-7) == ["their residual times the step 0.63 of X's width"]
