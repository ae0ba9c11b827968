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
