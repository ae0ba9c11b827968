"""The compiled passes on the window step's path agree with the NumPy expressions they replace.

NaN, infinities, empty arrays, sides that are absent and values on a side included.
"""

import numpy as np
import pytest

from uiest import DataError, System
from uiest.box import Box
from uiest.checks import all_finite
from uiest.estimators.input_fit import _minimum_norm_step
from uiest.health import BoundTest
from uiest.run_data import check_u_prev
from uiest.window.gauss_newton import ACTIVE_TOL, _largest_abs, _on_bounds, _trial_point

RNG = np.random.default_rng(7)


def _awkward(n):
    values = RNG.normal(size=n)
    values[::5] = 1.0  # on an upper side below
    values[1::7] = -1.0  # on a lower side
    values[2::11] = np.nan
    return values


def test_first_qp_marks_trial_point_and_largest_entry():
    value = _awkward(40)
    lower, upper = np.full(40, -1.0), np.full(40, 1.0)
    lower[3], upper[4] = -np.inf, np.inf
    ranged = RNG.random(40) > 0.3
    edges = (lower + ACTIVE_TOL, upper - ACTIVE_TOL)
    expected = np.where(value >= edges[1], ACTIVE_TOL, np.where(value <= edges[0], -ACTIVE_TOL, 0.0)) * ranged
    np.testing.assert_array_equal(_on_bounds(value, *edges, ranged), expected)
    z, dz = RNG.normal(size=40), _awkward(40)
    trial, small = _trial_point(z, dz, lower, upper, 1e-10)
    np.testing.assert_array_equal(trial, (z + dz).clip(lower, upper))
    assert not small  # NaN is no small step
    assert _trial_point(z, np.full(40, 1e-11), lower, upper, 1e-10)[1]
    finite = RNG.normal(size=9)
    assert _largest_abs(finite) == np.abs(finite).max() and _largest_abs(np.zeros(0)) == 0.0
    for position in (0, 4):
        with_nan = finite.copy()
        with_nan[position] = np.nan
        assert np.isnan(_largest_abs(with_nan))  # as NumPy's maximum, wherever the NaN is


def test_bound_tests_and_box_membership():
    box = Box([-1.0, -np.inf, 0.0], [1.0, 2.0, 0.0])  # the last axis pinned: no side counts there
    test = BoundTest(box, np.ones(3))
    rows = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, -1e300, 0.0], [np.nan, 0.0, 0.0], [0.0, 2.0, 0.0]])
    for row in rows:
        assert test.any(row[None]) == bool(test(row).any())
        assert box.contains(row) == bool(np.all((row >= box.lower) & (row <= box.upper)))
    assert test.any(rows) and not test.any(rows[[0, 2, 3]])
    with pytest.raises(DataError, match="rows of 3 entries"):
        test.any(np.zeros((2, 2)))
    lower, _ = box.sides(0.1)
    with pytest.raises(ValueError, match="read-only"):
        lower[0] = 5.0
    assert all_finite(np.zeros((2, 3))) and not all_finite(np.array([[0.0, np.inf]])) and all_finite(np.zeros(0))


def test_the_previous_input_fast_path_keeps_the_checks_messages():
    system = System.from_callables(lambda x, u, w: [x[0] + u[0] + w[0]], lambda x, v: [x[0] + v[0]], nx=1, nu=1,
                                   nw=1, nv=1, x_bounds=(-10, 10), u_bounds=(-1, 1), v_bounds=(-0.1, 0.1))  # fmt: skip
    assert np.array_equal(check_u_prev(system, np.array([0.5]), 3), [0.5])
    given = np.array([0.5])
    assert check_u_prev(system, given, 3) is not given  # a copy
    for bad, message in ((np.array([np.nan]), "finite"), (np.array([1e9]), "expected values in U")):
        with pytest.raises(DataError, match=message):
            check_u_prev(system, bad, 3)


@pytest.mark.parametrize(
    ("column", "r"),
    [([1.0, -2.0, 0.5], [0.3, 1.0, -2.0]), ([0.0, 0.0, 0.0], [1.0, 2.0, 3.0]), ([1e-300, 0, 0], [1.0, 0, 0]),
     ([1e99, 0, 0], [1e250, 0, 0]), ([1e-99, 0, 0], [1e-250, 0, 0])],
)  # fmt: skip
def test_one_inputs_least_squares_step_is_lstsqs(column, r):
    J, r = np.array(column)[:, None], np.array(r)
    expected = np.linalg.lstsq(J, -r, rcond=None)[0]
    np.testing.assert_allclose(_minimum_norm_step(J, r), expected, rtol=1e-12)
