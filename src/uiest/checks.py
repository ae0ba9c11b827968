"""Checks of user input shared across uiest: typed errors naming the argument, the expected and the received value."""

from __future__ import annotations

import difflib
import math
import numbers
import sys
from collections.abc import Iterable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from uiest.errors import DataError, OptionError

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from uiest.system import System

__all__ = [
    "DOMAIN_TOL",
    "MAX_SAMPLES",
    "MAX_STAGE_SIZE",
    "MEMORY_BUDGET",
    "STAGE_BYTES_PER_SIZE2",
    "check_callable",
    "check_flag",
    "check_int",
    "check_keywords",
    "check_name",
    "check_real",
    "check_run_data",
    "check_samples",
    "check_seed",
    "check_u_prev",
    "check_y",
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
        or value < low
        or (high is not None and value > high)
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


# ---------------------------------------------------------------------- records of a system's u and y


def check_u_prev(system: System, u_prev: ArrayLike | None, k: int) -> FloatArray:
    """``u[k-1]`` as shape (nu,); None at k = 0 (and when nu = 0)."""
    nu = system.nu
    if k == 0:
        if u_prev is not None and np.size(u_prev) != 0:
            raise DataError("u_prev: expected None at k = 0 (no transition precedes the first measurement)")
        return np.zeros(nu)
    if u_prev is None:
        if nu == 0:
            return np.zeros(0)
        raise DataError(f"u_prev: expected the known input u[{k - 1}] of shape ({nu},), got None")
    from uiest.box import as_vector  # box imports this module

    u_vec = as_vector(u_prev, nu, "u_prev")
    _check_in_U(system, u_vec[None], "u_prev", k - 1)
    return u_vec


def _check_in_U(system: System, u: FloatArray, name: str, first: int = 0) -> None:
    """DataError naming ``name`` when a row of ``u (m, nu)`` leaves U (tolerance as in :func:`~uiest.simulate`)."""
    inside = np.asarray(system.u.bounds.contains(u, tol=DOMAIN_TOL)).reshape(-1)
    if not inside.all():
        bad = int(np.argmin(inside))
        raise DataError(f"{name}: expected values in U = {system.u.bounds}, got {u[bad].tolist()} at k={first + bad}")


def check_y(system: System, y: ArrayLike) -> FloatArray:
    """One measurement as shape (ny,); NaN (missing) allowed, infinities not."""
    ny = system.ny
    if y is None:
        raise DataError(f"y: expected {ny} real numbers (NaN = missing), got None")
    arr = real_array(y, "y", f"{ny} real numbers (NaN = missing)")
    if arr.ndim == 0 and ny == 1:
        arr = arr.reshape(1)
    if arr.shape != (ny,):
        raise DataError(f"y: expected shape ({ny},), got shape {arr.shape}")
    if np.any(np.isinf(arr)):
        raise DataError(f"y: expected finite values or NaN (missing), got {arr.tolist()}")
    return arr.copy()


def check_run_data(system: System, u: ArrayLike | None, y: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Check ``u (K, nu)`` and ``y (K+1, ny)`` for a run.

    NaN in y is missing; windows without any measurement are bridged by the model.
    """
    y_arr = real_array(y, "y", f"an array of real numbers of shape (K+1, {system.ny}) (NaN = missing)")
    if y_arr.ndim != 2 or y_arr.shape[1] != system.ny or y_arr.shape[0] < 1:
        raise DataError(f"y: expected shape (K+1, {system.ny}) with K+1 >= 1, got {y_arr.shape}")
    if np.any(np.isinf(y_arr)):
        raise DataError("y: expected finite values or NaN (missing), got +-inf")
    if np.all(np.isnan(y_arr)):
        raise DataError("y: every measurement is missing (NaN): there is nothing to estimate from")
    K = y_arr.shape[0] - 1
    nu = system.nu
    if u is None:
        if nu:
            raise DataError(f"u: required, the system has nu={nu} known inputs; expected shape ({K}, {nu})")
        return np.zeros((K, 0)), y_arr
    u_arr = real_array(u, "u", f"an array of real numbers of shape ({K}, {nu})")
    if u_arr.size == 0 and nu == 0:
        u_arr = np.zeros((K, 0))
    if u_arr.ndim != 2 or u_arr.shape[1] != nu:
        raise DataError(f"u: expected shape (K, {nu}), got {u_arr.shape}")
    if u_arr.shape[0] != K:
        raise DataError(
            f"u, y: length mismatch, u has {u_arr.shape[0]} rows and y has {K + 1}; expected u (K, nu) with y (K+1, ny)"
        )
    if not np.all(np.isfinite(u_arr)):
        bad = int(np.argwhere(~np.isfinite(u_arr))[0][0])
        raise DataError(f"u: expected finite values, got {u_arr[bad].tolist()} at k={bad}")
    _check_in_U(system, u_arr, "u")
    return u_arr, y_arr


def user_stacklevel() -> int:
    """The ``stacklevel`` for ``warnings.warn`` called right here that names the first frame outside uiest."""
    frame, level = sys._getframe(1), 1
    while frame is not None and str(frame.f_globals.get("__name__", "")).split(".")[0] == "uiest":
        frame, level = frame.f_back, level + 1
    return level
