"""Input checks of the estimators: typed errors that name the argument, the expected and the received value."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from uiest.box import FloatArray, as_vector
from uiest.errors import DataError, OptionError
from uiest.system import System


def check_horizon(N: Any) -> int:
    """Return N as an int >= 1 or raise OptionError naming ``N``."""
    if isinstance(N, bool) or not isinstance(N, int | np.integer) or N < 1:
        raise OptionError(f"N: expected an integer horizon >= 1, got {N!r}")
    return int(N)


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
    return as_vector(u_prev, nu, "u_prev")


def check_y(system: System, y: ArrayLike) -> FloatArray:
    """One measurement as shape (ny,); NaN (missing) allowed, infinities not."""
    ny = system.ny
    try:
        arr = np.asarray(y, dtype=float)
    except (TypeError, ValueError) as exc:
        raise DataError(f"y: expected {ny} real numbers (NaN = missing), got {y!r}") from exc
    if arr.ndim == 0 and ny == 1:
        arr = arr.reshape(1)
    if arr.shape != (ny,):
        raise DataError(f"y: expected shape ({ny},), got shape {arr.shape}")
    if np.any(np.isinf(arr)):
        raise DataError(f"y: expected finite values or NaN (missing), got {arr.tolist()}")
    return arr.copy()


def window_bounds(k: int, N: int | None, one_step_ahead: bool) -> tuple[int, int, int]:
    """``(N_k, first, last)``: window length and the first and last measured time of step k."""
    length = k if N is None else min(N, k)
    return length, k - length, (k - 1 if one_step_ahead else k)


def check_run_data(
    system: System,
    u: ArrayLike | None,
    y: ArrayLike,
    N: int | None,
    one_step_ahead: bool,
    *,
    require_measurements: bool = True,
) -> tuple[FloatArray, FloatArray]:
    """Check ``u (K, nu)`` and ``y (K+1, ny)`` for a run.

    With ``require_measurements`` every window (``window_bounds``) must hold a measurement.
    """
    try:
        y_arr = np.asarray(y, dtype=float)
    except (TypeError, ValueError) as exc:
        raise DataError(f"y: expected an array of shape (K+1, {system.ny}), got {type(y).__name__}") from exc
    if y_arr.ndim != 2 or y_arr.shape[1] != system.ny or y_arr.shape[0] < 1:
        raise DataError(f"y: expected shape (K+1, {system.ny}) with K+1 >= 1, got {y_arr.shape}")
    if np.any(np.isinf(y_arr)):
        raise DataError("y: expected finite values or NaN (missing), got +-inf")
    K = y_arr.shape[0] - 1
    nu = system.nu
    if u is None:
        if nu:
            raise DataError(f"u: required, the system has nu={nu} known inputs; expected shape ({K}, {nu})")
        u_arr = np.zeros((K, 0))
    else:
        try:
            u_arr = np.asarray(u, dtype=float)
        except (TypeError, ValueError) as exc:
            raise DataError(f"u: expected an array of shape ({K}, {nu}), got {type(u).__name__}") from exc
        if u_arr.size == 0 and nu == 0:
            u_arr = np.zeros((K, 0))
        if u_arr.ndim != 2 or u_arr.shape[1] != nu:
            raise DataError(f"u: expected shape (K, {nu}), got {u_arr.shape}")
        if u_arr.shape[0] != K:
            raise DataError(
                f"u, y: length mismatch, u has {u_arr.shape[0]} rows and y has {K + 1}; "
                "expected u (K, nu) with y (K+1, ny)"
            )
        if not np.all(np.isfinite(u_arr)):
            bad = int(np.argwhere(~np.isfinite(u_arr))[0][0])
            raise DataError(f"u: expected finite values, got {u_arr[bad].tolist()} at k={bad}")
    if not require_measurements:
        return u_arr, y_arr
    has = (~np.isnan(y_arr)).any(axis=1).astype(int)
    counts = np.concatenate([[0], np.cumsum(has)])
    for k in range(K + 1):
        _, first, last = window_bounds(k, N, one_step_ahead)
        if last >= first and counts[last + 1] - counts[first] == 0:
            raise DataError(f"y: every measurement in the window {first}..{last} of step k={k} is missing (NaN)")
    return u_arr, y_arr
