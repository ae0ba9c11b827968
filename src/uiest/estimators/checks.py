"""Input checks of the estimators: typed errors that name the argument, the expected and the received value."""

from __future__ import annotations

import numpy as np

from uiest.box import FloatArray
from uiest.results import BOUNDARY_FLAG
from uiest.system import System


def window_bounds(k: int, N: int | None) -> tuple[int, int]:
    """``(N_k, first)``: the window length and first time of step k (``N_k = min(N, k)``, N None: k)."""
    length = k if N is None else min(N, k)
    return length, k - length


BOUNDARY_RESIDUAL = 10.0
"""An estimate on the boundary of X is flagged when its output residual exceeds this many noise bounds."""


def boundary_flag(system: System, x_hat: FloatArray, y: FloatArray, v_bar: FloatArray) -> str:
    """A status suffix when ``x_hat`` sits on a finite side of X and misses ``y`` by far more than the noise.

    The noise bound of each output is half ``|h(x_hat, v_hi) - h(x_hat, v_lo)|`` over V's corners
    (V's centre +- its scale where unbounded); the residual is ``y - h(x_hat, v_bar)`` (missing channels
    ignored). Such an estimate is held by the constraint, not by the data: the true state may
    have left X.
    """
    X = system.x.bounds
    width = np.where(np.isfinite(X.width) & (X.width > 0), X.width, 1.0)
    on = (np.isfinite(X.lower) & (x_hat <= X.lower + 1e-9 * width)) | (
        np.isfinite(X.upper) & (x_hat >= X.upper - 1e-9 * width)
    )
    if not on.any():
        return ""
    V = system.v.bounds
    lo = np.where(np.isfinite(V.lower), V.lower, V.center - system.v.scale)
    hi = np.where(np.isfinite(V.upper), V.upper, V.center + system.v.scale)
    noise = 0.5 * np.abs(system.output(x_hat, hi) - system.output(x_hat, lo)) + 1e-9 * system.y.scale
    residual = np.abs(y - system.output(x_hat, v_bar))
    ratio = np.nanmax(residual / noise, initial=0.0)
    if not ratio > BOUNDARY_RESIDUAL:
        return ""
    names = [n for n, flag in zip(system.x.names, on, strict=True) if flag]
    return f" {BOUNDARY_FLAG} ({', '.join(names)}), output residual {ratio:.3g}x the noise]"
