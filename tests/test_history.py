"""RowHistory: the newest rows an estimator keeps, against a deque of the same rows."""

from collections import deque

import numpy as np
import pytest

from uiest.estimators.history import RowHistory


@pytest.mark.parametrize("capacity", [1, 3, 7, None])
def test_the_newest_rows_are_those_a_deque_of_the_same_length_holds(capacity):
    rng = np.random.default_rng(4)
    history, reference = RowHistory(2, capacity), deque(maxlen=capacity)
    for appended in range(25):  # wraps the buffer several times (capacity None: grows past its first 16 rows)
        assert len(history) == len(reference)
        for n in range(len(reference) + 1):
            expected = np.array(list(reference)[len(reference) - n :]).reshape(n, 2)
            np.testing.assert_array_equal(history.last(n), expected)
            extra = np.array([9.0, -9.0])
            np.testing.assert_array_equal(history.last_and(n, extra), np.vstack((expected, extra)))
        if reference:
            np.testing.assert_array_equal(history[-1], reference[-1])
            np.testing.assert_array_equal(history[-len(reference)], reference[0])
            np.testing.assert_array_equal(history[0], reference[0])
        row = rng.standard_normal(2)
        row[appended % 2] = np.nan if appended % 5 == 0 else row[appended % 2]  # missing entries are kept as NaN
        history.append(row)
        reference.append(row.copy())


def test_rows_handed_out_are_copies_and_the_bounds_are_checked():
    history = RowHistory(1, 2)
    history.append(np.array([1.0]))
    window = history.last(1)
    window[0, 0] = 5.0
    history[-1][0] = 6.0
    np.testing.assert_array_equal(history.last(1), [[1.0]])
    with pytest.raises(IndexError, match="n: expected 0 <= n <= 1, got 2"):
        history.last(2)
    with pytest.raises(IndexError, match="n: expected 0 <= n <= 1, got 2"):
        history.last_and(2, np.array([0.0]))
    with pytest.raises(IndexError, match="index: expected -1 <= index < 1, got -2"):
        history[-2]
    empty = RowHistory(0, 3)  # rows without entries (a model without node data)
    empty.append(np.zeros(0))
    assert empty.last(1).shape == (1, 0)
