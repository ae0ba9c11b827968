"""Estimators: ``reset(x0_prior)``, ``step(u_prev, y) -> StepEstimate``, ``run(u, y) -> EstimationResult``.

- :class:`UISE`: MHE-based unknown input state estimator (Theorem 3.6 of Guo et al.; see the theory map).
- :class:`FIE`: full information estimator (Lemma 3.3), growing window.
- :class:`StandardMHE`: robust MHE of Schiller et al. 2023, one-step-ahead (baseline).
- :class:`SmoothInputMHE`: that MHE on the model with the unknown input as a state of bounded, penalised
  increments (:func:`uiest.augmented.augmented_system`), current measurement included.
- :class:`DelayedUISE`: the UISE of the delayed system, x[k-lag] for an input of relative degree 2.
- :class:`TwoStageUISE`: two-stage UISE with a reduced-order model (Theorem 4.8).
- :class:`LinearUIO`: the classical linear unknown input observer (baseline for LTI systems).
- :class:`EKF`, :class:`UKF`: Kalman filters with the unknown input as a random walk (:mod:`uiest.estimators.kalman`).

Each has a ``guarantee`` (:class:`~uiest.guarantee.Guarantee`): whether its theorem applies and its
worst-case error bound per state (:mod:`uiest.estimators.bounds`).

Index convention: ``u[k]``, ``w[k]`` act between k and k+1; ``x_hat[k]`` estimates ``x[k]``;
the UISE, the FIE and the smooth-input MHE use ``y[0..k]``, the standard MHE ``y[0..k-1]``; the window at time k
covers ``k-N_k .. k`` with ``N_k = min(N, k)``.
"""

from uiest.estimators.base import WindowOptions
from uiest.estimators.delayed import DelayedUISE
from uiest.estimators.fie import FIE
from uiest.estimators.kalman import EKF, UKF
from uiest.estimators.linear_uio import LinearUIO
from uiest.estimators.smooth_mhe import SmoothInputMHE
from uiest.estimators.standard_mhe import StandardMHE
from uiest.estimators.two_stage import TwoStageUISE
from uiest.estimators.uise import UISE
from uiest.estimators.weights import MHEWeights, TwoStageWeights, UISEWeights
from uiest.guarantee import Guarantee, Verdict
from uiest.results import EstimationResult, Outcome, StepEstimate

__all__ = [
    "EKF",
    "FIE",
    "UISE",
    "UKF",
    "DelayedUISE",
    "EstimationResult",
    "Guarantee",
    "LinearUIO",
    "MHEWeights",
    "Outcome",
    "SmoothInputMHE",
    "StandardMHE",
    "StepEstimate",
    "TwoStageUISE",
    "TwoStageWeights",
    "UISEWeights",
    "Verdict",
    "WindowOptions",
]
