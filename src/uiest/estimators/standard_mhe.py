r"""The standard robust MHE of Schiller et al. 2023 (the paper's baseline), one-step-ahead.

J. D. Schiller, S. Muntwiler, J. Koehler, M. N. Zeilinger, M. A. Mueller, "A Lyapunov function for
robust stability of moving horizon estimation", IEEE TAC 68(12), 2023, eq. (6); see
``shared/notes/references.md`` section 1.

Index convention::

    x[k+1] = f(x[k], u[k], w[k]),   y[k] = h(x[k], v[k])
    x_hat[k] = x^*_{k|k}  from  u[k-N_k .. k-1], y[k-N_k .. k-1]   (one-step-ahead: y[k] is not used)
    w_hat[k-2] = w^*_{k-2|k}        (the newest transition a measurement informs; w_hat[K-1] is NaN)
    N_k = min(N, k)

Cost (their eq. (6) with their generalised disturbance split into the unknown input w, treated
as a bounded disturbance with prior ``w_bar``, and the measurement noise v)::

    J = 2 eta^{N_k} |x_{k-N_k|k} - x_hat_{k-N_k}|_P^2
        + sum_{j=1}^{N_k} eta^{j-1} ( 2 |w_{k-j|k} - w_bar|_{Q_w}^2 + 2 |v_{k-j|k} - v_bar|_{Q_v}^2
                                      + |h(x_{k-j|k}, v_{k-j|k}) - y_{k-j}|_R^2 )

subject to the dynamics, ``x_{j|k}`` in X at every node, ``v_{j|k}`` in V and ``w_{j|k}`` in the
known range ``system.w_range`` (when the system has one). The prior ``x_hat_{k-N_k}`` is the
estimate delivered at time ``k-N_k`` (``x_bar_0`` at time 0), as in their filtering prior.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from uiest.box import as_vector
from uiest.checks import check_flag
from uiest.errors import DataError
from uiest.estimators.base import WindowEstimator
from uiest.estimators.bounds import mhe_bound
from uiest.estimators.uise import check_system
from uiest.estimators.weights import DeltaCertificate, MHEWeights, resolve_weights
from uiest.guarantee import Guarantee
from uiest.likelihood import LikelihoodProfile
from uiest.scales import data_scales
from uiest.system import System
from uiest.window import WindowModel

__all__ = ["SPAN", "StandardMHE", "span_normalised"]

SPAN = 1e8
"""Largest ratio between the window's newest and oldest discount the standard MHE keeps (``normalise``)."""


def span_normalised(weights: MHEWeights, N: int, normalise: bool) -> MHEWeights:
    """``weights`` with eta raised to ``SPAN^(-1/N)`` when ``normalise`` and it is smaller (see StandardMHE)."""
    floor = SPAN ** (-1.0 / N)
    return replace(weights, eta=floor) if normalise and weights.eta < floor else weights


