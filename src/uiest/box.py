"""Box domains ``{z : lower <= z <= upper}`` whose sides may be infinite."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from uiest.checks import all_true, real_array
from uiest.errors import DataError, ModelError

__all__ = ["Box", "as_vector"]

FloatArray = NDArray[np.float64]


def as_vector(value: ArrayLike, size: int, name: str, *, error: type[Exception] = DataError) -> FloatArray:
    """Return ``value`` as a finite 1-D float array of length ``size``.

    A scalar is accepted for ``size == 1``. Raises ``error`` naming ``name`` otherwise.
    """
    if type(value) is np.ndarray and value.dtype == np.float64:  # the common case, as real_array: a copy
        arr = value.copy()
    else:
        arr = real_array(value, name, f"{size} real numbers", error=error)
    if arr.ndim == 0 and size == 1:
        arr = arr.reshape(1)
    if arr.shape != (size,):
        raise error(f"{name}: expected shape ({size},), got shape {arr.shape}")
    if not all_true(np.isfinite(arr)):
        raise error(f"{name}: expected finite values, got {arr.tolist()}")
    return arr


@numba.njit(cache=True)
def _inside(z, lower, upper):  # pragma: no cover (compiled)
    """Whether ``lower <= z <= upper`` entrywise (1-D; NaN is outside)."""
    for i in range(z.size):  # noqa: SIM110 (an explicit loop for numba)
        if not lower[i] <= z[i] <= upper[i]:
            return False
    return True


def _read_both_ways(lower: FloatArray, upper: FloatArray) -> bool:
    """Whether the 2x2 pair ``(lower, upper)`` is also a box read as per-state pairs, and another one.

    Read per state, the rows ``(lower[0], lower[1])`` and ``(upper[0], upper[1])`` are the intervals
    of z_0 and z_1; the reading is plausible when both have positive width (a state pinned to a
    point is no domain a user writes), and different when ``lower[1] != upper[0]``.
    """
    valid = bool(np.all(lower <= upper))
    per_state = bool(lower[0] < lower[1] and upper[0] < upper[1])
    return valid and per_state and bool(lower[1] != upper[0])


@dataclass(frozen=True, eq=False)
class Box:
    """The box ``lower <= z <= upper`` in R^n; entries may be ``-inf``/``+inf``.

    Parameters
    ----------
    lower, upper : array_like, shape (n,)
        Elementwise bounds with ``lower <= upper``; NaN is not allowed.

    """

    lower: FloatArray
    upper: FloatArray

    def __post_init__(self) -> None:
        lower = np.array(self.lower, dtype=float, ndmin=1)
        upper = np.array(self.upper, dtype=float, ndmin=1)
        if lower.ndim != 1 or lower.shape != upper.shape:
            raise ModelError(
                f"Box: lower and upper must be 1-D of equal length, got shapes {lower.shape} and {upper.shape}"
            )
        if np.isnan(lower).any() or np.isnan(upper).any():
            raise ModelError(f"Box: bounds must not be NaN, got lower={lower.tolist()}, upper={upper.tolist()}")
        if (lower > upper).any():
            raise ModelError(f"Box: expected lower <= upper, got lower={lower.tolist()}, upper={upper.tolist()}")
        if (lower == np.inf).any() or (upper == -np.inf).any():
            raise ModelError(
                f"Box: expected lower < +inf and upper > -inf (a side at the wrong infinity holds no point), got "
                f"lower={lower.tolist()}, upper={upper.tolist()}"
            )
        lower.setflags(write=False)
        upper.setflags(write=False)
        object.__setattr__(self, "lower", lower)
        object.__setattr__(self, "upper", upper)

    @classmethod
    def unbounded(cls, n: int) -> Box:
        """The whole space R^n."""
        return cls(np.full(n, -np.inf), np.full(n, np.inf))

    @classmethod
    def symmetric(cls, bound: ArrayLike, n: int | None = None) -> Box:
        """The box ``|z_i| <= bound_i`` (``bound`` scalar or shape (n,))."""
        b = np.abs(np.asarray(bound, dtype=float))
        if b.ndim == 0:
            b = np.full(1 if n is None else n, float(b))
        return cls(-b, b)

    @classmethod
    def coerce(cls, value: Box | tuple[Any, Any] | None, n: int, name: str) -> Box:
        """Build a box of dimension ``n`` from a Box, a ``(lower, upper)`` pair or None (= R^n).

        The pair is ``(lower vector, upper vector)``: ``((0, -5), (10, 5))`` for n = 2 is
        ``0 <= z_0 <= 10, -5 <= z_1 <= 5``. Scalars in the pair are broadcast to length ``n``. Masked entries
        of a numpy masked array are unbounded sides; booleans, strings and mappings are refused.
        Per-state pairs ``((lo_0, hi_0), (lo_1, hi_1))`` are not a form of this argument; for n = 2
        they cannot be told from a ``(lower, upper)`` pair by their shape, so a pair that is a valid
        box under both readings, with different boxes, is refused (ModelError): write
        ``Box(lower=..., upper=...)`` then.
        """
        if value is None:
            return cls.unbounded(n)
        if isinstance(value, Box):
            box = value
        else:
            try:
                if isinstance(value, Mapping | str):  # unpacking would take its keys (characters) as the bounds
                    raise TypeError(type(value).__name__)
                lo, hi = value
            except (TypeError, ValueError) as exc:
                raise ModelError(f"{name}: expected a Box or a (lower, upper) pair, got {value!r}") from exc
            wanted = f"a (lower, upper) pair of numbers or vectors of length {n} (+-inf allowed)"
            lo_arr, hi_arr = (
                np.where(np.ma.getmaskarray(b), side, real_array(b, name, wanted, error=ModelError))
                if isinstance(b, np.ma.MaskedArray)
                else real_array(b, name, wanted, error=ModelError)
                for b, side in ((lo, -np.inf), (hi, np.inf))
            )
            lo_arr, hi_arr = (np.full(n, float(b)) if b.ndim == 0 else b for b in (lo_arr, hi_arr))
            if lo_arr.shape != (n,) or hi_arr.shape != (n,):
                raise ModelError(f"{name}: expected scalars or bounds of length {n}, got {lo!r} and {hi!r}")
            if n == 2 and lo_arr.ndim == 1 and _read_both_ways(lo_arr, hi_arr):
                a, b = (f"{name.split('_')[0]}[{i}]" for i in range(2))  # x_bounds: x[0], x[1]
                raise ModelError(
                    f"{name}: {value!r} is ambiguous for 2 components: as (lower, upper) it is {lo_arr[0]:g} <= {a} <= "
                    f"{hi_arr[0]:g}, {lo_arr[1]:g} <= {b} <= {hi_arr[1]:g}; as per-component pairs it would be "
                    f"{lo_arr[0]:g} <= {a} <= {lo_arr[1]:g}, {hi_arr[0]:g} <= {b} <= {hi_arr[1]:g}. {name} is "
                    f"(lower vector, upper vector): write {name}=Box(lower=..., upper=...) to say which"
                )
            try:
                box = cls(lo_arr, hi_arr)
            except ModelError as exc:
                convention = f"{name} is (lower vector, upper vector), not per-state pairs"
                raise ModelError(f"{name}: {exc} ({convention})") from exc
        if box.size != n:
            raise ModelError(f"{name}: expected a box of dimension {n}, got dimension {box.size}")
        return box

    @property
    def size(self) -> int:
        """Dimension n."""
        return int(self.lower.size)

    @property
    def is_bounded(self) -> bool:
        """True when every side is finite."""
        return bool(np.isfinite(self.lower).all() and np.isfinite(self.upper).all())

    @property
    def width(self) -> FloatArray:
        """``upper - lower``, shape (n,) (``inf`` where a side is infinite)."""
        return self.upper - self.lower

    @property
    def center(self) -> FloatArray:
        """A representative point, shape (n,).

        The midpoint where both sides are finite, the finite side where only one is, 0 where none is.
        """
        lo_ok, hi_ok = np.isfinite(self.lower), np.isfinite(self.upper)
        lo = np.where(lo_ok, self.lower, 0.0)
        hi = np.where(hi_ok, self.upper, 0.0)
        return np.where(lo_ok & hi_ok, 0.5 * (lo + hi), np.where(lo_ok, lo, hi))

    def contains(self, z: ArrayLike, tol: float = 0.0) -> bool | NDArray[np.bool_]:
        """Whether ``z`` (shape (n,) or (m, n)) lies in the box enlarged by ``tol`` times its width.

        Returns a bool for one point and an array of shape (m,) for m points.
        """
        arr = np.asarray(z, dtype=float)
        lower, upper = self._enlarged(tol)
        if arr.shape == lower.shape:  # one point: one compiled pass
            return bool(_inside(arr, lower, upper))
        inside = (arr >= lower) & (arr <= upper)
        if arr.ndim == 1:
            return all_true(inside)
        return np.asarray(inside.all(axis=-1))

    def sides(self, tol: float = 0.0) -> tuple[FloatArray, FloatArray]:
        """``(lower, upper)`` moved outwards by ``tol`` times the finite widths (the sides :meth:`contains` tests)."""
        return self._enlarged(tol)

    def _enlarged(self, tol: float) -> tuple[FloatArray, FloatArray]:
        """The sides moved outwards by ``tol`` times the finite widths, kept per ``tol`` (the bounds are read-only)."""
        cache: dict[float, tuple[FloatArray, FloatArray]] = self.__dict__.setdefault("_enlarged_sides", {})
        sides = cache.get(tol)
        if sides is None:
            slack = tol * np.where(np.isfinite(self.width), self.width, 0.0)
            sides = cache[tol] = (self.lower - slack, self.upper + slack)
            for side in sides:  # handed out by sides(): kept as they are
                side.setflags(write=False)
        return sides

    def clip(self, z: ArrayLike) -> FloatArray:
        """Project ``z`` (shape (..., n)) onto the box."""
        return np.asarray(z, dtype=float).clip(self.lower, self.upper)

    def corners(self) -> FloatArray:
        """The 2^n corners, shape (2^n, n); only for bounded boxes."""
        if not self.is_bounded:
            raise ModelError(f"Box.corners: the box is unbounded (lower={self.lower}, upper={self.upper})")
        grids = np.meshgrid(*[(lo, hi) for lo, hi in zip(self.lower, self.upper, strict=True)], indexing="ij")
        return np.stack([g.ravel() for g in grids], axis=-1)

    def sample(self, rng: np.random.Generator, count: int) -> FloatArray:
        """``count`` points drawn uniformly from a bounded box, shape (count, n)."""
        if not self.is_bounded:
            raise ModelError(f"Box.sample: the box is unbounded (lower={self.lower}, upper={self.upper})")
        return rng.uniform(self.lower, self.upper, size=(count, self.size))

    def to_dict(self) -> dict[str, list[float]]:
        """Plain-data form (``inf`` kept as float)."""
        return {"lower": self.lower.tolist(), "upper": self.upper.tolist()}

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Box):
            return NotImplemented
        return bool(np.array_equal(self.lower, other.lower) and np.array_equal(self.upper, other.upper))

    def __hash__(self) -> int:
        return hash((self.lower.tobytes(), self.upper.tobytes()))

    def __repr__(self) -> str:
        return f"Box(lower={self.lower.tolist()}, upper={self.upper.tolist()})"
