import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uiest import DataError, DomainWarning, GaussianNoise, ModelError, System, UniformNoise, simulate


def make_system(nu=1):
    return System.from_callables(
        lambda x, u, w: [0.9 * x[0] + w[0], 0.5 * x[1] + np.tanh(x[0]) + (u[0] if nu else 0.0)],
        lambda x, v: [x[0] + v[0], x[1] + v[1]],
        nx=2,
        nu=nu,
        nw=1,
        nv=2,
        x_bounds=(-100.0, 100.0),
        v_bounds=(-0.1, 0.1),
    )


def test_shapes_and_index_convention():
    system = make_system()
    traj = simulate(system, [1.0, 0.0], 10, u=np.ones((10, 1)), w=np.arange(10.0)[:, None])
    assert traj.t.shape == (11,) and traj.x.shape == (11, 2) and traj.u.shape == (10, 1)
    assert traj.w.shape == (10, 1) and traj.v.shape == (11, 2) and traj.y.shape == (11, 2)
    # x[k+1] = f(x[k], u[k], w[k])
    for k in range(10):
        np.testing.assert_allclose(traj.x[k + 1], system.step(traj.x[k], traj.u[k], traj.w[k]))
    np.testing.assert_allclose(traj.y, traj.x)  # no noise given -> v = 0
    frame = traj.to_pandas()
    assert list(frame.columns) == [
        "t",
        "x[0]",
        "x[1]",
        "u[0]",
        "w[0]",
        "v[0]",
        "v[1]",
        "y[0]",
        "y[1]",
        "x_outside",
        "v_outside",
    ]
    assert len(frame) == 11 and np.isnan(frame["w[0]"].iloc[-1])


def test_same_seed_same_numbers_bit_for_bit():
    system = make_system()
    a = simulate(system, [1.0, 0.0], 50, u=[0.1], v=UniformNoise.symmetric(0.05), seed=7)
    b = simulate(system, [1.0, 0.0], 50, u=[0.1], v=UniformNoise.symmetric(0.05), seed=7)
    c = simulate(system, [1.0, 0.0], 50, u=[0.1], v=UniformNoise.symmetric(0.05), seed=8)
    assert a.y.tobytes() == b.y.tobytes() and a.v.tobytes() == b.v.tobytes()
    assert a.y.tobytes() != c.y.tobytes()


def test_callable_inputs_receive_k_and_the_current_state():
    system = make_system()
    seen = []

    def w_law(k, x):
        seen.append((k, x.copy()))
        return -0.5 * x[0]

    traj = simulate(system, [2.0, 0.0], 5, u=lambda k, x: [0.0], w=w_law)
    assert [k for k, _ in seen] == list(range(5))
    for k, x in seen:
        np.testing.assert_array_equal(x, traj.x[k])
    np.testing.assert_allclose(traj.w[:, 0], -0.5 * traj.x[:-1, 0])


def test_noise_models():
    system = make_system()
    traj = simulate(system, [0.0, 0.0], 2000, u=[0.0], v=UniformNoise([-0.1, -0.01], [0.1, 0.01]), seed=1)
    assert np.all(np.abs(traj.v[:, 0]) <= 0.1) and np.all(np.abs(traj.v[:, 1]) <= 0.01)
    assert traj.v[:, 1].std() == pytest.approx(0.02 / np.sqrt(12), rel=0.1)
    with pytest.warns(DomainWarning, match=r"v left V at \d+ of 2001 samples"):
        g = simulate(system, [0.0, 0.0], 2000, u=[0.0], v=GaussianNoise(0.5), seed=1)  # V is +-0.1
    assert g.v.std(axis=0) == pytest.approx([0.5, 0.5], rel=0.1)
    assert g.v_outside.sum() > 1500 and not g.x_outside.any()


def test_a_state_leaving_x_is_recorded_and_announced():
    system = make_system()
    with pytest.warns(DomainWarning, match=r"x left X"):
        traj = simulate(system, [0.0, 0.0], 40, u=[0.0], w=lambda k, x: [1e3 * k])
    assert traj.x_outside.any() and not traj.x_outside[0]


def test_no_known_input_system():
    traj = simulate(make_system(nu=0), [1.0, 1.0], 3)
    assert traj.u.shape == (3, 0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"x0": [1.0]}, "x0"),
        ({"x0": [1e3, 0.0]}, "x0: expected a point in X"),
        ({"x0": [np.nan, 0.0]}, "x0"),
        ({"steps": -1}, "steps"),
        ({"steps": 2.5}, "steps"),
        ({"u": np.ones((4, 1))}, "u"),
        ({"u": [np.inf]}, "u"),
        ({"u": None}, "u: required"),
        ({"w": np.ones((5, 2))}, "w"),
        ({"v": np.zeros((5, 2))}, "v"),
        ({"w": lambda k, x: [1.0, 2.0]}, r"w\(k=0"),
    ],
)
def test_bad_input_raises_typed_errors(kwargs, match):
    args = {"x0": [0.0, 0.0], "steps": 5, "u": np.zeros((5, 1))}
    args.update(kwargs)
    with pytest.raises(DataError, match=match):
        simulate(make_system(), args.pop("x0"), args.pop("steps"), **args)


def test_diverging_model_is_reported_with_the_step():
    system = System.from_callables(lambda x, u, w: x * 1e200 + w, lambda x, v: x + v, nx=1, nw=1, nv=1)
    with pytest.raises(ModelError, match="k=2"):
        simulate(system, [1.0], 5)


@settings(max_examples=25, deadline=None)
@given(steps=st.integers(0, 30), nw_rows=st.integers(0, 35), seed=st.integers(0, 2**32 - 1))
def test_shape_property(steps, nw_rows, seed):
    system = make_system()
    w = np.zeros((nw_rows, 1))
    if nw_rows != steps:
        with pytest.raises(DataError, match="w"):
            simulate(system, [0.0, 0.0], steps, u=[0.0], w=w, v=UniformNoise.symmetric(0.1), seed=seed)
        return
    traj = simulate(system, [0.0, 0.0], steps, u=[0.0], w=w, v=UniformNoise.symmetric(0.1), seed=seed)
    assert traj.x.shape == (steps + 1, 2) and traj.y.shape == (steps + 1, 2)
    assert traj.steps == steps
