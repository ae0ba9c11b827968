"""uiest.analyse on models written for it: mechanical (sampling zeros), process, linear with known zeros, delayed."""

import json
import runpy
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
from typer.testing import CliRunner

import uiest
from uiest import DataError, OptionError, System, simulate
from uiest.analysis import Cause, Recommendation, analyse
from uiest.analysis.points import euler_frobenius_roots
from uiest.cli import app
from uiest.models.linear import with_invariant_zeros

ROOT = Path(__file__).resolve().parents[1]
NOISE = 1e-3


def pendulum() -> System:
    """examples/pendulum.py: a damped pendulum with an unknown torque, the angle measured (RK4, dt = 0.05)."""
    return runpy.run_path(str(ROOT / "examples" / "pendulum.py"))["system"]


def two_masses() -> System:
    """Two masses on springs, both positions measured, an unknown force on mass 1 (dt = 0.04)."""
    m1, m2, k1, k2, k12, c = 1.0, 0.5, 1.0, 1.0, 50.0, 0.2

    def rhs(x, u, w):
        q1, q2, p1, p2 = x
        return [p1, p2, (-k1 * q1 - k12 * (q1 - q2) - c * p1 + w[0]) / m1, (-k2 * q2 + k12 * (q1 - q2) - c * p2) / m2]

    return System.from_ode(
        rhs, lambda x, v: [x[0] + v[0], x[1] + v[1]], nx=4, nw=1, nv=2, dt=0.04,
        x_bounds=((-1, -1, -5, -5), (1, 1, 5, 5)), v_bounds=(-NOISE, NOISE), x_names=("q1", "q2", "p1", "p2"),
        w_names=("force",), y_names=("q1_measured", "q2_measured"), name="two masses",
    )  # fmt: skip


def cart() -> System:
    """A cart with friction pushed by an unknown force, its position measured (dt = 0.1)."""
    return System.from_ode(
        lambda x, u, w: [x[1], -0.5 * x[1] + w[0]], lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1, dt=0.1,
        x_bounds=((-10, -5), (10, 5)), v_bounds=(-1e-2, 1e-2), x_names=("position", "speed"), name="cart",
    )  # fmt: skip


G, AREA, OUTLET = 981.0, (28.0, 32.0, 28.0, 32.0), (0.071, 0.057, 0.071, 0.057)
PUMP, SPLIT = (3.33, 3.35), (0.7, 0.6)


def quadruple_tank(*, upper: bool, dt: float, lower: tuple[float, ...] = (4, 4, 1, 1)) -> System:
    """Johansson's quadruple tank (cm, s); unknown inflows into the lower (measured) or the upper tanks."""

    def rhs(x, u, w):
        q = [OUTLET[i] * np.sqrt(2 * G * x[i]) for i in range(4)]
        pumps = [SPLIT[0] * PUMP[0] * u[0], SPLIT[1] * PUMP[1] * u[1], (1 - SPLIT[1]) * PUMP[1] * u[1],
                 (1 - SPLIT[0]) * PUMP[0] * u[0]]  # fmt: skip
        d = [0, 0, w[0], w[1]] if upper else [w[0], w[1], 0, 0]
        return [(-q[0] + q[2] + pumps[0] + d[0]) / AREA[0], (-q[1] + q[3] + pumps[1] + d[1]) / AREA[1],
                (-q[2] + pumps[2] + d[2]) / AREA[2], (-q[3] + pumps[3] + d[3]) / AREA[3]]  # fmt: skip

    return System.from_ode(
        rhs, lambda x, v: [x[0] + v[0], x[1] + v[1]], nx=4, nu=2, nw=2, nv=2, dt=dt,
        x_bounds=(lower, (20, 20, 6, 6)), u_bounds=((2.5, 2.5), (3.5, 3.5)), v_bounds=(-0.05, 0.05),
        x_names=("h1", "h2", "h3", "h4"), x_units=("cm",) * 4, name="quadruple tank",
    )  # fmt: skip


def reactor() -> System:
    return runpy.run_path(str(ROOT / "examples" / "reactor.py"))["system"]


