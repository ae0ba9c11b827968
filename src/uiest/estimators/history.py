"""The last rows an estimator stored (inputs, measurements, node data), kept so that a window of them is one slice.

Index convention: rows are in the order appended; ``history.last(n)`` is the newest ``n`` of them, oldest first,
and ``history[-1]`` the newest.
"""

from __future__ import annotations

import numpy as np

from uiest.box import FloatArray

__all__ = ["RowHistory"]


class RowHistory:
    """The newest ``capacity`` rows of width ``width`` appended (every row when ``capacity`` is None).

    With a capacity, each row is written twice, at ``i`` and ``i + capacity`` of a ``(2 capacity, width)``
    buffer (``i`` its position modulo the capacity), so the newest ``n`` rows always lie in one contiguous slice.

    Parameters
    ----------
    width : int
        Entries per row.
    capacity : int or None
        How many rows are kept (older ones are dropped); None keeps them all.

    """

    def __init__(self, width: int, capacity: int | None) -> None:
        self.width, self.capacity = width, capacity
        self._count = 0
        self._rows = np.empty((2 * capacity if capacity is not None else 16, width))

    def __len__(self) -> int:
        """How many rows are held (at most the capacity)."""
        return self._count if self.capacity is None else min(self._count, self.capacity)

    def append(self, row: FloatArray) -> None:
        """Store ``row`` (shape (width,)) as the newest."""
        if self.capacity is None:
            if self._count == len(self._rows):
                self._rows = np.concatenate((self._rows, np.empty_like(self._rows)))
            self._rows[self._count] = row
        elif self.capacity:
            position = self._count % self.capacity
            self._rows[position] = row
            self._rows[position + self.capacity] = row
        self._count += 1

    def last(self, n: int) -> FloatArray:
        """A copy of the newest ``n`` rows, oldest first, shape (n, width); ``n`` at most ``len(self)``."""
        if not 0 <= n <= len(self):
            raise IndexError(f"n: expected 0 <= n <= {len(self)}, got {n}")
        if self.capacity is None:
            return self._rows[self._count - n : self._count].copy()
        first = (self._count - n) % self.capacity if self.capacity else 0
        return self._rows[first : first + n].copy()

    def last_and(self, n: int, row: FloatArray) -> FloatArray:
        """The newest ``n`` rows, oldest first, then ``row``: shape (n + 1, width), one new array."""
        if not 0 <= n <= len(self):
            raise IndexError(f"n: expected 0 <= n <= {len(self)}, got {n}")
        out = np.empty((n + 1, self.width))
        if self.capacity is None:
            out[:n] = self._rows[self._count - n : self._count]
        elif n:
            first = (self._count - n) % self.capacity
            out[:n] = self._rows[first : first + n]
        out[n] = row
        return out

    def __getitem__(self, index: int) -> FloatArray:
        """A copy of row ``index`` (negative: from the newest, ``-1`` the newest; else from the oldest held)."""
        held = len(self)
        if not -held <= index < held:
            raise IndexError(f"index: expected {-held} <= index < {held}, got {index}")
        return self.last(held)[index] if index >= 0 else self.last(-index)[0]
