"""Input checks of the estimators: typed errors that name the argument, the expected and the received value."""

from __future__ import annotations

import numpy as np

from uiest.box import FloatArray
from uiest.system import System

__all__ = ["held_on_boundary", "window_bounds"]


def window_bounds(k: int, N: int | None) -> tuple[int, int]:
    """``(N_k, first)``: the window length and first time of step k (``N_k = min(N, k)``, N None: k)."""
    length = k if N is None else min(N, k)
    return length, k - length


BOUNDARY_RESIDUAL = 10.0
"""An estimate at a side of X is held there against the data when its output residual exceeds this many noise
bounds."""


def held_on_boundary(system: System, x_hat: FloatArray, y: FloatArray, v_bar: FloatArray) -> bool:
    """Whether ``x_hat`` (some state at a side of X) misses ``y`` by more than :data:`BOUNDARY_RESIDUAL` noise bounds.

    The noise bound of each output is half ``|h(x_hat, v_hi) - h(x_hat, v_lo)|`` over V's corners
    (V's centre +- its scale where unbounded); the residual is ``y - h(x_hat, v_bar)`` (missing channels
    ignored). Such an estimate is held by the constraint, not by the data: the true state may
    have left X. The caller checks that some state is at a side (:func:`uiest.health.at_bound`).
    """
    V = system.v.bounds
    lo = np.where(np.isfinite(V.lower), V.lower, V.center - system.v.scale)
    hi = np.where(np.isfinite(V.upper), V.upper, V.center + system.v.scale)
    noise = 0.5 * np.abs(system.output(x_hat, hi) - system.output(x_hat, lo)) + 1e-9 * system.y.scale
    residual = np.abs(y - system.output(x_hat, v_bar))
    return bool(np.nanmax(residual / noise, initial=0.0) > BOUNDARY_RESIDUAL)
