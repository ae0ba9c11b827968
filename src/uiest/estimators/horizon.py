r"""The information horizon: the longest window whose every cost term still counts in double precision.

A window estimator's cost (:class:`~uiest.estimators.weights.Schedule`) weighs a term ``a`` steps
older than another ``rate^a`` times as much. The window problems are solved in scaled coordinates
(:mod:`uiest.window.problem`), where a weight ``W`` of a signal with scales ``s`` is ``W~ = S W S``
(``S = diag(s)``). The cost, its gradient and its Gauss-Newton matrix are sums of these terms: a term
below ``eps`` (2.2e-16) times the largest one it is summed with vanishes in rounding, and the window
problem the solver sees is no longer the estimator's. :func:`~uiest.estimators.weight_range.check_weight_range`
makes sure a one-step window keeps every term; a window of ``L`` transitions spreads them further:

    oldest terms:  rate^L   lambda_min(S P S)                 (the prior of the first node)
                   rate^(L - shift) lambda_min+(S R S)         (its output, noise and input weights)
    largest term:  rate^(j_new - shift) lambda_max(S R S)      (the newest measured node, j_new = 0, or 1
                                                                for one-step-ahead estimators)

so the smallest term over the largest is ``ratio(L) = rate^L c`` with
``c = min(lambda_min(S P S), rate^-shift lambda_min+(S R S)) / (rate^(j_new - shift) lambda_max(S R S))``
(``R`` ranging over the output, noise and, where the cost has one, the unknown-input weight; ``+``: the
positive eigenvalues, zero ones are terms the cost leaves out on purpose). The information horizon is the
largest ``L`` with ``ratio(L) >= eps``:

    L_info = floor( log(eps / c) / log(rate) ),

beyond which the prior of the window's first node (the term that fixes what the outputs do not, and the
term the guarantees' proofs need) and then the oldest outputs are lost in rounding. Without a discount
(``rate >= 1``) no term is discounted away and there is no horizon. The estimators cap their window at
``L_info`` (:attr:`WindowEstimator.N <uiest.estimators.base.WindowEstimator>`; the design notes, scales and
horizons, give the measurements behind the choice).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from uiest.box import FloatArray
from uiest.estimators.weight_range import EPS
from uiest.estimators.weights import Schedule
from uiest.window import WindowModel

__all__ = ["InformationHorizon", "information_horizon"]


@dataclass(frozen=True, kw_only=True)
class InformationHorizon:
    """Where a window's oldest cost terms fall below double precision (module docstring).

    Attributes
    ----------
    horizon : int or None
        ``L_info``: the longest window (transitions) whose every term is at least ``eps`` times its
        largest; None without a discount (``rate >= 1``).
    rate : float
        The discount per step (``mu``, ``eta``).
    oldest : float
        ``c`` times ``largest``: the smallest scaled weight of the oldest node's terms, undiscounted.
    oldest_term : str
        Which term that is (``"prior"``, ``"output"``, ``"noise"``, ``"input"``).
    largest : float
        The largest scaled weight of the newest measured node's terms.
    largest_term : str
        Which term that is.

    """

    horizon: int | None
    rate: float
    oldest: float
    oldest_term: str
    largest: float
    largest_term: str

    def ratio(self, length: int) -> float:
        """``ratio(L) = rate^L oldest / largest``: the smallest term over the largest in a window of ``length``."""
        return float(self.rate**length * self.oldest / self.largest)

    def cap(self, N: int) -> int:
        """``min(N, horizon)`` (N itself without a horizon)."""
        return N if self.horizon is None else min(N, self.horizon)

    def text(self) -> str:
        """Why the horizon lies where it does, derived from the numbers."""
        if self.horizon is None:
            return f"no information horizon (discount {self.rate:.4g} >= 1)"
        return (
            f"information horizon {self.horizon}: beyond it the {self.oldest_term} term of the oldest node "
            f"(discount {self.rate:.4g} per step) falls below eps = {EPS:.2g} times the {self.largest_term} term of "
            "the newest and vanishes in double-precision rounding"
        )


def _extreme(matrix: FloatArray, scale: FloatArray) -> tuple[float, float]:
    """Smallest positive and largest eigenvalue of ``S W S`` (inf, 0 when it has none)."""
    if matrix.size == 0:
        return math.inf, 0.0
    eig = np.linalg.eigvalsh(np.outer(scale, scale) * np.asarray(matrix, dtype=float))
    kept = eig[eig > 0.0]
    return (float(kept.min()), float(kept.max())) if kept.size else (math.inf, 0.0)


def information_horizon(schedule: Schedule, model: WindowModel, *, one_step_ahead: bool) -> InformationHorizon:
    """The information horizon of windows weighted by ``schedule`` on ``model`` (module docstring).

    Parameters
    ----------
    schedule : Schedule
        The estimator's weights (original units) and discount.
    model : WindowModel
        Gives the scales ``x_scale, y_scale, v_scale, w_scale`` of the window problem.
    one_step_ahead : bool
        Whether the newest measured node is one step before the window's end (standard MHE).

    Returns
    -------
    InformationHorizon

    """
    rate = float(schedule.rate)
    stages = [("output", schedule.y, model.y_scale), ("noise", schedule.v, model.v_scale)]
    if schedule.w is not None:
        stages.append(("input", schedule.w, model.w_scale))
    newest = (1 if one_step_ahead else 0) - schedule.shift  # exponent of the newest measured node's weights
    oldest_candidates = [(_extreme(schedule.prior, model.x_scale)[0], "prior")]
    largest_candidates = [(0.0, "prior")]
    for name, matrix, scale in stages:
        low, high = _extreme(matrix, scale)
        oldest_candidates.append((rate ** (-schedule.shift) * low, name))
        exponent = newest if name != "input" else 1 - schedule.shift  # the newest transition is one step back
        largest_candidates.append((rate**exponent * high, name))
    oldest, oldest_term = min(oldest_candidates)
    largest, largest_term = max(largest_candidates)
    if rate >= 1.0 or largest <= 0.0 or not math.isfinite(oldest):
        horizon = None
    else:
        # ratio(L) = rate^L oldest / largest >= eps; at least one transition (the weights' own check keeps L = 1)
        horizon = max(1, math.floor(math.log(EPS * largest / oldest) / math.log(rate) + 1e-9))
    return InformationHorizon(horizon=horizon, rate=rate, oldest=oldest, oldest_term=oldest_term, largest=largest,
                              largest_term=largest_term)  # fmt: skip