def relative_degree_two() -> System:
    """w moves x1, which reaches the measured x2 one step later (matching fails)."""

    def f(x, u, w):
        return [x[0] + w[0], x[0] + 0.3 * ca.sin(x[2]), (0.5 + 0.3 * ca.tanh(x[1])) * x[2] + u[0]]

    return System.from_callables(f, lambda x, v: [x[1] + v[0]], nx=3, nu=1, nw=1, nv=1, x_bounds=(-5, 5),
                                 u_bounds=(-1, 1), v_bounds=(-1e-3, 1e-3), name="relative degree 2")  # fmt: skip


def linear(zeros, **keywords) -> System:
    return with_invariant_zeros(zeros, x_bounds=(-10, 10), v_bounds=(-NOISE, NOISE), seed=3, **keywords)[0]


@pytest.fixture(scope="module")
def analysed():
    """Each model's analysis, made once."""
    cache = {}

    def get(name, **keywords):
        key = (name, tuple(sorted(keywords.items())))
        if key not in cache:
            builders = {"pendulum": pendulum, "two masses": two_masses, "cart": cart, "reactor": reactor,
                        "tank": lambda: quadruple_tank(upper=False, dt=1.0),
                        "upper tank": lambda: quadruple_tank(upper=True, dt=2.0),
                        "relative degree 2": relative_degree_two}  # fmt: skip
            cache[key] = analyse(builders[name](), **keywords)
        return cache[key]

    return get


def second_order_zero(system: System) -> float:
    """The zero of a 2-state SISO channel y = x1 from its Jacobians: ``b1 (z - a22) + a12 b2 = 0``."""
    lin = system.linearize(system.x.bounds.center)
    (_, a12), (_, a22) = lin.A
    b1, b2 = lin.B_w[:, 0]
    return a22 - a12 * b2 / b1


def hidden_ratio(system: System, z: complex, state: int) -> float:
    """|x_state| / |C x / eps| for x = (zI - A)^-1 B at X's centre (one unknown input)."""
    lin = system.linearize(system.x.bounds.center)
    x = np.linalg.solve(z * np.eye(system.nx) - lin.A, lin.B_w[:, 0])
    eps = 0.5 * system.v.bounds.width
    return float(abs(x[state]) / np.linalg.norm((lin.C @ x) / eps))


# ---------------------------------------------------------------------------------------------- mechanical
def test_pendulum_sampling_zero_is_named_and_a_smooth_input_estimator_recommended(analysed):
    a = analysed("pendulum")
    system = pendulum()
    assert a.matching and a.steps == (1,) and a.continuous_degree == (2,)
    (zero,) = a.zeros.reference
    assert zero.value.imag == 0 and zero.value.real == pytest.approx(second_order_zero(system), abs=1e-9)
    assert -1.0 < zero.value.real < -0.99 and zero.from_sampling
    (channel,) = a.zeros.channels
    assert channel.continuous_degree == 2 and channel.zeros[0].limit == pytest.approx(-1.0)
    # the smallest certified rate is the known answer |z|^2 (matching holds)
    assert a.strong.certified and a.strong.certificate.rate_min == pytest.approx(zero.modulus**2, abs=2e-3)
    assert a.strong.min_horizon > 60 and not a.strong.guarantee.applies
    assert a.recommendation is Recommendation.SMOOTH_INPUT_MHE and a.cause is Cause.WINDOW_TOO_LONG
    # near z = -1 the torque hides the rate: more than X's width for an angle noise of 1e-3
    assert abs(a.near_zeros.unit_circle.z + 1) < 1e-6 and a.near_zeros.unit_circle.sigma < 1e-4
    assert a.near_zeros.error_floor[1] > 12.0 and a.near_zeros.error_floor[0] == pytest.approx(NOISE)
    assert a.near_zeros.error_floor[1] >= hidden_ratio(system, -1.0, 1) * (1 - 1e-9)
    for words in (f"{zero.value.real:.4g}", "created by sampling", "alternating every sample", "rate by", "smooth"):
        assert words in a.reason


