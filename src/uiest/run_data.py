"""Checks of a system's records: one measurement ``y (ny,)``, the previous known input, a run's ``u`` and ``y``.

Index convention: ``u[k]`` acts between k and k+1; a run has ``u (K, nu)`` and ``y (K+1, ny)``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from uiest.box import FloatArray, as_vector
from uiest.checks import DOMAIN_TOL, all_finite, any_true, real_array
from uiest.errors import DataError

if TYPE_CHECKING:
    from numpy.typing import ArrayLike

    from uiest.system import System

__all__ = ["check_run_data", "check_u_prev", "check_y"]


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
    if (
        type(u_prev) is np.ndarray  # every step's case: a float array of the right shape, finite and in U
        and u_prev.dtype == np.float64
        and u_prev.shape == (nu,)
        and all_finite(u_prev)
        and system.u.bounds.contains(u_prev, tol=DOMAIN_TOL)
    ):
        return u_prev.copy()
    u_vec = as_vector(u_prev, nu, "u_prev")
    if not system.u.bounds.contains(u_vec, tol=DOMAIN_TOL):
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
    if type(y) is np.ndarray and y.dtype == np.float64:  # the common case, as real_array: a copy
        arr = y.copy()
    else:
        arr = real_array(y, "y", f"{ny} real numbers (NaN = missing)")
    if arr.ndim == 0 and ny == 1:
        arr = arr.reshape(1)
    if arr.shape != (ny,):
        raise DataError(f"y: expected shape ({ny},), got shape {arr.shape}")
    if any_true(np.isinf(arr)):
        raise DataError(f"y: expected finite values or NaN (missing), got {arr.tolist()}")
    return arr


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
