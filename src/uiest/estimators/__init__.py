"""Estimators: ``reset(x0_prior)``, ``step(u_prev, y) -> StepEstimate``, ``run(u, y) -> EstimationResult``.

- :class:`UISE`: MHE-based unknown input state estimator (theo:MHE_full).
- :class:`FIE`: full information estimator (lem:FIE), growing window.
- :class:`StandardMHE`: robust MHE of Schiller et al. 2023, one-step-ahead (baseline).
- :class:`DelayedUISE`: the UISE of the delayed system, x[k-lag] for an input of relative degree 2.
- :class:`TwoStageUISE`: two-stage UISE with a reduced-order model (theo:stab).
- :class:`LinearUIO`: the classical linear unknown input observer (baseline for LTI systems).

Index convention: ``u[k]``, ``w[k]`` act between k and k+1; ``x_hat[k]`` estimates ``x[k]``;
the UISE and the FIE use ``y[0..k]``, the standard MHE ``y[0..k-1]``; the window at time k
covers ``k-N_k .. k`` with ``N_k = min(N, k)``.
"""

from uiest.estimators.base import WindowOptions
from uiest.estimators.delayed import DelayedUISE
from uiest.estimators.fie import FIE
from uiest.estimators.linear_uio import LinearUIO
from uiest.estimators.standard_mhe import StandardMHE
from uiest.estimators.two_stage import TwoStageUISE
from uiest.estimators.uise import UISE
from uiest.estimators.weights import MHEWeights, TwoStageWeights, UISEWeights
from uiest.results import EstimationResult, StepEstimate

__all__ = [
    "FIE",
    "UISE",
    "DelayedUISE",
    "EstimationResult",
    "LinearUIO",
    "MHEWeights",
    "StandardMHE",
    "StepEstimate",
    "TwoStageUISE",
    "TwoStageWeights",
    "UISEWeights",
    "WindowOptions",
]
