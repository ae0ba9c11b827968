r"""The standard MHE's weights from the data alone: its disturbance variance by the prediction-error method.

The standard MHE (:class:`~uiest.estimators.StandardMHE`) treats the unknown input as a disturbance around its
prior ``w_bar``; with Gaussian weights (:meth:`MHEWeights.from_variances
<uiest.estimators.MHEWeights.from_variances>`) its cost is the negative log-posterior of the model::

    x[k+1] = f(x[k], u[k], w[k]),   w[k] ~ N(w_bar, Sigma_w) independent,   y[k] = h(x[k], v[k]),  v ~ N(v_bar, Sigma_v)

(a white disturbance, not the Kalman filters' random walk). :func:`fit_standard_mhe` chooses ``Sigma_w = q
diag(w.scale^2)`` by the likelihood of that model's innovations on the record (:mod:`uiest.likelihood`), computed by
an extended Kalman filter of the same model, and returns the MHE with those weights and the profile. The window's
prior weight is the inverse of that filter's settled covariance (:func:`arrival_covariance`, the classical EKF arrival
cost held fixed): with ``P0^-1``, a prior that never tightens, the window can explain a persistent unknown input by
moving its oldest state instead.
"""

from __future__ import annotations

import warnings
from typing import Any, TypeVar

import numpy as np
from numpy.typing import ArrayLike

from uiest.box import FloatArray
from uiest.errors import OptionError
from uiest.estimators.design_search import ERROR_TOLERANCE
from uiest.estimators.kalman import EKF
from uiest.estimators.standard_mhe import StandardMHE
from uiest.estimators.weights import MHEWeights
from uiest.health import quiet_bound_warnings
from uiest.likelihood import GRID_EXTENSION, ProfileShape, Score, check_grid, maximise_likelihood
from uiest.run_data import check_run_data
from uiest.system import System

SMOOTH_DISCOUNTS = (0.95, 0.99)
"""Discounts ``uiest estimate`` tries for the data-tuned smooth-input MHE beside its design's eta (those above it),
choosing by :func:`prediction_error`."""

ARRIVAL_FLOOR = 1e-6
"""The smallest standard deviation, in scales of x, of :func:`arrival_covariance` along any direction (a window solve
resolves about 1e-8 of a scale)."""


class WhiteInputEKF(EKF):
    """The EKF of the standard MHE's model: ``w[k] ~ N(w0, w_variance)`` independent (not a random walk).

    The augmented ``d[k] = w[k]`` is drawn afresh at every step: after each prediction its mean is ``w0`` and its
    covariance ``w_variance``, uncorrelated with x (``W0`` defaults to ``w_variance``). Its ``w_hat`` is therefore the
    prior ``w0``; it serves to score the model's likelihood (:attr:`log_likelihood`), not to estimate w.
    """

    estimator_name = "EKF (white input)"

    def __init__(self, system: System, *, w_variance: ArrayLike, W0: ArrayLike | None = None, **keywords: Any) -> None:
        if "input_model" in keywords or "W0_rate" in keywords:
            raise OptionError("input_model, W0_rate: the white-input EKF's input is drawn afresh at every step")
        super().__init__(system, w_variance=w_variance, W0=w_variance if W0 is None else W0, **keywords)

    def _predict(self, z: FloatArray, P: FloatArray, u: FloatArray, inside: bool) -> tuple[FloatArray, FloatArray]:
        z_next, P_next = super()._predict(z, P, u, inside)
        n = self.system.nx
        z_next[n:] = self.w0
        P_next[n:, :] = 0.0
        P_next[:, n:] = 0.0
        P_next[n:, n:] = self.Q[n:, n:]
        return z_next, P_next