def test_pendulum_floor_at_the_reference_point_alone_is_the_transfer_ratio_and_the_nonlinear_model_hides_it():
    system = pendulum()
    a = analyse(system, points=1)
    floor = hidden_ratio(system, -1.0, 1)
    assert a.near_zeros.error_floor[1] == pytest.approx(floor, rel=1e-6)
    # the sampled nonlinear model: a torque alternating every sample moves the rate by +-2 rad/s while the angle
    # moves by 2 / floor * 1e-3 rad, below the angle noise
    lin = system.linearize(system.x.bounds.center)
    xi = np.linalg.solve(-np.eye(2) - lin.A, lin.B_w[:, 0])
    scale = 2.0 / abs(xi[1])
    record = simulate(system, scale * xi, 200, w=lambda k, x: [scale * (-1.0) ** k])
    assert np.abs(record.x[:, 1]).min() > 1.9 and np.abs(record.x[:, 0]).max() < NOISE


def test_two_masses_without_an_exact_zero_still_name_the_channel_sampling_zero(analysed):
    a = analysed("two masses")
    assert a.zeros.reference == ()  # two outputs: no exact invariant zero
    q1, q2 = a.zeros.channels
    assert q1.continuous_degree == 2 and q2.continuous_degree == 4
    sampled = [z for z in q1.zeros if z.from_sampling]
    assert len(sampled) == 1 and -1.0 < sampled[0].value.real < -0.99 and sampled[0].limit == pytest.approx(-1)
    assert sum(not z.from_sampling for z in q1.zeros) == 2  # images of the continuous zeros -0.1 +- 7.1j
    np.testing.assert_allclose(sorted(z.value.real for z in q2.zeros), euler_frobenius_roots(4), atol=0.2)
    assert all(z.from_sampling for z in q2.zeros)
    assert abs(a.near_zeros.unit_circle.z + 1) < 1e-6 and a.near_zeros.unit_circle.sigma < 1e-4
    assert a.near_zeros.error_floor[2] > 10.0  # p1, beyond X's width
    assert a.near_zeros.error_floor[2] >= hidden_ratio(two_masses(), -1.0, 2) * (1 - 1e-9)
    # certified, but the certificate's weights span 3e13 (prior against output, scaled): the window is capped at its
    # information horizon, shorter than min_horizon(), so Theorem 3.6 does not apply to the window used
    guarantee = a.strong.guarantee
    assert a.strong.certified and guarantee.capped and not guarantee.applies
    assert guarantee.horizon is not None and guarantee.horizon < a.strong.certificate.min_horizon()
    assert a.recommendation is Recommendation.SMOOTH_INPUT_MHE and a.cause is Cause.BEYOND_INFORMATION_HORIZON
    assert f"its window 24 is longer than its weights' information horizon {guarantee.horizon}" in a.reason
    assert "near-zero" in a.reason and f"{sampled[0].value.real:.4g}" in a.reason and "p1 by" in a.reason


def test_cart_zero_and_a_longer_window_left_vacuous_as_the_floor_implies(analysed):
    a = analysed("cart")
    (zero,) = a.zeros.reference
    assert zero.value.real == pytest.approx(second_order_zero(cart()), abs=1e-9) and zero.from_sampling
    assert a.recommendation is Recommendation.SMOOTH_INPUT_MHE and a.cause is Cause.WINDOW_TOO_LONG
    longer = analysed("cart", max_horizon=80)
    assert longer.strong.N <= 80 and longer.strong.guarantee.applies
    assert longer.cause is Cause.VACUOUS and longer.near_zeros.error_floor[1] > 10.0  # speed: X's width is 10
    assert np.all(longer.strong.guarantee.error_bound >= longer.near_zeros.error_floor)


# ---------------------------------------------------------------------------------------------- process
def test_reactor_certifies_with_an_informative_bound_and_gets_the_uise(analysed):
    a = analysed("reactor")
    assert a.continuous_degree == (1,) and not any(z.from_sampling for z in a.zeros.reference)
    assert a.recommendation is Recommendation.UISE and a.cause is Cause.UISE_INFORMATIVE
    guarantee = a.strong.guarantee
    assert guarantee.informative and a.strong.min_horizon <= a.strong.N <= 60
    # any quadratic certificate's rate is at least max |z|^2 over the linearisations
    assert a.strong.certificate.rate_min >= a.zeros.largest_modulus**2 - 1e-6
    assert np.all(guarantee.error_bound >= a.near_zeros.error_floor)
    assert a.near_zeros.error_floor[1] == pytest.approx(2e-3)  # the measured temperature: its noise
    assert f"N = {a.strong.N}" in a.reason and "informative" in a.reason


