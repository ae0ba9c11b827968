"""Checks of user input shared across uiest: typed errors naming the argument, the expected and the received value."""

from __future__ import annotations

import difflib
import math
import numbers
import sys
from collections.abc import Iterable, Mapping
from typing import TYPE_CHECKING, Any

import numba
import numpy as np
from numpy.typing import NDArray

from uiest.errors import DataError, OptionError

if TYPE_CHECKING:
    from types import FrameType


__all__ = [
    "DOMAIN_TOL",
    "MAX_SAMPLES",
    "MAX_STAGE_SIZE",
    "MEMORY_BUDGET",
    "STAGE_BYTES_PER_SIZE2",
    "all_true",
    "any_true",
    "check_callable",
    "check_flag",
    "check_int",
    "check_keywords",
    "check_name",
    "check_real",
    "check_samples",
    "check_seed",
    "real_array",
    "shown",
    "user_stacklevel",
]

FloatArray = NDArray[np.float64]

MAX_SAMPLES = 1_000_000
"""Most random points one call may draw (cover samples, verification pairs, assumption-check points).

Ten times the default verification; a larger count is refused before anything is allocated (design notes:
input checks)."""

STAGE_BYTES_PER_SIZE2 = 4 * 1024
"""Estimated bytes of a window problem per stage and per squared stage size ``(nx + nw + nv + ny)^2``: the build's
measured memory rounded up to 2 KiB and doubled for the solver's factorisation (:mod:`uiest.window.size`; design
notes: input checks)."""

MEMORY_BUDGET = 4 * 1024**3
"""Largest estimated memory of one window problem, or of one record's arrays: 4 GiB."""

MAX_STAGE_SIZE = math.isqrt(MEMORY_BUDGET // (2 * STAGE_BYTES_PER_SIZE2))
"""Largest stage size ``nx + nw + nv + ny`` of a system: a window of one transition (two stages) fits the budget."""

DOMAIN_TOL = 1e-12
"""Known inputs may leave U by this fraction of its width (rounding) before they are refused."""


def shown(value: Any) -> str:
    """A short description of a received value for an error message."""
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape} and dtype {value.dtype}"
    text = repr(value)
    return text if len(text) <= 80 else f"an object of type {type(value).__name__} ({text[:60]}...)"


def check_int(
    value: Any, name: str, *, low: int = 0, high: int | None = None, error: type[Exception] = OptionError
) -> int:
    """``value`` as an int in ``[low, high]`` (bools refused), else ``error`` naming ``name``."""
    if (
        isinstance(value, bool)
        or not isinstance(value, numbers.Integral)
        or int(value) < low
        or (high is not None and int(value) > high)
    ):
        wanted = f">= {low}" if high is None else f"in [{low}, {high:_}]"
        raise error(f"{name}: expected an integer {wanted}, got {shown(value)}")
    return int(value)


def check_seed(seed: Any, name: str = "seed", *, error: type[Exception] = OptionError) -> int:
    """A random seed: an integer >= 0."""
    return check_int(seed, name, low=0, error=error)


def check_samples(value: Any, name: str, *, low: int = 1, error: type[Exception] = OptionError) -> int:
    """A count of random points: an integer in ``[low, MAX_SAMPLES]``."""
    return check_int(value, name, low=low, high=MAX_SAMPLES, error=error)


def check_real(value: Any, name: str, expected: str, *, error: type[Exception] = OptionError) -> float:
    """``value`` as a float when it is a real number (bools and strings refused); range checks are the caller's."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise error(f"{name}: expected {expected}, got {shown(value)}")
    return float(value)


def check_flag(value: Any, name: str, *, optional: bool = False, error: type[Exception] = OptionError) -> Any:
    """``value`` as a bool when it is one (``numpy.bool_`` too; None as well when ``optional``), else ``error``.

    Truthy stand-ins are refused: ``"no"`` is a true string and ``1`` a number, neither says which was meant.
    """
    if optional and value is None:
        return None
    if not isinstance(value, bool | np.bool_):
        wanted = "True, False or None" if optional else "True or False"
        raise error(f"{name}: expected {wanted}, got {shown(value)}")
    return bool(value)


def check_name(value: Any, name: str, *, error: type[Exception] = OptionError) -> str:
    """``value`` if it is a non-empty string without control characters and not only spaces, else ``error``."""
    if not isinstance(value, str) or not value.strip() or not value.isprintable():
        raise error(f"{name}: expected a non-empty printable string, got {shown(value)}")
    return value


def check_keywords(
    given: Mapping[str, Any], known: Iterable[str], name: str, *, error: type[Exception] = OptionError
) -> None:
    """``error`` naming each keyword of ``given`` not among ``known`` (with close matches); ``name``: the caller."""
    known = sorted(known)
    unknown = [key for key in given if key not in known]
    if unknown:
        close = sorted({m for key in unknown for m in difflib.get_close_matches(str(key), known, n=2)})
        hint = f" (did you mean {', '.join(close)}?)" if close else ""
        raise error(f"{name}: unknown keywords {unknown}{hint}; expected some of {known}")


def check_callable(value: Any, name: str, *, error: type[Exception] = OptionError) -> Any:
    """``value`` if it is None or callable."""
    if value is not None and not callable(value):
        raise error(f"{name}: expected a callable or None, got {shown(value)}")
    return value


def any_true(mask: NDArray[np.bool_]) -> bool:
    """``mask.any()`` for a boolean array, by a count.

    A NumPy reduction's call costs several times a count on the few entries of a check repeated every step.
    """
    return int(np.count_nonzero(mask)) > 0


def all_finite(values: NDArray[np.float64]) -> bool:
    """Whether every entry of a float array is finite (one compiled pass; ``np.isfinite`` and a count take two)."""
    return bool(_all_finite(values.reshape(-1)))


@numba.njit(cache=True)
def _all_finite(values):  # pragma: no cover (compiled)
    for value in values:  # noqa: SIM110 (an explicit loop for numba)
        if not math.isfinite(value):
            return False
    return True


def all_true(mask: NDArray[np.bool_]) -> bool:
    """``mask.all()`` by a count (see :func:`any_true`)."""
    return int(np.count_nonzero(mask)) == mask.size


def real_array(value: Any, name: str, expected: str, *, error: type[Exception] = DataError) -> NDArray[np.float64]:
    """``value`` as a float array; the masked entries of a numpy masked array are NaN (missing).

    Booleans (0/1 read as numbers would be data no sensor gave), complex numbers, strings and
    objects that are not real numbers are refused.
    """
    try:
        arr = np.ma.getdata(value) if isinstance(value, np.ma.MaskedArray) else np.asarray(value)
        if arr.dtype.kind not in "iufO":
            raise TypeError(arr.dtype)
        if arr.dtype.kind == "O" and any(isinstance(item, bool | np.bool_) for item in arr.flat):
            raise TypeError("bool")
        out = np.array(arr, dtype=float)
    except (TypeError, ValueError) as exc:
        raise error(f"{name}: expected {expected}, got {shown(value)}") from exc
    if isinstance(value, np.ma.MaskedArray):
        out[np.ma.getmaskarray(value)] = np.nan
    return out


def user_stacklevel() -> int:
    """The ``stacklevel`` for ``warnings.warn`` called right here that names the first frame outside uiest."""
    frame: FrameType | None = sys._getframe(1)
    level = 1
    while frame is not None and str(frame.f_globals.get("__name__", "")).split(".")[0] == "uiest":
        frame, level = frame.f_back, level + 1
    return level
