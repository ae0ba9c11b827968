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

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from uiest.box import Box, FloatArray, as_vector
from uiest.errors import DataError, OptionError
from uiest.estimators.base import WindowEstimator
from uiest.estimators.checks import check_horizon
from uiest.estimators.weights import DeltaCertificate, MHEWeights
from uiest.system import System
from uiest.window import DEFAULT_BACKEND, WindowWeights


def mhe_window_weights(weights: MHEWeights, length: int) -> WindowWeights:
    """Residual weights of Schiller et al. eq. (6) for a window of ``length`` transitions.

    Measured node ``i`` (``y`` at time ``k - length + i``, i < length) and transition ``i`` have
    ``j = length - i``: output weight ``eta^{j-1} R``, noise ``2 eta^{j-1} Q_v``, unknown input
    ``2 eta^{j-1} Q_w``; the prior weight is ``2 eta^length P``.
    """
    eta = weights.eta
    discounts = eta ** (length - np.arange(length) - 1.0)
    return WindowWeights(
        prior=2.0 * eta**length * weights.P,
        y=discounts[:, None, None] * weights.R,
        v=2.0 * discounts[:, None, None] * weights.Q_v,
        w=2.0 * discounts[:, None, None] * weights.Q_w,
    )


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
    solver, solver_options, warm_start, strict
        As for :class:`~uiest.estimators.UISE`.

    """

    estimator_name = "StandardMHE"
    one_step_ahead = True

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
        solver: str = DEFAULT_BACKEND,
        solver_options: Mapping[str, Any] | None = None,
        warm_start: bool = True,
        strict: bool = False,
    ) -> None:
        if not isinstance(system, System):
            raise OptionError(f"system: expected a uiest.System, got {type(system).__name__}")
        if (certificate is None) == (weights is None):
            raise OptionError("certificate, weights: expected exactly one of them")
        if weights is not None and not isinstance(weights, MHEWeights):
            raise OptionError(f"weights: expected an MHEWeights, got {type(weights).__name__}")
        resolved = MHEWeights.from_certificate(certificate) if certificate is not None else weights
        assert resolved is not None  # exactly one was given
        resolved.check(system)
        self.weights, self.certificate = resolved, certificate
        if N is None:
            if certificate is None:
                raise OptionError("N: required with explicit weights (no certificate to take min_horizon() from)")
            N = certificate.min_horizon()
        check_horizon(N)
        self.w_range = system.w_range if use_w_range else None
        w_bar = system.nominal_w if w_prior is None else as_vector(w_prior, system.nw, "w_prior")
        if self.w_range is not None and not self.w_range.contains(w_bar):
            raise DataError(f"w_prior: expected a point in the known range {self.w_range}, got {w_bar.tolist()}")
        self.w_prior = w_bar
        super().__init__(
            system,
            N=N,
            x0_prior=x0_prior,
            v_prior=v_prior,
            solver=solver,
            solver_options=solver_options,
            warm_start=warm_start,
            strict=strict,
        )

    def _window_weights(self, length: int) -> WindowWeights:
        return mhe_window_weights(self.weights, length)

    def _w_box(self) -> Box | None:
        return self.w_range

    def _w_bar(self) -> FloatArray:
        return self.w_prior

    @property
    def guarantee(self) -> str:
        """What Schiller et al.'s theorem gives here, or why it does not apply."""
        if self.certificate is None:
            return "none: explicit weights without a delta-IOSS certificate"
        n_min = self.certificate.min_horizon()
        horizon = self.N
        if horizon is not None and horizon < n_min:
            return f"none: N={self.N} < min_horizon()={n_min} (Schiller et al. 2023, eq. (16))"
        return (
            f"Schiller et al. 2023 robust stability with eta={self.weights.eta:.4g}, N={self.N} >= {n_min}: the "
            "error is bounded by a decaying function of the initial error plus a function of |w - w_bar| and "
            "|v - v_bar|; it does not converge when the unknown input does not"
        )

    def __repr__(self) -> str:
        return (
            f"StandardMHE(system={self.system.name!r}, N={self.N}, eta={self.weights.eta:.4g}, "
            f"w_range={self.w_range}, guaranteed={self.guaranteed})"
        )