def test_quadruple_tank_window_limit_decides_between_uise_and_smooth_input_mhe(analysed):
    a = analysed("tank")
    assert a.zeros.largest_modulus < 1 and not any(z.from_sampling for z in a.zeros.reference)
    assert a.strong.min_horizon > 60 and a.cause is Cause.WINDOW_TOO_LONG
    assert a.recommendation is Recommendation.SMOOTH_INPUT_MHE and "exceeds max_horizon 60" in a.reason
    longer = analysed("tank", max_horizon=80)
    assert longer.recommendation is Recommendation.UISE and longer.strong.guarantee.informative


def test_quadruple_tank_with_inflows_into_the_upper_tanks_has_sampling_zeros(analysed):
    a = analysed("upper tank")
    assert a.continuous_degree == (2, 2) and len(a.zeros.reference) == 2
    assert all(z.from_sampling and abs(z.value + 1) < 0.02 for z in a.zeros.reference)
    # the integral input channel's direction is fixed at X's centre: far from it the sampling zero leaves the disk
    assert a.zeros.largest.from_sampling and a.zeros.largest_modulus > 1
    assert a.cause is Cause.ZERO_OUTSIDE and a.recommendation is Recommendation.SMOOTH_INPUT_MHE
    assert np.all(a.near_zeros.error_floor[2:] > 5.0)  # h3, h4: beyond X's width
    # the linearisation sampled exactly has its zeros inside (the model's fixed input direction moved this one), and
    # a nonlinear model's zero outside denies a certificate, not strong detectability itself
    assert abs(a.zeros.largest.exact) < 1 and not a.linear
    assert "no certificate over X of the kind uiest computes" in a.reason and "sampled exactly" in a.reason


# ---------------------------------------------------------------------------------------------- known answers
def test_linear_zeros_are_exact_and_the_certified_rate_is_their_largest_modulus_squared():
    a = analyse(linear([0.5, 0.2]))
    np.testing.assert_allclose(sorted(z.value.real for z in a.zeros.reference), [0.2, 0.5], atol=1e-9)
    assert all(z.from_sampling is None for z in a.zeros.reference) and a.continuous_degree is None
    assert a.zeros.largest_modulus == pytest.approx(0.5, abs=1e-9)
    assert a.strong.certificate.rate_min == pytest.approx(0.25, abs=1e-3)
    assert a.recommendation is Recommendation.UISE
    ring = a.near_zeros.ring
    assert a.near_zeros.ring_radius == pytest.approx(np.sqrt(a.strong.certificate.rate))
    assert ring.sigma < 0.1 * a.near_zeros.unit_circle.sigma and abs(ring.z - 0.5) < 0.05


def test_linear_zero_outside_and_at_one():
    outside = analyse(linear([1.2, 0.3]))
    assert outside.zeros.largest.value.real == pytest.approx(1.2, abs=1e-9)
    assert outside.cause is Cause.ZERO_OUTSIDE and outside.recommendation is Recommendation.SMOOTH_INPUT_MHE
    at_one = analyse(linear([1.0, 0.5]))
    assert not at_one.random_walk.detectable and at_one.random_walk.mode == pytest.approx(1.0)
    assert at_one.recommendation is Recommendation.EKF_UKF and "not detectable either" in at_one.reason
    assert at_one.cause is Cause.ZERO_OUTSIDE  # its modulus is 1 to rounding: on the circle, not inside it


def test_euler_frobenius_roots():
    np.testing.assert_allclose(euler_frobenius_roots(2), [-1.0])
    np.testing.assert_allclose(euler_frobenius_roots(3), [-2 - np.sqrt(3), -2 + np.sqrt(3)])
    np.testing.assert_allclose(euler_frobenius_roots(4), [-5 - 2 * np.sqrt(6), -1.0, -5 + 2 * np.sqrt(6)], atol=1e-12)


