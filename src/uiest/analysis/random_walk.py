r"""Whether the model with the unknown input as a random walk is detectable: what a smooth-input estimator needs.

An estimator that assumes a smooth unknown input (``w[k+1] = w[k] + dw[k]`` with small steps dw, the
smooth-input MHE, an EKF or UKF with w as a random walk) estimates the augmented state ``(x, w)`` of ::

    [x; w]+ = [A, B; 0, I] [x; w],   y = [C, 0] [x; w]

linearised. Its modes on or outside the unit circle must show in the outputs (detectability, the
Hautus test): the modes of A there (``rank [A - lambda I; C] = nx``), and the input's own mode at 1,
seen iff ``[A - I, B; C, 0]`` has full column rank, i.e. unless the model has an invariant zero at 1
(a constant unknown input and a constant state offset that cancel in the outputs). Sampling zeros
near -1 do not matter here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from uiest.analysis.points import Linearisations
from uiest.box import FloatArray
from uiest.detectability.linear import off_unit_disk
from uiest.detectability.structure import RANK_RTOL

__all__ = ["RandomWalkDetectability", "random_walk_detectability"]


@dataclass(frozen=True, eq=False, kw_only=True)
class RandomWalkDetectability:
    """The Hautus test of the augmented model (module docstring) at every linearisation point.

    Attributes
    ----------
    detectable : bool
        Every tested mode shows in the outputs at every point.
    mode : complex or None
        A mode the outputs do not see (1: a constant unknown input hidden by a constant state offset).
    point : ndarray (nx,) or None
        The state where it was found.

    """

    detectable: bool
    mode: complex | None = None
    point: FloatArray | None = None

    def to_dict(self) -> dict[str, object]:
        """Plain data for JSON."""
        return {"detectable": self.detectable, "mode": None if self.mode is None else [self.mode.real, self.mode.imag],
                "point": None if self.point is None else self.point.tolist()}  # fmt: skip


def _deficient(M: np.ndarray) -> bool:
    s = np.linalg.svd(M, compute_uv=False)
    return bool(s[-1] <= RANK_RTOL * max(1.0, s[0]))


def random_walk_detectability(lin: Linearisations) -> RandomWalkDetectability:
    """The test at each point of ``lin`` (scaled Jacobians)."""
    for i in range(lin.count):
        A, B, C = lin.A[i], lin.B[i], lin.C[i]
        n = A.shape[0]
        for lam in np.linalg.eigvals(A):
            if off_unit_disk(abs(lam)) and _deficient(np.vstack([A - lam * np.eye(n), C])):
                return RandomWalkDetectability(detectable=False, mode=complex(lam), point=lin.x[i] * 1.0)
        Q = scipy.linalg.orth(B) if B.size else np.zeros((n, 0))  # redundant input columns are one direction
        if Q.shape[1]:
            top = np.hstack([A - np.eye(n), Q])
            bottom = np.hstack([C, np.zeros((C.shape[0], Q.shape[1]))])
            if _deficient(np.vstack([top, bottom])):
                return RandomWalkDetectability(detectable=False, mode=1.0 + 0.0j, point=lin.x[i] * 1.0)
    return RandomWalkDetectability(detectable=True)