def fit_standard_mhe(
    system: System,
    u: ArrayLike | None,
    y: ArrayLike,
    *,
    x0_prior: ArrayLike,
    N: int,
    eta: float,
    variances: ArrayLike | None = None,
    v_covariance: ArrayLike | None = None,
    P0: ArrayLike | None = None,
    **options: Any,
) -> StandardMHE:
    """The standard MHE whose disturbance variance maximises the likelihood of the record (u, y) (module docstring).

    Parameters
    ----------
    system : System
    u : array_like (K, nu) or None
    y : array_like (K+1, ny)
        The record (NaN: missing, dropped per step); no true states needed.
    x0_prior : array_like (nx,)
    N : int
        The MHE's horizon.
    eta : float
        Its discount in (0, 1) (1 would make the cost the exact negative log-posterior of the window).
    variances : array_like, optional
        Factors ``q`` of ``w.scale^2`` to try (default :data:`~uiest.likelihood.DEFAULT_GRID`, grown beyond an end
        where the likelihood is largest, :data:`~uiest.likelihood.GRID_EXTENSION`; refined).
    v_covariance, P0 : array_like, optional
        As for the Kalman filters (defaults: V's uniform variance, ``x.scale^2 / 12``); held fixed. ``P0`` is the
        filter's prior of x[0]; the window's prior weight is ``arrival_covariance()^-1``.
    **options
        For :class:`~uiest.estimators.StandardMHE` (``solver``, ``lag``, ...).

    Returns
    -------
    StandardMHE
        With :func:`likelihood_weights` at the chosen variance (explicit weights: no guarantee) and
        ``likelihood``, the :class:`~uiest.likelihood.LikelihoodProfile`. Warns (``UserWarning``) when the profile
        is flat or largest at an end of the grid.

    """
    u_arr, y_arr = check_run_data(system, u, y)
    grid = check_grid(variances)
    scale2 = system.w.scale**2

    def score(factor: float) -> Score:
        return WhiteInputEKF(system, w_variance=factor * scale2, x0_prior=x0_prior, v_covariance=v_covariance,
                             P0=P0).score(u_arr, y_arr)  # fmt: skip

    profile = maximise_likelihood(score, grid, name="w_variance", unit="w.scale^2", scale=system.w.scale,
                                  extend=GRID_EXTENSION if variances is None else 0)  # fmt: skip
    if profile.shape is ProfileShape.FLAT or profile.at_end:
        warnings.warn(f"fit_standard_mhe: {profile.summary()}", UserWarning, stacklevel=2)
    weights = likelihood_weights(system, u_arr, y_arr, x0_prior=x0_prior, eta=eta, w_variance=profile.variance,
                                 v_covariance=v_covariance, P0=P0)  # fmt: skip
    mhe = StandardMHE(system, weights=weights, N=N, x0_prior=x0_prior, **options)
    mhe.likelihood = profile
    return mhe


def likelihood_weights(
    system: System,
    u: ArrayLike | None,
    y: ArrayLike,
    *,
    x0_prior: ArrayLike,
    eta: float,
    w_variance: ArrayLike,
    v_covariance: ArrayLike | None = None,
    P0: ArrayLike | None = None,
) -> MHEWeights:
    """The standard MHE's Gaussian weights for a given disturbance covariance ``w_variance`` (module docstring).

    :meth:`MHEWeights.from_variances <uiest.estimators.MHEWeights.from_variances>` with the window prior's covariance
    from :func:`arrival_covariance` of the :class:`WhiteInputEKF` with ``w_variance`` run over the record (u, y).
    """
    u_arr, y_arr = check_run_data(system, u, y)
    white = WhiteInputEKF(system, w_variance=w_variance, x0_prior=x0_prior, v_covariance=v_covariance, P0=P0)
    return MHEWeights.from_variances(system, eta, w_variance=w_variance, v_covariance=v_covariance,
                                     P0=arrival_covariance(white, u_arr, y_arr), at=x0_prior)  # fmt: skip


Key = TypeVar("Key")