def test_matching_fails_recommends_the_delayed_uise(analysed):
    a = analysed("relative degree 2")
    assert not a.matching and (a.rank_CB, a.rank_B) == (0, 1) and a.steps == (2,)
    assert a.strong.certificate is None and "matching fails" in a.strong.not_applicable
    assert a.delayed.certified and a.delayed.certificate.rate_min == pytest.approx(0.64, abs=1e-3)
    bound = a.delayed.guarantee.error_bound
    assert np.isnan(bound[0]) and np.all(bound[1:] < a.x_width[1:])  # x1 = a, the delayed system's input
    assert a.recommendation is Recommendation.DELAYED_UISE and a.cause is Cause.DELAYED_INFORMATIVE


# ---------------------------------------------------------------------------------------------- API and CLI
def test_system_records_the_continuous_model_it_was_sampled_from():
    system = pendulum()
    assert system.sampled_from.method == "rk4" and system.sampled_from.input_channel == "integral"
    assert system.with_scales(x=[1.0, 2.0]).sampled_from is system.sampled_from
    assert relative_degree_two().sampled_from is None


def test_analysis_is_plain_data_and_refuses_bad_input(analysed):
    a = analysed("pendulum")
    data = json.loads(json.dumps(a.to_dict(), default=float))
    assert data["recommendation"] == "smooth-input MHE" and data["cause"] == "WINDOW_TOO_LONG"
    assert data["zeros"]["reference"][0]["from_sampling"] is True and data["reason"] == a.reason
    assert str(a) == a.text() and a.text().splitlines()[-2] == f"recommended: {a.reason}"
    assert a.cpu_time > 0 and uiest.analyse is analyse
    with pytest.raises(OptionError, match="system"):
        analyse("pendulum")
    with pytest.raises(OptionError, match="max_horizon"):
        analyse(pendulum(), max_horizon=0)
    with pytest.raises(DataError, match="x0"):
        analyse(pendulum(), x0=[0.0])


def _refused(name):
    raise ValueError(f"not JSON: {name}")


def test_json_text_writes_non_finite_numbers_as_null():
    from uiest.json_text import json_text

    text = json_text({"a": [1.0, float("inf"), np.nan], "b": np.array([2.5, -np.inf]), "c": np.float64("nan")})
    assert json.loads(text, parse_constant=_refused) == {"a": [1.0, None, None], "b": [2.5, None], "c": None}


def test_cli_analyse_json_of_an_unbounded_floor_is_json_any_reader_parses(tmp_path):
    # a zero at 1.2: x2's error floor is unbounded and no rate is certified (inf and NaN in the analysis's data)
    model = tmp_path / "zero_outside.py"
    model.write_text(
        "import numpy as np\nfrom uiest.models import linear\n\n\ndef build():\n"
        "    A = np.array([[0.5, 0.1, 0.0], [0.0, 1.2, 0.2], [0.1, 0.0, 0.7]])\n"
        "    return linear.linear_system(A, [[1.0], [0.0], [0.0]], [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],\n"
        "                                x_bounds=(-20, 20), v_bounds=(-0.02, 0.02))\n"
    )
    out = tmp_path / "analysis.json"
    result = CliRunner().invoke(app, ["analyse", str(model), "--json", str(out)])
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text(), parse_constant=_refused)  # no NaN, no Infinity (RFC 8259)
    assert data["near_zeros"]["error_floor"][1] is None  # unbounded


def test_cli_analyse_prints_the_recommendation_and_writes_json(tmp_path):
    runner = CliRunner()
    out = tmp_path / "analysis.json"
    result = runner.invoke(app, ["analyse", str(ROOT / "examples" / "reactor.py"), "--json", str(out)])
    assert result.exit_code == 0, result.output
    assert "recommended: UISE" in result.output
    assert json.loads(out.read_text())["recommendation"] == "UISE"
    bad = runner.invoke(app, ["analyse", "linear-example", "--max-horizon", "0"])
    assert bad.exit_code == 2 and "--max-horizon" in bad.output


