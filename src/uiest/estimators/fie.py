r"""The full information estimator of Lemma 3.3 of Guo et al. (Eq. (6), Eq. (7); see the theory map).

Index convention::

    x[k+1] = f(x[k], u[k], w[k]),   y[k] = h(x[k], v[k])
    x_hat[k] = x^*_{k|k}  from  x_bar_0, u[0 .. k-1], y[0 .. k]    (growing window, N_k = k)
    w_hat[k-1] = w^*_{k-1|k}

Cost: Eq. (7) with the comparison functions a quadratic strong-detectability
certificate implies (iterating Eq. (5b) as in the proof of Theorem 3.2):
``alpha_0(r, k) = mu^k |r|_P^2``, ``alpha_v(r, j) = 2 mu^{j-1} |r|_{R_v}^2``,
``alpha_y(r, j) = 2 mu^{j-1} |r|_{R_y}^2``, so that::

    J_k = mu^k 4 |x_{0|k} - x_bar_0|_P^2
          + sum_{j=0}^{k} mu^{j-1} ( 8 |v_{k-j|k} - v_bar|_{R_v}^2 + 2 |y_{k-j} - h(x_{k-j|k}, v_{k-j|k})|_{R_y}^2 ),

the UISE's cost Eq. (11) with the window reaching back to time 0. The FIE and the UISE
therefore solve the same problem while ``k <= N``, which makes the FIE a cross-check of the
moving-horizon machinery (and an offline estimator). Its problems grow with k: one is built per
length (k+1 of them) and all data are kept, so building takes time that grows with the square
of the record's length (design notes: input checks) and memory grows with k.
``max_steps`` (default 500) bounds it: a longer record raises :class:`OptionError` before any
work, pointing to the UISE, whose window stays N long. For large k the prior weight ``mu^k``
vanishes, and directions the data do not determine become flat: use it offline and for short
records.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from uiest.checks import check_int
from uiest.errors import OptionError
from uiest.estimators.base import WindowEstimator
from uiest.estimators.bounds import strong_bound
from uiest.estimators.uise import check_system
from uiest.estimators.weights import StrongCertificate, UISEWeights, resolve_weights
from uiest.guarantee import Guarantee
from uiest.results import EstimationResult, StepEstimate
from uiest.run_data import check_run_data
from uiest.scales import data_scales
from uiest.system import System
from uiest.theory import FIE_GUARANTEE
from uiest.window import WindowModel

__all__ = ["FIE"]


class FIE(WindowEstimator):
    r"""Full information estimator (Lemma 3.3 of Guo et al.): growing window from time 0, cost Eq. (7).

    Index convention::

        x[k+1] = f(x[k], u[k], w[k]),  y[k] = h(x[k], v[k]),  N_k = k
        x_hat[k]   = x^*_{k|k}    from x_bar_0, u[0 .. k-1], y[0 .. k]
        w_hat[k-1] = w^*_{k-1|k}

    Parameters as for :class:`~uiest.estimators.UISE`, without N, and ``max_steps``: the longest
    record (k at most this) the FIE accepts; building grows with its square (module docstring).
    """

    estimator_name = "FIE"
    theorem = FIE_GUARANTEE
    free_input = True

    def __init__(
        self,
        system: System,
        *,
        certificate: StrongCertificate | None = None,
        weights: UISEWeights | None = None,
        x0_prior: ArrayLike | None = None,
        v_prior: ArrayLike | None = None,
        max_steps: int = 500,
        **options: Any,
    ) -> None:
        system = data_scales(check_system(system), x0_prior)
        self.weights, self.certificate, _ = resolve_weights(
            UISEWeights, certificate, weights, None, lambda w: w.check(system), needs_horizon=False
        )
        self.max_steps = check_int(max_steps, "max_steps", low=1)
        super().__init__(system, WindowModel.from_system(system), schedule=self.weights.schedule(), N=None,
                         x0_prior=x0_prior, v_prior=v_prior, options=options)  # fmt: skip

    def step(self, u_prev: ArrayLike | None, y: ArrayLike) -> StepEstimate:
        """As :meth:`WindowEstimator.step`; raises :class:`OptionError` beyond ``max_steps``."""
        self._check_length(self._k)
        return super().step(u_prev, y)

    def run(self, u: ArrayLike | None, y: ArrayLike, *, x0_prior: ArrayLike | None = None) -> EstimationResult:
        """As :meth:`WindowEstimator.run`; a record longer than ``max_steps`` is refused before any work."""
        _, y_arr = check_run_data(self.system, u, y)
        self._check_length(y_arr.shape[0] - 1)
        return super().run(u, y, x0_prior=x0_prior)

    def _check_length(self, k: int) -> None:
        if k > self.max_steps:
            raise OptionError(
                f"max_steps: the FIE builds one problem per length, so its time grows with the square of the "
                f"record; k = {k} exceeds max_steps = {self.max_steps}. Raise max_steps, or use a UISE (its window "
                "stays N long)"
            )

    @property
    def guarantee(self) -> Guarantee:
        """Lemma 3.3's bound per state (:func:`~uiest.estimators.bounds.strong_bound` with N None), or why none."""
        if self.certificate is None:
            return self._no_guarantee(self.theorem, "explicit weights without a strong-detectability certificate")
        bound, settling = strong_bound(self.weights.P, self.weights.R_v, self.weights.mu, None, self.system.v.bounds,
                                       self.v_prior, self.system.x.bounds.width)  # fmt: skip
        assumes = (
            f"mu={self.weights.mu:.4g}; noise in V around v_prior {np.round(self.v_prior, 12).tolist()}, the true "
            "state in X, every output measured and every problem solved to optimality; any unknown input"
        )
        return self._holds(self.theorem, bound, settling, assumes)

    def __repr__(self) -> str:
        return f"FIE(system={self.system.name!r}, mu={self.weights.mu:.4g}, guarantee={str(self.guarantee)!r})"
