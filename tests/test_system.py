import casadi as ca
import numpy as np
import pytest

from uiest import DataError, ModelError, System
from uiest.errors import OptionError
from uiest.signal import SignalSpec


def pendulum(**spec):
    def f(x, u, w):
        return [x[0] + 0.1 * x[1], x[1] - 0.1 * np.sin(x[0]) + 0.1 * u[0] + w[0]]

    def h(x, v):
        return x[0] + v[0]

    return System.from_callables(f, h, nx=2, nu=1, nw=1, nv=1, **spec)


def test_from_callables_traces_numpy_operations_and_matrices():
    A = np.array([[1.0, 0.1], [0.0, 0.9]])
    system = System.from_callables(
        lambda x, u, w: A @ x + np.array([0.0, 1.0]) * w[0] + np.exp(-x[0]) * 0.0,
        lambda x, v: x[0] + v,
        nx=2,
        nw=1,
        nv=1,
    )
    assert (system.nx, system.nu, system.nw, system.nv, system.ny) == (2, 0, 1, 1, 1)
    np.testing.assert_allclose(system.step([1.0, 2.0], None, [3.0]), [1.2, 4.8])
    assert ca.GlobalOptions.getNumpyMode() == 0  # tracing leaves the global setting alone


def test_from_expressions_and_from_functions_agree():
    x, u, w, v = ca.SX.sym("x", 2), ca.SX.sym("u", 0), ca.SX.sym("w", 1), ca.SX.sym("v", 1)
    sys_a = System.from_expressions(x, u, w, v, ca.vertcat(x[1], -x[0] + w), x[0] + v)
    f = ca.Function("f", [x, u, w], [ca.vertcat(x[1], -x[0] + w)])
    h = ca.Function("h", [x, v], [x[0] + v])
    sys_b = System.from_functions(f, h)
    for s in (sys_a, sys_b):
        np.testing.assert_allclose(s.step([1.0, 2.0], None, [0.5]), [2.0, -0.5])


def test_step_and_output_batch():
    system = pendulum()
    xs = np.random.default_rng(0).normal(size=(5, 2))
    batch = system.step(xs, np.zeros((5, 1)), np.ones((5, 1)))
    single = np.array([system.step(x, [0.0], [1.0]) for x in xs])
    np.testing.assert_allclose(batch, single, rtol=1e-15)
    assert system.output(xs, np.zeros((5, 1))).shape == (5, 1)


def test_linearize_matches_finite_differences():
    system = pendulum()
    x, u, w = np.array([0.3, -0.2]), np.array([0.1]), np.array([0.4])
    lin = system.linearize(x, u, w, [0.0])
    eps = 1e-7
    fd = np.column_stack(
        [(system.step(x + eps * e, u, w) - system.step(x - eps * e, u, w)) / (2 * eps) for e in np.eye(2)]
    )
    np.testing.assert_allclose(lin.A, fd, atol=1e-8)
    np.testing.assert_allclose(lin.B_w, [[0.0], [1.0]])
    np.testing.assert_allclose(lin.B_u, [[0.0], [0.1]])
    np.testing.assert_allclose(lin.C, [[1.0, 0.0]])
    np.testing.assert_allclose(lin.D_v, [[1.0]])


def test_scales_from_widths_user_values_and_output_propagation():
    system = pendulum(x_bounds=([-1.0, -np.inf], [1.0, np.inf]), v_bounds=(-0.1, 0.1), w_range=(0.0, 4.0))
    np.testing.assert_allclose(system.x.scale, [2.0, 1.0])  # width where finite, else 1
    np.testing.assert_allclose(system.w.scale, [4.0])  # from the known range
    np.testing.assert_allclose(system.y.scale, [np.hypot(2.0, 0.2)])  # dh/dx s_x and dh/dv s_v
    assert not np.isfinite(system.w.bounds.lower).any()  # w itself stays unbounded
    custom = pendulum(x_scale=[3.0, 4.0])
    np.testing.assert_allclose(custom.x.scale, [3.0, 4.0])


def test_construction_rejects_inconsistent_models():
    with pytest.raises(ModelError, match="nx"):
        System.from_callables(lambda x, u, w: [x[0]], lambda x, v: x[0] + v, nx=2, nw=1, nv=1)
    with pytest.raises(ModelError, match="not finite"):
        System.from_callables(lambda x, u, w: 1 / x + w, lambda x, v: x[0] + v, nx=1, nw=1, nv=1)
    with pytest.raises(ModelError, match="x_bounds"):
        pendulum(x_bounds=([0.0, 0.0], [1.0]))
    with pytest.raises(ModelError, match="unique"):
        pendulum(x_names=["a", "b"], y_names=["a"])
    with pytest.raises(ModelError, match="x_scale"):
        pendulum(x_scale=[1.0, -1.0])
    with pytest.raises(ModelError, match="dt"):
        pendulum(dt=0.0)
    with pytest.raises(ModelError, match="tracing"):
        System.from_callables(lambda x, u, w: undefined_name, lambda x, v: x, nx=1, nw=1, nv=1)  # noqa: F821
    x, w, v = ca.SX.sym("x", 2), ca.SX.sym("w", 1), ca.SX.sym("v", 1)
    f = ca.Function("f", [x, w], [x])
    with pytest.raises(ModelError, match="3 inputs"):
        System.from_functions(f, ca.Function("h", [x, v], [x[0]]))