def test_the_error_floor_makes_no_claim_where_zi_minus_a_is_singular_to_working_precision():
    # a Jacobian of 1e20 (an explicit integrator where it is unstable): at z = 1 and -1, z I - A rounds to a singular
    # matrix although z is 1 away from A's eigenvalues; the floor once ended the analysis with LinAlgError
    from uiest.analysis.near_zeros import _floor

    z = np.array([1.0, -1.0, 1j])
    floors = _floor(np.full((2, 2), 1e20), np.array([[1.0], [0.0]]), np.array([[1.0, 0.0]]), np.ones(2), z)
    np.testing.assert_array_equal(floors[:2], np.zeros((2, 2)))  # no claim there
    assert np.all(np.isfinite(floors[2])) and np.all(floors[2] > 0)  # the solve at z = i is regular


def test_a_zero_where_the_rk4_step_is_unstable_is_not_attributed_to_sampling():
    # a DC motor whose electrical pole (-1975 / s) RK4 amplifies at dt = 2 ms: the zero at 6.0 comes from the
    # integrator (the exactly sampled motor's is at -0.3); it was once "created by sampling", and so the reason
    def rhs(x, u, w):
        return [(u[0] - x[0] - 0.05 * x[1]) / 0.5e-3, (0.05 * x[0] - 1e-5 * x[1] - w[0]) / 1e-4]

    def motor(substeps):
        return System.from_ode(rhs, lambda x, v: [x[0] + v[0]], nx=2, nu=1, nw=1, nv=1, dt=2e-3, substeps=substeps,
                               x_bounds=((-50.0, -1000.0), (50.0, 1000.0)), u_bounds=(-24.0, 24.0),
                               v_bounds=(-0.01, 0.01))  # fmt: skip

    with pytest.warns(UserWarning, match="RK4 with step 0.002 grows where the ODE decays"):
        unstable = analyse(motor(1), points=4)
    (zero,) = unstable.zeros.reference
    assert zero.value.real == pytest.approx(6.0, abs=0.05) and zero.unstable_step and zero.from_sampling is None
    assert "may come from the integrator" in unstable.reason and "created by sampling" not in unstable.reason
    (zero,) = analyse(motor(4), points=4).zeros.reference  # RK4 stable: the sampling zero, named as such
    assert zero.value.real == pytest.approx(-0.297, abs=0.01) and zero.from_sampling and not zero.unstable_step


def test_an_unbounded_x_without_zeros_is_told_to_give_bounds():
    # a sampled mass on a spring, position and velocity measured, X unbounded: no zero on or outside the unit circle,
    # so the missing certificate is X's doing, and the reason says so
    def cart(**bounds):
        return System.from_ode(lambda x, u, w: [x[1], -4 * x[0] - 0.4 * x[1] + w[0]],
                               lambda x, v: [x[0] + v[0], x[1] + v[1]], nx=2, nw=1, nv=2, dt=0.05,
                               v_bounds=(-1e-3, 1e-3), **bounds)  # fmt: skip

    free = analyse(cart())
    assert not free.x_bounded and free.to_dict()["x_bounded"] is False
    assert "give X bounds (x_bounds) and analyse again" in free.reason
    bounded = analyse(cart(x_bounds=(-10.0, 10.0)))
    assert bounded.x_bounded and "give X bounds" not in bounded.reason


def test_an_input_no_output_sees_leaves_unbounded_only_the_states_it_moves():
    # w2 drives x4 alone, which no output sees; x1..x3 are measured: their floor is their noise's reach, not
    # "unbounded" (the floor once multiplied their zero motion along w2's direction by an infinite gain: 0 * inf)
    import warnings

    from uiest.models.linear import linear_system

    A = np.array([[0.8, 0.1, 0.0, 0.0], [0.2, 0.7, 0.1, 0.0], [0.0, 0.3, 0.6, 0.0], [0.1, 0.0, 0.0, 0.8]])
    B = np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 1.0]])
    C = np.eye(4)[:3]
    system = linear_system(A, B, C, x_bounds=(-50, 50), v_bounds=(-0.01, 0.01))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        floor = analyse(system, points=4).near_zeros.error_floor
    assert np.all(np.isfinite(floor[:3])) and np.all(floor[:3] < 0.05) and floor[3] == np.inf