def prediction_error(system: System, x_hat: FloatArray, w_hat: FloatArray, u: FloatArray, y: FloatArray,
                     first: int | None = None) -> float:  # fmt: skip
    """The RMS one-step output prediction error of a run over the record's second half, in output scales.

    ``y[k+1] - h(f(x_hat[k], u[k], w))`` (no noise) for ``k = first .. K - 1`` (default ``first = K // 2``: the
    second half, past the transient from the prior; 0: the whole record), with ``w`` the newest estimate of the
    unknown input at time k (``w_hat[k-1]``, else ``w_hat[k-2]``, else ``nominal_w``): x_hat[k] has seen ``y[..k]``
    only, so this scores an estimator without the true states. ``x_hat (K+1, nx)``, ``w_hat (K, nw)``, ``u (K, nu)``,
    ``y (K+1, ny)``; missing outputs are left out; inf where no output or prediction is finite.
    """
    K = len(y) - 1
    ks = np.arange(K // 2 if first is None else first, K)
    w = np.tile(system.nominal_w, (len(ks), 1))
    for lag in (2, 1):  # the newer finite estimate overwrites the older
        j = ks - lag
        usable = np.flatnonzero((j >= 0) & (j < len(w_hat)))
        usable = usable[np.all(np.isfinite(w_hat[j[usable]]), axis=1)]
        w[usable] = w_hat[j[usable]]
    keep = np.all(np.isfinite(x_hat[ks]), axis=1)
    if not keep.any():
        return float("inf")
    with np.errstate(all="ignore"):
        predicted = system.output(system.step(x_hat[ks[keep]], u[ks[keep]], w[keep]))
        squares = np.square((y[ks[keep] + 1] - predicted) / system.y.scale)
    if not np.isfinite(squares).any():
        return float("inf")
    return float(np.sqrt(np.nanmean(np.where(np.isfinite(squares), squares, np.nan))))


def preferred_discount(errors: dict[Key, float], design: Key) -> Key:
    """The candidate to use of ``errors`` (an eta, or any key -> :func:`prediction_error`).

    The design's, unless another's error is smaller by more than the design search's ``ERROR_TOLERANCE`` (a
    smaller difference is within a record's scatter).
    """
    best = min(errors, key=lambda eta: errors[eta])
    return best if errors[best] * ERROR_TOLERANCE < errors[design] else design


def arrival_covariance(estimator: EKF, u: FloatArray, y: FloatArray, *, with_input: bool = False) -> FloatArray:
    """The mean posterior covariance of x (nx, nx) of ``estimator``'s steps over the second half of the record.

    ``u (K, nu)``, ``y (K+1, ny)`` checked; the filter starts from its prior. It is the window prior's covariance of
    :func:`fit_standard_mhe`: the uncertainty of an estimate after the filter has settled (the first half holds the
    transient from ``P0``). A direction the filter knows exactly (a state without process noise that the outputs
    pin down) is given a standard deviation of ``ARRIVAL_FLOOR`` scales, so that the weight stays finite.
    ``with_input``: the covariance of ``(x, w)`` (nx + nw, nx + nw) instead, the filter's random-walk input included
    (the smooth-input MHE's window prior; w in scales of w).
    """
    return arrival_covariances(estimator, u, y, with_input=with_input)[0]


def arrival_covariances(
    estimator: EKF, u: FloatArray, y: FloatArray, *, with_input: bool = False
) -> tuple[FloatArray, FloatArray]:
    """:func:`arrival_covariance`, and the uncertainty of what the window that starts at time k starts from, k = 0..K.

    (K+1, n, n): at k = 0 the filter's prior covariance (the window's prior is x[0]'s), at k >= 1 its posterior
    covariance after y[k] (the window's prior is the estimate delivered at time k), floored as the settled one; where
    it is not finite, the settled one.
    """
    estimator.reset()
    system = estimator.system
    n, K = system.nx + (system.nw if with_input else 0), len(y) - 1
    scale = np.concatenate([system.x.scale, system.w.scale]) if with_input else system.x.scale
    outer = np.outer(scale, scale)

    def floored(P: FloatArray) -> FloatArray:
        values, vectors = np.linalg.eigh(0.5 * (P + P.T) / outer)
        return (vectors * np.maximum(values, ARRIVAL_FLOOR**2)) @ vectors.T * outer

    total, count = np.zeros((n, n)), 0
    starts = np.full((K + 1, n, n), np.nan)
    starts[0] = floored(estimator._prior_covariance()[:n, :n])
    with quiet_bound_warnings():
        for k in range(K + 1):
            estimator.step(None if k == 0 else u[k - 1], y[k])
            P = estimator.covariance
            if P is None or not np.all(np.isfinite(P)):
                continue
            if k:
                starts[k] = floored(P[:n, :n])
            if k >= K // 2:
                total += P[:n, :n]
                count += 1
    if not count:
        raise OptionError("P0: the filter of the chosen variance has no finite covariance on the record's second half")
    settled = floored(total / count)
    starts[~np.all(np.isfinite(starts), axis=(1, 2))] = settled
    return settled, starts


__all__ = ["WhiteInputEKF", "arrival_covariance", "arrival_covariances", "fit_standard_mhe", "likelihood_weights"]
