"""Interval enclosures and branch-and-bound bounds of CasADi expressions."""

import casadi as ca
import numpy as np
import pytest

from uiest.box import Box
from uiest.detectability import interval


def _function(expr_builder, n=2):
    z = ca.SX.sym("z", n)
    return ca.Function("g", [z], [expr_builder(z)])


EXPRESSIONS = {
    "polynomial": lambda z: z[0] * z[1] - z[0] ** 2 + 3.0 * z[1] ** 3,
    "trigonometric": lambda z: ca.sin(3.0 * z[0]) * ca.cos(z[1]) + ca.tan(0.3 * z[1]),
    "exponential": lambda z: ca.exp(-2.0 * z[0]) / (1.5 + ca.tanh(z[1])) + ca.sqrt(z[0] + 5.0),
    "rational": lambda z: z[0] / (z[1] ** 2 + 1.0) + ca.fabs(z[0] - z[1]) + ca.fmax(z[0], 0.3),
    "logarithm": lambda z: ca.log(z[0] + 4.0) * ca.atan(z[1]) + ca.log1p(z[1] ** 2),
}


@pytest.mark.parametrize("name", sorted(EXPRESSIONS))
def test_enclosures_contain_every_sampled_value(name):
    fun = _function(EXPRESSIONS[name])
    rng = np.random.default_rng(0)
    lower = rng.uniform(-3.0, 0.0, (200, 2))
    upper = lower + rng.uniform(0.0, 2.0, (200, 2))
    derivative = interval.centered(fun)
    for centred in (None, derivative):
        lo, hi = interval.enclosure(fun, lower, upper, centred)
        for _ in range(20):
            z = lower + rng.random((200, 2)) * (upper - lower)
            value = np.asarray(fun.map(200)(z.T)).reshape(-1)
            assert np.all((lo[:, 0] <= value) & (value <= hi[:, 0]))


@pytest.mark.parametrize("name", sorted(EXPRESSIONS))
def test_bounds_are_sound_and_tight(name):
    fun = _function(EXPRESSIONS[name])
    box = Box([-2.0, -1.0], [1.0, 1.0])
    found = interval.bounds(fun, box, rtol=1e-3)
    z = box.sample(np.random.default_rng(1), 20_000)
    values = np.asarray(fun.map(len(z))(z.T)).reshape(-1)
    assert found.lower[0] <= values.min() and values.max() <= found.upper[0]
    spread = values.max() - values.min()
    assert found.gap[0] <= 2e-3 * spread


def test_sine_peaks_are_found():
    fun = _function(lambda z: ca.sin(z[0]), n=1)
    lo, hi = interval.enclosure(fun, np.array([[1.0], [-2.0], [0.1]]), np.array([[2.0], [-1.0], [0.2]]))
    assert hi[0, 0] == pytest.approx(1.0) and lo[1, 0] == pytest.approx(-1.0)
    assert lo[2, 0] == pytest.approx(np.sin(0.1)) and hi[2, 0] == pytest.approx(np.sin(0.2))


def test_unsupported_operations_are_named():
    fun = _function(lambda z: ca.floor(z[0]) + z[1])
    with pytest.raises(interval.IntervalUnsupportedError, match="floor"):
        interval.bounds(fun, Box([0.0, 0.0], [1.0, 1.0]))


def test_arguments_outside_a_domain_give_no_false_bounds():
    # the natural extension of z^2 - 2 c z + c^2 + 0.01 dips below 0, where log and sqrt are undefined
    c = 0.37
    for build, name in ((lambda z: 3.0 * ca.log(z[0] ** 2 - 2 * c * z[0] + c**2 + 0.01), "log"),
                        (lambda z: ca.sqrt(z[0] ** 2 - z[0] + 0.26), "sqrt")):  # fmt: skip
        fun = _function(build, n=1)
        box = Box([0.0], [1.0])
        z = np.linspace(0.0, 1.0, 100_001)[:, None]
        values = np.asarray(fun.map(len(z))(z.T)).reshape(-1)
        lo, hi = interval.enclosure(fun, box.lower[None], box.upper[None], interval.centered(fun))
        assert lo[0, 0] <= values.min() and values.max() <= hi[0, 0], name
        found = interval.bounds(fun, box)
        assert found.lower[0] <= values.min() and values.max() <= found.upper[0], name


def test_sparse_outputs_stay_in_place():
    z = ca.SX.sym("z", 2)
    fun = ca.Function("g", [z], [ca.vertcat(ca.SX(1, 1), z[0], 10.0 * z[1])])
    assert not fun.sparsity_out(0).is_dense()
    lo, hi = interval.enclosure(fun, np.array([[0.0, 0.0]]), np.array([[1.0, 1.0]]))
    np.testing.assert_allclose(lo[0], [0.0, 0.0, 0.0], atol=1e-300)
    np.testing.assert_allclose(hi[0], [0.0, 1.0, 10.0], rtol=1e-15)
    found = interval.bounds(fun, Box([0.0, 0.0], [1.0, 1.0]))
    np.testing.assert_allclose(found.upper, [0.0, 1.0, 10.0], rtol=1e-12, atol=1e-300)


def test_large_arguments_and_cancellation_are_enclosed():
    fun = _function(lambda z: ca.cos(z[0]) + (z[0] + z[1]) * 2.0 - 2.0 * z[1])
    for point in ([100.0, 0.0], [1e6, 3.0], [0.1, 1e8]):
        p = np.array([point])
        lo, hi = interval.enclosure(fun, p, p, interval.centered(fun))
        exact = np.cos(point[0]) + 2.0 * point[0]
        assert lo[0, 0] <= exact <= hi[0, 0]


def test_a_narrow_feature_is_localised_and_its_extremes_are_returned():
    # the derivative of a bump 3e-4 wide, times the other coordinate: splitting the side where the function
    # changes most closes the bound in a few hundred boxes (halving the widest side alternated and ran out)
    fun = _function(lambda z: ca.exp(-(((z[0] - 1.3) / 3e-4) ** 2)) * (z[0] - 1.3) / 9e-8 * z[1])
    box = Box([-5.0, -3.0], [5.0, 3.0])
    found = interval.bounds(fun, box, rtol=1e-3)
    peak = 3.0 * 3e-4 / np.sqrt(2.0) * np.exp(-0.5) / 9e-8
    assert peak - 2e-3 * 2.0 * peak <= found.attained_upper[0] <= peak <= found.upper[0]
    assert found.gap[0] <= 2e-3 * 2.0 * peak and found.boxes < 20_000
    for at, value in ((found.upper_at[0], found.attained_upper[0]), (found.lower_at[0], found.attained_lower[0])):
        assert box.contains(at) and float(fun(at)) == pytest.approx(value)
        assert abs(at[0] - 1.3) < 1e-3 and abs(abs(at[1]) - 3.0) < 1e-2