def test_a_zero_outside_the_unit_circle_leaves_the_states_its_motion_moves_unbounded():
    # zero at 1.25 (x3 driven by x2, y = (x1, x2)): a motion growing 1.25-fold per sample shows in no output, so
    # x3's error is unbounded; the floor once looked at |z| = 1 only and reported 0.016
    from uiest.analysis.recommend import frequency_text
    from uiest.models.linear import linear_system

    A = np.array([[0.6, 0.3, 0.0], [0.2, 0.5, 0.1], [0.0, 0.5, 1.25]])
    system = linear_system(A, np.array([[0.0], [1.0], [0.0]]), np.eye(3)[:2], x_bounds=(-20, 20),
                           v_bounds=(-0.01, 0.01))  # fmt: skip
    a = analyse(system, points=4)
    assert a.near_zeros.floor_z == pytest.approx(1.25)
    assert np.all(a.near_zeros.error_floor[:2] < 0.05) and a.near_zeros.error_floor[2] == np.inf
    assert "growing 1.25-fold per sample" in a.reason
    assert frequency_text(1.0 + 0j) == "constant or slowly drifting"
    assert frequency_text(-1.5 + 0j) == "alternating every sample and growing 1.5-fold per sample"


def test_a_zero_the_discretisation_moved_is_not_called_the_continuous_models():
    # a washout chemostat sampled with its input direction frozen at X's centre had a zero at 1.086 that paired
    # with the continuous zero's image 0.974 and was called "from the continuous model"; the comparison is with the
    # zeros of the linearisation sampled exactly, not with exp(s dt) (which an exact sampling does not keep either)
    from scipy.signal import cont2discrete

    from uiest.analysis.zeros import _zeros_at, exactly_sampled_zeros

    A_c, G, C, dt = np.array([[-2.0, 0.0], [1.0, 0.5]]), np.array([[1.0], [0.0]]), np.array([[1.0, 0.0]]), 1.0
    A_d, B_d, *_ = cont2discrete((A_c, G, C, np.zeros((1, 1))), dt)
    (exact,) = exactly_sampled_zeros(A_c, G, C, dt)
    assert abs(exact - np.exp(0.5 * dt)) < 1e-9  # here the hidden mode's exp(s dt); in general it is not
    (kept,) = _zeros_at(A_d, B_d, C, A_c, G, dt)  # the plant sampled exactly: the continuous model's zero
    assert kept.from_sampling is False and kept.exact is None
    (moved,) = _zeros_at(np.array([[A_d[0, 0], 0.0], [A_d[1, 0], 1.2]]), B_d, C, A_c, G, dt)
    assert moved.value == pytest.approx(1.2) and moved.from_sampling is False and moved.exact == pytest.approx(exact)
    # zeros the exact sampling moves away from exp(s dt) stay the continuous model's (0.9842 against 0.990)
    A_c, G, C = np.array([[-2.0, 0.0], [0.0, -3.0]]), np.array([[1.0], [1.0]]), np.array([[1.0, -0.99]])
    A_d, B_d, *_ = cont2discrete((A_c, G, C, np.zeros((1, 1))), dt)
    (zoh,) = _zeros_at(A_d, B_d, C, A_c, G, dt)
    assert zoh.from_sampling is False and zoh.exact is None


def test_linearity_is_read_from_the_model_not_from_the_points_linearised():
    # analysed at one point, a nonlinear model's Jacobians looked constant, and its zero outside was then
    # "so it is not strongly detectable" as for a linear model
    A = np.array([[0.5, 0.1], [0.3, 1.2]])

    def f(x, u, w):
        return [A[0, 0] * x[0] + A[0, 1] * x[1] + w[0], A[1, 0] * x[0] + A[1, 1] * x[1] + 0.1 * np.sin(x[1])]

    system = System.from_callables(f, lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1, x_bounds=(-10, 10),
                                   v_bounds=(-0.01, 0.01))  # fmt: skip
    one = analyse(system, points=1)
    assert not one.linear and "not strongly detectable" not in one.reason and one.to_dict()["linear"] is False
    assert analyse(linear([1.2, 0.3]), points=1).linear


