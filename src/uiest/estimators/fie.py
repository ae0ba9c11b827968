r"""The full information estimator of Lemma 3.3 of Guo et al. (Eq. (6), Eq. (7); see the theory map).

Index convention::

    x[k+1] = f(x[k], u[k], w[k]),   y[k] = h(x[k], v[k])
    x_hat[k] = x^*_{k|k}  from  x_bar_0, u[0 .. k-1], y[0 .. k]    (growing window, N_k = k, while k <= H)
    w_hat[k-1] = w^*_{k-1|k}

(``H``: where the window stops growing, below.) Cost: Eq. (7) with the comparison functions a quadratic
strong-detectability certificate implies (iterating Eq. (5b) as in the proof of Theorem 3.2):
``alpha_0(r, k) = mu^k |r|_P^2``, ``alpha_v(r, j) = 2 mu^{j-1} |r|_{R_v}^2``,
``alpha_y(r, j) = 2 mu^{j-1} |r|_{R_y}^2``, so that::

    J_k = mu^k 4 |x_{0|k} - x_bar_0|_P^2
          + sum_{j=0}^{k} mu^{j-1} ( 8 |v_{k-j|k} - v_bar|_{R_v}^2 + 2 |y_{k-j} - h(x_{k-j|k}, v_{k-j|k})|_{R_y}^2 ),

the UISE's cost Eq. (11) with the window reaching back to time 0. The FIE and the UISE
therefore solve the same problem while ``k <= N``, which makes the FIE a cross-check of the
moving-horizon machinery (and an offline estimator).

Its window stops growing at its information horizon ``H`` (:mod:`uiest.estimators.horizon`): beyond it, the
oldest cost terms (the prior's ``mu^k`` first) fall below double precision against the newest, so the exact FIE
cannot be told apart from its neighbours in floating point, directions only those terms determine turn flat, and
the solvers fail or stall there (crop model, mu = 0.48, H = 30, 120 samples: IPOPT failed 24 samples, the
``gn-riccati`` backend handed 6 to IPOPT, ``gn`` 16 with 1 failure). From ``k = H`` on the window slides with
``N = H`` and the UISE's prior (Eq. (12)): ``x_hat[k]`` from ``x_hat[k-H]``, ``u[k-H .. k-1]``, ``y[k-H .. k]``.
The FIE is then the UISE with ``N = H`` and the same weights, and its guarantee is Theorem 3.6's for that N,
stated as such (:attr:`~uiest.guarantee.Guarantee.grows`); where ``H`` is below the certificate's
``min_horizon()``, it has none. One problem is built per window length and the window's data are kept, so building
takes time that grows with the square of ``min(k, H)`` (design notes: input checks). Where ``H`` exceeds the
longest window memory allows (:func:`~uiest.window.size.max_horizon`; crop model at mu = 0.999: 34,640 against
16,383), the window does not stop growing and the guarantee is Lemma 3.3's, for the exact FIE. ``max_steps``
(default 500) bounds the growth: a record longer than it raises :class:`OptionError` before any work, pointing to
the UISE, whose window stays N long, unless the window stops growing at or before it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from uiest.checks import check_int
from uiest.errors import OptionError
from uiest.estimators.base import WindowEstimator
from uiest.estimators.bounds import strong_bound
from uiest.estimators.horizon import information_horizon
from uiest.estimators.uise import check_system
from uiest.estimators.weights import StrongCertificate, UISEWeights, resolve_weights
from uiest.guarantee import Guarantee
from uiest.results import EstimationResult, StepEstimate
from uiest.run_data import check_run_data
from uiest.scales import data_scales
from uiest.system import System
from uiest.theory import FIE_GUARANTEE, FULL_ORDER_GUARANTEE, FULL_ORDER_HORIZON
from uiest.window import WindowModel
from uiest.window.size import max_horizon

__all__ = ["FIE"]


class FIE(WindowEstimator):
    r"""Full information estimator (Lemma 3.3 of Guo et al.): window from time 0, cost Eq. (7), up to its horizon.

    Index convention::

        x[k+1] = f(x[k], u[k], w[k]),  y[k] = h(x[k], v[k]),  N_k = min(k, N)
        x_hat[k]   = x^*_{k|k}    from x_bar_0, u[0 .. k-1], y[0 .. k]         (k <= N)
                                  from x_hat[k-N], u[k-N .. k-1], y[k-N .. k]   (k > N: the UISE with N)
        w_hat[k-1] = w^*_{k-1|k}

    Parameters as for :class:`~uiest.estimators.UISE`, without N, and ``max_steps``: the longest
    record (k at most this) the FIE accepts when its window would grow beyond it (no information horizon, or a
    longer one); building grows with the square of the window (module docstring).

    Attributes
    ----------
    N : int or None
        Where the window stops growing: its information horizon (None where that exceeds the longest window
        memory allows: the window grows without bound).
    theorem : str
        Lemma 3.3, the FIE's; :attr:`guarantee` names Theorem 3.6 where the window stops growing.

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
        model, schedule = WindowModel.from_system(system), self.weights.schedule()
        horizon = information_horizon(schedule, model, one_step_ahead=False).horizon
        stops = horizon is not None and horizon <= max_horizon(model)  # else it grows (max_steps bounds it)
        super().__init__(system, model, schedule=schedule, N=horizon if stops else None, x0_prior=x0_prior,
                         v_prior=v_prior, options=options)  # fmt: skip
        self.requested_N = None  # a window from time 0; N, if set, is where it stops growing

    def step(self, u_prev: ArrayLike | None, y: ArrayLike) -> StepEstimate:
        """As :meth:`WindowEstimator.step`; :class:`OptionError` beyond ``max_steps`` if the window grows further."""
        self._check_length(self._k)
        return super().step(u_prev, y)

    def run(self, u: ArrayLike | None, y: ArrayLike, *, x0_prior: ArrayLike | None = None) -> EstimationResult:
        """As :meth:`WindowEstimator.run`; a record beyond ``max_steps`` is refused first if the window grows on."""
        _, y_arr = check_run_data(self.system, u, y)
        self._check_length(y_arr.shape[0] - 1)
        return super().run(u, y, x0_prior=x0_prior)

    @property
    def horizon_capped(self) -> bool:
        """Whether the window stops growing (at :attr:`N`, the information horizon)."""
        return self.N is not None

    def _horizon_fields(self) -> dict[str, Any]:
        return {**super()._horizon_fields(), "grows": True}

    def _horizon_missing(self, certificate_kind: str, horizon_eq: str) -> str:
        certificate = self.certificate
        if certificate is not None and self.N is not None and certificate.min_horizon() > self.N:
            return (f"its window stops growing at N={self.N}, below min_horizon()={certificate.min_horizon()} "
                    f"({horizon_eq}), and beyond N the exact FIE cannot be solved in double precision; weights "
                    "spanning fewer orders of magnitude would lift N")  # fmt: skip
        return super()._horizon_missing(certificate_kind, horizon_eq)

    def _check_length(self, k: int) -> None:
        grows_to = "without bound" if self.N is None else f"to N={self.N} (its information horizon)"
        raise_to = "" if self.N is None else f" to at least {self.N}"
        if k > self.max_steps and (self.N is None or self.max_steps < self.N):
            raise OptionError(
                f"max_steps: the FIE builds one problem per window length, so its time grows with the square of "
                f"the window, which grows {grows_to}; k = {k} exceeds max_steps = {self.max_steps}. Raise "
                f"max_steps{raise_to}, or use a UISE (its window stays N long)"
            )

    @property
    def guarantee(self) -> Guarantee:
        """Lemma 3.3's bound per state, or Theorem 3.6's with N where the window stops growing; or why none.

        (:func:`~uiest.estimators.bounds.strong_bound`; the window stops growing at its information horizon, and
        from there the FIE is the UISE with that N.)
        """
        theorem = self.theorem if self.N is None else FULL_ORDER_GUARANTEE  # from k = N on, the UISE's
        missing = self._horizon_missing("strong-detectability", FULL_ORDER_HORIZON)
        if missing:
            return self._no_guarantee(theorem, missing)
        bound, settling = strong_bound(self.weights.P, self.weights.R_v, self.weights.mu, self.N, self.system.v.bounds,
                                       self.v_prior, self.system.x.bounds.width)  # fmt: skip
        window = "" if self.N is None else f", the window N={self.N} from k={self.N} on"
        assumes = (
            f"mu={self.weights.mu:.4g}{window}; noise in V around v_prior {np.round(self.v_prior, 12).tolist()}, the "
            "true state in X, every output measured and every problem solved to optimality; any unknown input"
        )
        return self._holds(theorem, bound, settling, assumes)

    def __repr__(self) -> str:
        return (
            f"FIE(system={self.system.name!r}, mu={self.weights.mu:.4g}, N={self.N}, guarantee={str(self.guarantee)!r})"
        )
