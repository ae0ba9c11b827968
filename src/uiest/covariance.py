"""Covariances the filters and the likelihood-weighted MHE share: parsing and the defaults a model implies.

- :func:`as_covariance`: a covariance (n, n) from variances, a matrix or None (a default diagonal).
- :func:`noise_variance`: V's uniform variance ``width^2 / 12`` per noise component (v's scale^2 on an infinite side).
- :func:`prior_variance`: x[0]'s default variance ``x.scale^2 / 12`` (uniform over a box one scale wide).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from uiest.box import FloatArray
from uiest.checks import real_array
from uiest.errors import OptionError
from uiest.system import System


def as_covariance(value: ArrayLike | None, n: int, default: FloatArray, name: str) -> FloatArray:
    """A covariance (n, n) from None (``diag(default)``), variances (n,) or a matrix; OptionError if not PSD."""
    arr = np.diag(default) if value is None else real_array(value, name, "a covariance", error=OptionError)
    if arr.ndim < 2 and arr.size in (1, n):
        arr = np.diag(np.broadcast_to(arr.reshape(-1), (n,)))
    if arr.shape != (n, n):
        raise OptionError(f"{name}: expected variances ({n},) or a symmetric ({n}, {n}) matrix, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise OptionError(f"{name}: expected finite values, got {arr.tolist()}")
    if not np.allclose(arr, arr.T):
        raise OptionError(f"{name}: expected a symmetric ({n}, {n}) matrix, got {arr.tolist()}")
    if n and np.linalg.eigvalsh(arr)[0] < -1e-12 * max(float(np.abs(arr).max()), 1e-300):
        raise OptionError(f"{name}: expected a positive semidefinite covariance")
    return 0.5 * (arr + arr.T)


def noise_variance(system: System) -> FloatArray:
    """V's uniform variance ``width^2 / 12`` per component, v's ``scale^2`` where V has an infinite side; (nv,)."""
    V = system.v.bounds
    return np.where(np.isfinite(V.width), V.width**2 / 12.0, system.v.scale**2)


def output_noise_variance(system: System, floor: float) -> FloatArray:
    """The noise's variance seen in each output, ``diag(D Sigma_v D^T)`` (ny,), at least ``(floor * y.scale)^2``.

    ``D = dh/dv`` at X's centre (0 on an infinite side), ``Sigma_v`` V's uniform variance (:func:`noise_variance`).
    """
    center = system.x.bounds.center
    D = system.linearize(np.where(np.isfinite(center), center, 0.0)).D_v
    return np.maximum(np.einsum("ij,j,ij->i", D, noise_variance(system), D), (floor * system.y.scale) ** 2)


def prior_variance(system: System) -> FloatArray:
    """x[0]'s default variance ``x.scale^2 / 12``: uniform over a box one scale wide; (nx,)."""
    return system.x.scale**2 / 12.0


__all__ = ["as_covariance", "noise_variance", "output_noise_variance", "prior_variance"]