def test_every_zero_outside_the_unit_circle_leaves_the_states_its_motion_moves_unbounded():
    # zeros at 1.5 (hiding x3) and 1.2 (hiding x4): the floor once took the largest zero alone, and x4 came out 0.015
    from uiest.models.linear import linear_system

    A = np.array([[0.5, 0, 0.1, 0], [0, 0.5, 0, 0.1], [0.3, 0, 1.5, 0], [0, 0.3, 0, 1.2]])
    system = linear_system(A, np.eye(4)[:, :2], np.eye(4)[:2], x_bounds=(-20, 20), v_bounds=(-0.01, 0.01))
    a = analyse(system, points=2)
    floor = a.near_zeros.error_floor
    assert np.all(floor[:2] < 0.05) and np.all(floor[2:] == np.inf)
    # each state's floor is named with the motion that reaches it: the 1.5-fold one hides x3 only
    assert a.near_zeros.state_z[2:] == pytest.approx((1.5, 1.2))
    assert "growing 1.5-fold per sample moves x[2] by any amount (more than X's width 40); one growing 1.2-fold " \
           "per sample moves x[3] by any amount" in a.reason  # fmt: skip
    assert "x[3] unbounded (at z = 1.2, more than X's width)" in str(a)
    assert a.to_dict()["near_zeros"]["state_z"][3] == pytest.approx([1.2, 0.0])


def test_a_measured_states_floor_names_no_frequency_and_a_shared_point_is_named_once():
    # the zeros at 1.7 and 1.2 of a nonlinear model linearised at one point: the sentence named that point twice,
    # and the measured x[0], whose floor is its noise at every frequency, got a stray "at z = -0.682+0.7314j"
    import casadi as ca

    from uiest.analysis.recommend import hidden_motion

    A = np.array([[0.5, 0, 0.1, 0], [0, 0.5, 0, 0.1], [0.3, 0, 1.5, 0], [0, 0.3, 0, 1.2]])
    x, u, w, v = ca.SX.sym("x", 4), ca.SX.sym("u", 0), ca.SX.sym("w", 2), ca.SX.sym("v", 2)
    curved = ca.vertcat(0.05 * ca.sin(x[2]), 0, 0.2 * ca.sin(x[2]), 0.1 * ca.cos(x[3]))
    x_next = ca.mtimes(ca.DM(A), x) + ca.mtimes(ca.DM(np.eye(4)[:, :2]), w) + curved
    system = System.from_expressions(x, u, w, v, x_next, ca.mtimes(ca.DM(np.eye(4)[:2]), x) + v,
                                     x_bounds=(-20, 20), v_bounds=(-0.01, 0.01))  # fmt: skip
    a = analyse(system, points=4)
    assert a.near_zeros.state_z[0] is None and a.near_zeros.state_z[2:] == pytest.approx((1.7, 1.2))
    sentence = hidden_motion(a)
    assert sentence is not None and sentence.count("linearised at") == 1
    assert "; one growing 1.2-fold per sample moves x[3] by any amount" in sentence
    assert "x[0] 0.01, x[1] 0.01, x[2] unbounded" in str(a)


def test_a_failed_solve_reads_as_undecided_and_claims_no_smallest_rate():
    from types import SimpleNamespace

    from uiest.analysis.recommend import _certificate_text
    from uiest.detectability.certificate import CertificateStatus
    from uiest.detectability.lmi import Bisection

    failed = SimpleNamespace(certificate=object(), status=CertificateStatus.SOLVER_FAILED)
    assert _certificate_text(failed) == "undecided: the LMI solver failed"  # was "... is solver failed"
    assert _certificate_text(SimpleNamespace(certificate=object(), status=CertificateStatus.INFEASIBLE)) == "infeasible"
    none_proved = Bisection(rate=None, outcome="solver failed", failed_at=(0.999999, 0.99999), probes=2)
    assert none_proved.note == "the solver failed at rate(s) 0.999999, 0.99999"
    some_proved = Bisection(rate=0.9, outcome="feasible", failed_at=(0.5,), probes=4)
    assert some_proved.note.endswith("so the smallest rate is an upper estimate")