def test_unknown_keywords_raise():
    with pytest.raises(OptionError, match=r"x_bound.*did you mean x_bounds"):
        pendulum(x_bound=(0, 1))


def test_numeric_helpers_reject_bad_shapes():
    system = pendulum()
    with pytest.raises(DataError, match="x"):
        system.step([1.0, 2.0, 3.0], [0.0], [0.0])
    with pytest.raises(DataError, match="finite"):
        system.output([np.nan, 0.0])
    with pytest.raises(DataError, match="disagree"):
        system.step(np.zeros((3, 2)), np.zeros((4, 1)), np.zeros((3, 1)))


def test_system_is_frozen():
    system = pendulum()
    with pytest.raises(AttributeError):
        system.dt = 2.0
    with pytest.raises(ValueError):
        system.x.scale[0] = 5.0


def _scalar_functions():
    x, u, w, v = (ca.SX.sym(name) for name in "xuwv")
    return ca.Function("f", [x, u, w], [0.5 * x + u + w]), ca.Function("h", [x, v], [x + v])


def test_signal_specs_build_the_same_system_as_the_flat_keywords():
    f, h = _scalar_functions()
    flat = System.from_functions(f, h, x_bounds=(-10, 10), x_names=["level"], x_units=["m"], u_bounds=(-1, 1),
                                 v_bounds=(-0.1, 0.1), w_scale=2.0)  # fmt: skip
    grouped = System.from_functions(
        f,
        h,
        signals={
            "x": SignalSpec(bounds=(-10, 10), names=["level"], units=["m"]),
            "u": SignalSpec(bounds=(-1, 1)),
            "v": SignalSpec(bounds=(-0.1, 0.1)),
            "w": SignalSpec(scale=2.0),
        },
    )
    for kind in "xuwvy":
        a, b = getattr(flat, kind), getattr(grouped, kind)
        assert (a.names, a.units, a.bounds, a.scale_source) == (b.names, b.units, b.bounds, b.scale_source)
        np.testing.assert_array_equal(a.scale, b.scale)


def test_signal_specs_refuse_mixed_forms_unknown_keywords_and_bad_fields():
    f, h = _scalar_functions()
    with pytest.raises(OptionError, match=r"signals\['x'\] and x_bounds given together"):
        System.from_functions(f, h, signals={"x": SignalSpec(names=["a"])}, x_bounds=(-1, 1))
    with pytest.raises(OptionError, match=r"^signals\['x'\] and x_names given together"):  # no other caller named
        System.from_callables(lambda x, u, w: x + w, lambda x, v: x + v, nx=1, nw=1, nv=1, x_names=("a",),
                              signals={"x": SignalSpec(names=("b",))})  # fmt: skip
    with pytest.raises(OptionError, match=r"unexpected keyword.*x_bound\b"):
        System.from_functions(f, h, x_bound=(-1, 1))
    with pytest.raises(OptionError, match=r"signals\['x'\]: expected a SignalSpec"):
        System.from_functions(f, h, signals={"x": (-1, 1)})
    with pytest.raises(OptionError, match="signals: expected a mapping from some of"):
        System.from_functions(f, h, signals={"z": SignalSpec()})
    with pytest.raises(ModelError, match="w: the unknown input has no domain"):
        System.from_functions(f, h, signals={"w": SignalSpec(bounds=(-1, 1))})
    with pytest.raises(ModelError, match="x_scale: expected positive finite numbers"):
        System.from_functions(f, h, x_scale=-1.0)
    with pytest.raises(ModelError, match="scale: expected positive finite numbers"):
        SignalSpec(scale=[1.0, float("nan")])
    with pytest.raises(ModelError, match="names: expected a sequence of strings"):
        SignalSpec(names="level")


def test_signal_specs_pass_through_from_callables_and_from_ode():
    spec = {"x": SignalSpec(bounds=(-10.0, 10.0), names=["level"]), "v": SignalSpec(bounds=(-0.01, 0.01))}
    system = System.from_callables(lambda x, u, w: [0.9 * x[0] + w[0]], lambda x, v: [x[0] + v[0]],
                                   nx=1, nu=0, nw=1, nv=1, signals=spec)  # fmt: skip
    assert system.x.names == ("level",) and system.x.bounds.upper.tolist() == [10.0]
    ode = System.from_ode(lambda x, u, w: [-x[0] + w[0]], lambda x, v: [x[0] + v[0]], nx=1, nu=0, nw=1, nv=1,
                          dt=0.1, signals=spec)  # fmt: skip
    assert ode.x.names == ("level",) and ode.v.bounds.upper.tolist() == [0.01]