class StandardMHE(WindowEstimator):
    r"""Robust MHE of Schiller et al. 2023 (eq. (6)), one-step-ahead; the unknown input is a bounded disturbance.

    Index convention::

        x[k+1] = f(x[k], u[k], w[k]),  y[k] = h(x[k], v[k]),  N_k = min(N, k)
        x_hat[k]   = x^*_{k|k}    from u[k-N_k .. k-1], y[k-N_k .. k-1]  (y[k] not used)
        w_hat[k-2] = w^*_{k-2|k}  (w_{k-1|k} is informed by no measurement; w_hat[K-1] is NaN)

    See the module docstring for the cost.

    Parameters
    ----------
    system : System
    certificate : DeltaIOSS, optional
        Anything with ``certified, eta, P, Q_w, Q_v, R, min_horizon()``; gives the weights and
        the default horizon.
    weights : MHEWeights, optional
        Explicit weights instead (then N is required and no guarantee is claimed).
    N : int, optional
        Horizon >= 1; default ``certificate.min_horizon()``.
    x0_prior : array_like (nx,), optional
        Prior of x[0] in X.
    w_prior : array_like (nw,), optional
        Prior ``w_bar`` of the unknown input (default ``system.nominal_w``: the centre of the
        known range, else 0); must lie in the known range.
    v_prior : array_like (nv,), optional
        Noise prior in V (default 0).
    use_w_range : bool
        Constrain the unknown-input estimates to ``system.w_range`` (default True, as in the paper).
    normalise : bool, optional
        Default: True with a certificate, False with explicit weights (the user's eta is kept).
        Raise eta to ``SPAN^(-1/N)`` when it is smaller, so that the window's weights span at
        most ``SPAN = 1e8`` (a certified eta ~ 2e-4 with N = 10 spans 37 orders of magnitude and
        the solves fail). The guarantee survives: a delta-IOSS bound with eta holds with any
        larger eta', and Schiller et al.'s horizon for eta' = SPAN^(-1/N),
        ``floor(log 4 N / log SPAN) + 1``, is at most N. :attr:`eta_given` keeps the original.
    **options
        As for :class:`~uiest.estimators.UISE`.

    """

    estimator_name = "StandardMHE"
    theorem = "robust MHE theorem (Schiller et al. 2023)"
    one_step_ahead = True
    likelihood: LikelihoodProfile | None = None
    """The likelihood profile of its disturbance variance when built by :func:`uiest.tuning.fit_standard_mhe`."""

    def __init__(
        self,
        system: System,
        *,
        certificate: DeltaCertificate | None = None,
        weights: MHEWeights | None = None,
        N: int | None = None,
        x0_prior: ArrayLike | None = None,
        w_prior: ArrayLike | None = None,
        v_prior: ArrayLike | None = None,
        use_w_range: bool = True,
        normalise: bool | None = None,
        **options: Any,
    ) -> None:
        use_w_range = check_flag(use_w_range, "use_w_range")
        normalise = check_flag(normalise, "normalise", optional=True)
        system = data_scales(check_system(system), x0_prior)
        self.weights, self.certificate, N = resolve_weights(
            MHEWeights, certificate, weights, N, lambda w: w.check(system)
        )
        self.eta_given = self.weights.eta
        self.weights = span_normalised(self.weights, N, certificate is not None if normalise is None else normalise)
        self.w_range = system.w_range if use_w_range else None
        w_bar = system.nominal_w if w_prior is None else as_vector(w_prior, system.nw, "w_prior")
        if self.w_range is not None and not self.w_range.contains(w_bar):
            raise DataError(f"w_prior: expected a point in the known range {self.w_range}, got {w_bar.tolist()}")
        super().__init__(system, WindowModel.from_system(system), schedule=self.weights.schedule(), N=N,
                         x0_prior=x0_prior, v_prior=v_prior, options=options, w_box=self.w_range,
                         w_prior=w_bar)  # fmt: skip

    @property
    def guarantee(self) -> Guarantee:
        """Schiller et al.'s bound per state (:func:`~uiest.estimators.bounds.mhe_bound`), or why it does not apply.

        It holds while the unknown input stays in the range the certificate covers (its ``w_box``,
        else ``system.w_range``; without either, no finite bound) and, unlike the UISEs', does not
        vanish when the noise does.
        """
        if self.certificate is None:
            return self._no_guarantee(self.theorem, "explicit weights without a delta-IOSS certificate")
        eta = self.weights.eta
        n_min = int(np.floor(np.log(4.0) / np.log(1.0 / eta))) + 1  # their eq. (16) with P1 = P2, at the eta used
        if self.N is not None and n_min > self.N:
            return self._no_guarantee(self.theorem, f"N={self.N} < min_horizon()={n_min} (Schiller et al. 2023, "
                                      "eq. (16))")  # fmt: skip
        assert self.N is not None
        w_range = getattr(self.certificate, "w_box", None)
        w_range = self.system.w_range if w_range is None else w_range
        w = self.weights
        bound, settling = mhe_bound(w.P, w.Q_w, w.Q_v, eta, self.N, w_range, self.w_prior, self.system.v.bounds,
                                    self.v_prior, self.system.x.bounds.width)  # fmt: skip
        raised = "" if eta == self.eta_given else f" (the certificate's {self.eta_given:.3g} raised, see normalise)"
        assumes = (
            f"eta={eta:.4g}{raised}, N={self.N}; the unknown input in {w_range} around w_prior "
            f"{np.round(self.w_prior, 12).tolist()}, noise in V around v_prior {np.round(self.v_prior, 12).tolist()}, "
            "the true state in X, every output measured and every window problem solved to optimality"
        )
        note = (
            "the unknown input has no known range (system.w_range or the certificate's w_box)"
            if w_range is None
            else ""
        )
        within = "" if w_range is None else "w in " + " x ".join(
            f"[{lo:.4g}, {hi:.4g}]" for lo, hi in zip(w_range.lower, w_range.upper, strict=True))  # fmt: skip
        return self._holds(self.theorem, bound, settling, assumes, note, condition=within)

    def __repr__(self) -> str:
        return (
            f"StandardMHE(system={self.system.name!r}, N={self.N}, eta={self.weights.eta:.4g}, "
            f"w_range={self.w_range}, guarantee={str(self.guarantee)!r})"
        )
