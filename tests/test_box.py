import numpy as np
import pytest

from uiest import Box, ModelError


def test_center_width_and_contains_with_infinite_sides():
    box = Box([0.0, -np.inf, -np.inf, 1.0], [2.0, np.inf, 3.0, np.inf])
    np.testing.assert_array_equal(box.center, [1.0, 0.0, 3.0, 1.0])
    assert not box.is_bounded
    assert box.contains([1.0, 1e9, -1e9, 5.0])
    assert not box.contains([3.0, 0.0, 0.0, 1.0])
    np.testing.assert_array_equal(box.contains(np.array([[1, 0, 0, 1], [-1, 0, 0, 1]])), [True, False])


def test_invalid_boxes_raise():
    with pytest.raises(ModelError, match="lower <= upper"):
        Box([1.0], [0.0])
    with pytest.raises(ModelError, match="NaN"):
        Box([np.nan], [0.0])
    with pytest.raises(ModelError, match="x_bounds"):
        Box.coerce(([0, 0], [1, 1, 1]), 2, "x_bounds")


def test_corners_and_sampling():
    box = Box([0.0, 1.0], [1.0, 2.0])
    assert box.corners().shape == (4, 2)
    pts = box.sample(np.random.default_rng(0), 100)
    assert box.contains(pts).all()
    with pytest.raises(ModelError):
        Box.unbounded(2).corners()


def test_bounds_for_two_states_are_lower_and_upper_vectors_and_per_state_pairs_that_read_both_ways_are_refused():
    from uiest import System

    def build(x_bounds):
        return System.from_callables(lambda x, u, w: [x[1], w[0]], lambda x, v: [x[0] + v[0]], nx=2, nw=1, nv=1,
                                     x_bounds=x_bounds, v_bounds=(-0.1, 0.1))  # fmt: skip

    # per-state pairs as a user writes them: 0 <= x0 <= 10, 5 <= x1 <= 20; also a valid (lower, upper) pair
    ambiguous = r"x_bounds: \(\(0, 10\), \(5, 20\)\) is ambiguous for 2 components: as \(lower, upper\) it is "
    with pytest.raises(ModelError, match=ambiguous + r"0 <= x\[0\] <= 5.*Box\("):
        build(((0, 10), (5, 20)))
    explicit = build(Box(lower=(0, 10), upper=(5, 20))).x.bounds
    np.testing.assert_array_equal(explicit.lower, [0, 10])
    np.testing.assert_array_equal(explicit.upper, [5, 20])
    # (lower, upper) pairs that no per-state reading admits are read as the convention says
    signed = build(((-20.0, -10.0), (20.0, 10.0))).x.bounds
    np.testing.assert_array_equal(signed.lower, [-20, -10])
    np.testing.assert_array_equal(signed.upper, [20, 10])
    positive = build(((0.0, 0.0), (10.0, 10.0))).x.bounds  # per state: two points, no domain
    np.testing.assert_array_equal(positive.upper, [10, 10])
    with pytest.raises(ModelError, match=r"expected lower <= upper"):
        build(((0, 20), (10, 5)))  # per-state pairs read as (lower, upper): lower > upper, refused already
