r"""The projection of Eq. (35) onto X for the two-stage UISE: ``"clip"``, ``"exact"`` or ``"none"``.

Equation and theorem numbers are those of Guo et al. (see the theory map).

See :mod:`uiest.estimators.two_stage` for what each costs and why each keeps the remark after
Theorem 4.8 (the projection error vanishes with the noise).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import scipy.optimize

from uiest.box import FloatArray
from uiest.detectability import lmi
from uiest.errors import OptionError
from uiest.reduction import ReducedModel

__all__ = ["Projection"]

PROJECTIONS = ("clip", "exact", "none")
"""Values accepted as ``projection=``."""


class Projection:
    """The projection of Eq. (35) (``"clip"``, ``"exact"`` or ``"none"``; see the module docstring)."""

    def __init__(self, reduced: ReducedModel, mode: str) -> None:
        if mode not in PROJECTIONS:
            raise OptionError(f"projection: expected one of {list(PROJECTIONS)}, got {mode!r}")
        self.mode = mode
        self.box = reduced.system.x.bounds
        self.used = 0  # how many estimates the projection changed
        if mode == "exact":
            x = ca.SX.sym("x", reduced.system.nx)
            grid = lmi.grid_points(lmi.finite_box(self.box, self.box.center, reduced.system.x.scale), 5)
            zs = np.asarray(reduced.T.map(len(grid))(grid.T), dtype=float).T
            spread = zs.max(axis=0) - zs.min(axis=0)
            self.scale = np.where(np.isfinite(spread) & (spread > 0), spread, 1.0)
            Tx = reduced.T(x) / ca.DM(self.scale)
            self._T = ca.Function("T_scaled", [x], [Tx, ca.jacobian(Tx, x)])

    def __call__(self, x: FloatArray) -> FloatArray:
        """Project ``x = T^-1(z)`` (computed by Eq. (26)) onto X as described for the mode."""
        if self.mode == "none" or self.box.contains(x):
            return x
        self.used += 1
        start = self.box.clip(x)
        if self.mode == "clip":
            return start
        target = np.asarray(self._T(x)[0], dtype=float).reshape(-1)

        def residual(p: FloatArray) -> FloatArray:
            return np.asarray(self._T(p)[0], dtype=float).reshape(-1) - target

        def jacobian(p: FloatArray) -> FloatArray:
            return np.asarray(self._T(p)[1], dtype=float)

        result = scipy.optimize.least_squares(
            residual, start, jac=jacobian, bounds=(self.box.lower, self.box.upper), xtol=1e-15, ftol=1e-15, gtol=1e-15
        )
        return self.box.clip(np.asarray(result.x, dtype=float))
