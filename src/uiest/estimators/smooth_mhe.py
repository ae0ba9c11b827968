r"""The smooth-input MHE: the unknown input as a state whose increments are bounded and penalised.

The augmented model (:func:`uiest.augmented.augmented_system`), state ``z = (x, w)`` in X x W::

    x[k+1] = f(x[k], u[k], w[k]),   w[k+1] = w[k] + dw[k],   y[k] = h(x[k], v[k]),   |dw[k]| <= dw_bound

Index convention (time-first arrays; ``u[k]`` and ``w[k]`` act between k and k+1)::

    x_hat[k]   = x^*_{k|k}   from  u[k-N_k .. k-1], y[k-N_k .. k]     (current measurement included)
    w_hat[k-1] = w^*_{k-1|k}                                        (the w part of node k-1 of the window at k)
    N_k = min(N, k)

Cost at time k (the standard MHE's, Schiller et al. 2023 eq. (6), on the augmented model, with the
current output added; node time ``k-j``)::

    J = 2 eta^{N_k} |z_{k-N_k|k} - z_hat_{k-N_k}|_P^2
        + sum_{j=1}^{N_k} eta^{j-1} 2 |dw_{k-j|k} - dw_bar|_{Q_w}^2
        + sum_{j=0}^{N_k} eta^{j-1} ( 2 |v_{k-j|k} - v_bar|_{Q_v}^2 + |h(x_{k-j|k}, v_{k-j|k}) - y_{k-j}|_R^2 )

subject to the augmented dynamics, ``z_{j|k}`` in X x W, ``v_{j|k}`` in V and, with
``constrain_increments``, ``dw_{j|k}`` in ``[-dw_bound, dw_bound]``. The prior ``z_hat_{k-N_k}`` is
the window's estimate delivered at time ``k-N_k`` (``(x0_prior, w0_prior)`` at time 0).

Weights (:func:`variance_weights`): the cost is twice the negative log-likelihood of Gaussian
increments and noise, ``2 Q_w = Sigma_dw^-1`` (``dw_variance``), ``Q_v = Sigma_v^-1`` and
``R = 2 diag(D Sigma_v D^T)^-1`` (``D = dh/dv``: the noise and the output residual in series weigh an
output mismatch of a model ``h(x) + v`` by ``Sigma_y^-1``); ``Sigma_v`` is V's uniform variance
``width^2 / 12`` (``v.scale^2`` where V is unbounded), as for the EKF. With a delta-IOSS certificate
``(eta, P_c, Q_c)`` of the augmented model (Schiller et al.'s Assumption 1, which is homogeneous in
``(P, Q, R)`` and holds with any larger Q and R), the prior weight is ``P = c P_c`` with the largest c
for which ``Q_w >= c Q_w,c``, ``Q_v >= c Q_v,c``, ``R >= c R_c``: the statistical weights keep the
certificate's guarantee (:attr:`SmoothInputMHE.guarantee`).

``dw_variance`` is the EKF's ``w_variance`` (:class:`~uiest.estimators.kalman.EKF` treats the unknown input as
a random walk with exactly this step): a variance tuned for the EKF gives this estimator's weights.
"""

from __future__ import annotations

import warnings
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from uiest.augmented import augmented_system, increment_bound
from uiest.box import Box, FloatArray, as_vector
from uiest.checks import check_flag, check_int, user_stacklevel
from uiest.covariance import noise_variance, output_noise_variance
from uiest.detectability import certify_delta_ioss
from uiest.errors import CertificationError, DataError, ModelError, OptionError
from uiest.estimators.base import WindowEstimator
from uiest.estimators.bounds import mhe_bound
from uiest.estimators.standard_mhe import span_normalised
from uiest.estimators.uise import check_system
from uiest.estimators.weights import DeltaCertificate, MHEWeights, resolve_weights
from uiest.guarantee import Guarantee
from uiest.system import System
from uiest.window import WindowModel, WindowTrajectory

DW_SIGMAS = 3.0
"""Given only a variance, the increments' bound is ``DW_SIGMAS`` standard deviations; given only a bound, the
variance is ``(bound / DW_SIGMAS)^2``."""

DEFAULT_HORIZON = 30
"""N of :meth:`SmoothInputMHE.design` (or the certificate's ``min_horizon()`` when longer): the window is the
estimator's whole memory (its prior is weak beside the data), so a state the outputs see only through the model
gains from a long one."""

MAX_HORIZON = 60
"""The longest certified window :meth:`SmoothInputMHE.design` accepts by default."""

FALLBACK_ETA = 0.8
"""Discount of :meth:`SmoothInputMHE.design`'s explicit weights where the augmented model does not certify."""

NOISE_FLOOR = 1e-6
"""An output without noise (``D Sigma_v D^T`` zero on the diagonal) is weighted as if its noise were this
fraction of its scale."""

CHECK_POINTS = 8
"""Points of X x W at which a certificate's system is compared with the augmented model of ``system``."""


def increments(dw_bound: ArrayLike | None, dw_variance: ArrayLike | None, nw: int) -> tuple[FloatArray, FloatArray]:
    """``(bound, variance)`` per component of dw from either or both (:data:`DW_SIGMAS`); OptionError without."""
    if dw_bound is None and dw_variance is None:
        raise OptionError("dw_bound, dw_variance: expected at least one (the increments' bound or variance)")
    variance = None if dw_variance is None else increment_bound(dw_variance, nw, "dw_variance")
    if dw_bound is not None:
        bound = increment_bound(dw_bound, nw)
    else:
        assert variance is not None  # one of the two is given (checked above)
        bound = DW_SIGMAS * np.sqrt(variance)
    return bound, (bound / DW_SIGMAS) ** 2 if variance is None else variance


def _weight_matrices(value: ArrayLike, n: int, name: str) -> FloatArray:
    """Symmetric positive semi-definite (m, n, n) weights, or OptionError naming ``name``."""
    try:
        stack = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise OptionError(f"{name}: expected (m, {n}, {n}) matrices, got {value!r}") from None
    if stack.ndim != 3 or stack.shape[1:] != (n, n) or not len(stack) or not np.all(np.isfinite(stack)):
        raise OptionError(f"{name}: expected finite (m, {n}, {n}) matrices with m >= 1, got shape {stack.shape}")
    symmetric = 0.5 * (stack + stack.transpose(0, 2, 1))
    if not np.allclose(stack, symmetric) or np.linalg.eigvalsh(symmetric)[:, 0].min() < 0.0:
        raise OptionError(f"{name}: expected symmetric positive semi-definite matrices")
    return symmetric


def variance_weights(augmented: System, dw_variance: ArrayLike, eta: float) -> MHEWeights:
    """The weights of the module docstring: ``Q_w = Sigma_dw^-1 / 2``, ``Q_v = Sigma_v^-1``, ``R = 2 Sigma_y^-1``.

    The prior weight is ``P = Sigma_0^-1 / 2`` with the EKF's prior covariances, ``Sigma_0 = diag(x.scale^2 / 12,
    w.scale^2)`` (the augmented model's states); a certificate replaces it (:func:`certified_weights`).

    Parameters
    ----------
    augmented : System
        The augmented model (:func:`~uiest.augmented.augmented_system`).
    dw_variance : float or array_like (nw,)
        Variance of each increment per sample.
    eta : float
        Discount in (0, 1).

    """
    variance = increment_bound(dw_variance, augmented.nw, "dw_variance")
    sigma_v = noise_variance(augmented)
    sigma_y = output_noise_variance(augmented, NOISE_FLOOR)
    nx = augmented.nx - augmented.nw
    sigma_0 = augmented.x.scale**2 / np.concatenate([np.full(nx, 12.0), np.ones(augmented.nw)])
    return MHEWeights(eta=eta, P=np.diag(0.5 / sigma_0), Q_w=np.diag(0.5 / variance), Q_v=np.diag(1.0 / sigma_v),
                      R=np.diag(2.0 / sigma_y))  # fmt: skip


def certified_weights(certificate: DeltaCertificate, weights: MHEWeights) -> MHEWeights:
    """``weights`` with the certificate's eta and prior ``c P_c``, c the largest with ``c Q_c <= Q`` for Q_w, Q_v, R.

    Raises CertificationError when the certificate does not hold (``MHEWeights.from_certificate``).
    """
    cert = MHEWeights.from_certificate(certificate)
    factor = np.inf
    for mine, theirs in ((weights.Q_w, cert.Q_w), (weights.Q_v, cert.Q_v), (weights.R, cert.R)):
        if not len(mine):
            continue
        root = np.linalg.cholesky(np.linalg.inv(mine))  # mine^-1 = L L^T: c <= 1 / lambda_max(L^T theirs L)
        largest = float(np.linalg.eigvalsh(root.T @ theirs @ root)[-1])
        if largest > 0:
            factor = min(factor, 1.0 / largest)
    if not np.isfinite(factor):
        factor = 1.0  # the certificate weighs nothing: its own scale
    return replace(weights, eta=cert.eta, P=factor * cert.P)


class SmoothInputMHE(WindowEstimator):
    r"""MHE on the augmented model: the unknown input as a state with bounded, penalised increments.

    See the module docstring for the index convention, the cost and the weights.

    Parameters
    ----------
    system : System
        ``x+ = f(x, u, w)``, ``y = h(x, v)`` with ``nw >= 1``.
    certificate : DeltaIOSS, optional
        A delta-IOSS certificate of the augmented model (``certify_delta_ioss(augmented_system(
        system, dw_bound, w_bounds))``): gives eta, the prior's shape, the default horizon and
        the guarantee; the augmented model (and so ``dw_bound`` and W) is its ``system``.
    weights : MHEWeights, optional
        Explicit weights of the augmented model instead (e.g. :func:`variance_weights`); then N is
        required and no guarantee is claimed.
    dw_variance : float or array_like (nw,), optional
        Variance of the increments per sample (the EKF's ``w_variance``); gives ``Q_w``. Default
        ``(dw_bound / DW_SIGMAS)^2``.
    dw_bound : float or array_like (nw,), optional
        ``|dw_i[k]| <= dw_bound_i``, the bound the guarantee assumes (default ``DW_SIGMAS``
        standard deviations). Not with a certificate (its model has it).
    w_bounds : Box or (lower, upper), optional
        W (:func:`~uiest.augmented.input_box`); not with a certificate.
    N : int, optional
        Horizon >= 1; default ``certificate.min_horizon()``.
    x0_prior : array_like (nx,), optional
        Prior of x[0] in X.
    w0_prior : array_like (nw,), optional
        Prior of w[0] in W (default its centre).
    v_prior : array_like (nv,), optional
        Noise prior in V (default 0).
    constrain_increments : bool
        Constrain the estimated increments to ``[-dw_bound, dw_bound]`` (default False: penalised
        only, so a jump beyond the bound is followed within the window). Either way the guarantee
        needs only the true increments within the bound: the augmented model is affine in dw with
        a constant Jacobian, so the certificate's inequality holds for any estimated increment.
    normalise : bool, optional
        As for :class:`~uiest.estimators.StandardMHE` (raise a tiny eta to ``SPAN^(-1/N)``).
    arrival_P : array_like (m, nx + nw, nx + nw), optional
        ``arrival_P[s]``: the prior weight of ``(x[s], w[s])`` in the window that starts at time s, for s < m
        (later windows: the weights' ``P``). A filter's covariances along the record give them
        (:func:`uiest.tuning.arrival_covariances`): the first estimates a window starts from are far less certain
        than the settled ones, and a ``P`` taken from a filter's settled covariance holds a wrong x[0] for hundreds
        of samples.
    **options
        Window options (:class:`~uiest.estimators.WindowOptions`), as keywords or one ``window=WindowOptions(...)``.

    Attributes
    ----------
    w_domain : Box
        W, the range of w the augmented state covers: the estimates ``w_hat`` stay in it, and a run warns
        (:class:`~uiest.errors.BoundWarning`) where they sit at its sides in more than 5 % of the steps.

    """

    estimator_name = "SmoothInputMHE"
    theorem = "robust MHE theorem on the augmented model (Schiller et al. 2023)"

    def __init__(
        self,
        system: System,
        *,
        certificate: DeltaCertificate | None = None,
        weights: MHEWeights | None = None,
        dw_variance: ArrayLike | None = None,
        dw_bound: ArrayLike | None = None,
        w_bounds: Box | tuple[ArrayLike, ArrayLike] | None = None,
        N: int | None = None,
        x0_prior: ArrayLike | None = None,
        w0_prior: ArrayLike | None = None,
        v_prior: ArrayLike | None = None,
        constrain_increments: bool = False,
        normalise: bool | None = None,
        arrival_P: ArrayLike | None = None,
        **options: Any,
    ) -> None:
        check_system(system)
        if certificate is not None:
            if dw_bound is not None or w_bounds is not None:
                raise OptionError("dw_bound, w_bounds: the certificate's augmented model has them; give neither")
            self.augmented = _certified_model(system, certificate)
            assert self.augmented.w_range is not None
            dw_bound = self.augmented.w_range.width / 2.0
        self.dw_bound, self.dw_variance = increments(dw_bound, dw_variance, system.nw)
        if certificate is None:
            self.augmented = augmented_system(system, self.dw_bound, w_bounds)
        aug = self.augmented
        self.constrain_increments = check_flag(constrain_increments, "constrain_increments")
        normalise = check_flag(normalise, "normalise", optional=True)
        self.why_uncertified = ""
        """Why :meth:`design` fell back to explicit weights (the certificate's reason); empty otherwise."""
        self.weights, self.certificate, N = resolve_weights(MHEWeights, certificate, weights, N,
                                                            lambda w: w.check(aug))  # fmt: skip
        if certificate is not None:
            self.weights = certified_weights(certificate, variance_weights(aug, self.dw_variance, self.weights.eta))
        self.eta_given = self.weights.eta
        self.weights = span_normalised(self.weights, N, certificate is not None if normalise is None else normalise)
        W = self.w_domain = Box(aug.x.bounds.lower[system.nx :], aug.x.bounds.upper[system.nx :])
        self.w0_prior = W.center if w0_prior is None else as_vector(w0_prior, system.nw, "w0_prior")
        if not W.contains(self.w0_prior):
            raise DataError(f"w0_prior: expected a point in W = {W}, got {self.w0_prior.tolist()}")
        self.arrival_P = None if arrival_P is None else _weight_matrices(arrival_P, aug.nx, "arrival_P")
        arrival = [] if self.arrival_P is None else [replace(self.weights, P=P).schedule() for P in self.arrival_P]
        super().__init__(
            system,
            WindowModel.from_system(aug),
            schedule=self.weights.schedule(),
            N=N,
            x0_prior=x0_prior,
            v_prior=v_prior,
            options=options,
            w_box=aug.w_range if constrain_increments else None,
            w_prior=aug.nominal_w,
            start_schedules=arrival,
        )

    @classmethod
    def design(
        cls,
        system: System,
        *,
        dw_variance: ArrayLike | None = None,
        dw_bound: ArrayLike | None = None,
        w_bounds: Box | tuple[ArrayLike, ArrayLike] | None = None,
        x0_prior: ArrayLike | None = None,
        N: int | None = None,
        max_horizon: int = MAX_HORIZON,
        certify_options: dict[str, Any] | None = None,
        **options: Any,
    ) -> SmoothInputMHE:
        """Certify the augmented model (:func:`~uiest.detectability.certify_delta_ioss`) and build the estimator.

        With a certificate whose ``min_horizon() <= max(N, max_horizon)``: N (default
        ``min(DEFAULT_HORIZON, max_horizon)``), raised to ``min_horizon()`` when shorter (a ``UserWarning`` where the
        estimator's guarantee does not apply even so, e.g. its weights' information horizon caps N). Otherwise explicit
        :func:`variance_weights` with ``eta = FALLBACK_ETA`` and that N, and :attr:`why_uncertified` (and the
        guarantee) says why. ``certify_options`` go to ``certify_delta_ioss``; ``options`` are the window options.
        """
        check_system(system)
        longest = check_int(max_horizon, "max_horizon", low=1)
        window = min(DEFAULT_HORIZON, longest) if N is None else check_int(N, "N", low=1)
        longest = max(window, longest)
        bound, variance = increments(dw_bound, dw_variance, system.nw)
        aug = augmented_system(system, bound, w_bounds)
        try:
            cert = certify_delta_ioss(aug, **(certify_options or {}))
            reason = cert.reason
            if cert.certified and cert.min_horizon() <= longest:
                est = cls(system, certificate=cert, dw_variance=variance, x0_prior=x0_prior,
                          N=max(window, cert.min_horizon()), **options)  # fmt: skip
                if not est.guarantee.applies:  # e.g. the weights' information horizon caps N below min_horizon()
                    warnings.warn(f"SmoothInputMHE.design: certified, but the estimator's guarantee is {est.guarantee}",
                                  UserWarning, stacklevel=user_stacklevel())  # fmt: skip
                return est
            if cert.certified:
                reason = f"certified, but min_horizon() = {cert.min_horizon()} > max_horizon = {longest}"
        except (CertificationError, ModelError) as exc:  # X unbounded, say
            reason = str(exc)
        weights = variance_weights(aug, variance, FALLBACK_ETA)
        est = cls(system, weights=weights, dw_variance=variance, dw_bound=bound, w_bounds=w_bounds,
                  x0_prior=x0_prior, N=window, **options)  # fmt: skip
        est.why_uncertified = f"the augmented model's delta-IOSS is not certified ({reason})"
        return est

    # ------------------------------------------------------------------ the window's nodes are (x, w)
    def _node_of(self, x: FloatArray) -> FloatArray:
        return np.concatenate([x, self.w0_prior])

    def _to_state(
        self, node: FloatArray, y: FloatArray, u_prev: FloatArray, k: int, window: WindowTrajectory | None
    ) -> tuple[FloatArray, FloatArray]:
        return node[: self.system.nx].copy(), np.zeros(0)

    def _node_state(self, window: WindowTrajectory, j: int, data: FloatArray) -> FloatArray:
        return window.x[j][: self.system.nx].copy()

    def _w_guess(self) -> FloatArray:
        """The increments' prior (the window model's unknown input is dw, not w)."""
        return self.w_prior

    def _w_estimate(
        self, window: WindowTrajectory | None, x_hat: FloatArray, u_prev: FloatArray, k: int
    ) -> tuple[FloatArray | None, int | None]:
        """``w_hat[k-1]``: the w part of node k-1 (of the last node when there is no window solution)."""
        if k < 1:
            return None, None
        node = window.x[-2] if window is not None and len(window.x) > 1 else self._node_last
        assert node is not None
        return node[self.system.nx :].copy(), k - 1

    # ------------------------------------------------------------------ guarantee
    @property
    def guarantee(self) -> Guarantee:
        """Schiller et al.'s bound on the augmented model, for x (:func:`~uiest.estimators.bounds.mhe_bound`).

        It holds while the increments stay within ``dw_bound`` and w within W (the condition), for
        noise in V and the true state in X.
        """
        if self.certificate is None:
            return self._no_guarantee(self.theorem, self.why_uncertified or "explicit weights without a delta-IOSS "
                                      "certificate of the augmented model")  # fmt: skip
        aug, w = self.augmented, self.weights
        n_min = int(np.floor(np.log(4.0) / np.log(1.0 / w.eta))) + 1  # their eq. (16) with P1 = P2, at the eta used
        assert self.N is not None
        if n_min > self.N:
            return self._no_guarantee(self.theorem, f"N={self.N} < min_horizon()={n_min} (Schiller et al. 2023, "
                                      "eq. (16))")  # fmt: skip
        dw_box = getattr(self.certificate, "w_box", None)
        dw_box = aug.w_range if dw_box is None else dw_box
        assert dw_box is not None  # the augmented model's w_range is the increments' range: always set
        bound, settling = mhe_bound(w.P, w.Q_w, w.Q_v, w.eta, self.N, dw_box, self.w_prior, aug.v.bounds, self.v_prior,
                                    aug.x.bounds.width, current=True)  # fmt: skip
        nx = self.system.nx
        W = Box(aug.x.bounds.lower[nx:], aug.x.bounds.upper[nx:])
        raised = "" if w.eta == self.eta_given else f" (the certificate's {self.eta_given:.3g} raised, see normalise)"
        steps = zip(aug.w.names, dw_box.lower, dw_box.upper, strict=True)
        values = zip(self.system.w.names, W.lower, W.upper, strict=True)
        condition = " and ".join([f"{d} in [{lo:.4g}, {hi:.4g}] per sample" for d, lo, hi in steps]
                                 + [f"{n} in [{lo:.4g}, {hi:.4g}]" for n, lo, hi in values])  # fmt: skip
        assumes = (
            f"eta={w.eta:.4g}{raised}, N={self.N}; noise in V around v_prior {np.round(self.v_prior, 12).tolist()}, "
            "the true state in X, every output measured and every window problem solved to optimality"
        )
        return self._holds(self.theorem, bound[:nx], settling, assumes, condition=condition)

    def __repr__(self) -> str:
        return (
            f"SmoothInputMHE(system={self.system.name!r}, N={self.N}, eta={self.weights.eta:.4g}, "
            f"dw_bound={self.dw_bound.tolist()}, guarantee={str(self.guarantee)!r})"
        )


def _certified_model(system: System, certificate: Any) -> System:
    """The certificate's system, checked to be the augmented model of ``system``; OptionError otherwise."""
    aug = getattr(certificate, "system", None)
    nx, nw = system.nx, system.nw
    expected = "a certificate of augmented_system(system, dw_bound, w_bounds)"
    if not isinstance(aug, System):
        raise OptionError(f"certificate: expected {expected}, got {type(certificate).__name__} without a system")
    sizes, wanted = (aug.nx, aug.nu, aug.nw, aug.nv, aug.ny), (nx + nw, system.nu, nw, system.nv, system.ny)
    if sizes != wanted or aug.w_range is None or not (aug.w_range.is_bounded and aug.x.bounds.is_bounded):
        raise OptionError(f"certificate: expected {expected} (sizes nx, nu, nw, nv, ny = {wanted}, a bounded X x W "
                          f"and a range of dw), got sizes {sizes}")  # fmt: skip
    rng = np.random.default_rng(0)
    z = np.vstack([aug.x.bounds.center, aug.x.bounds.sample(rng, CHECK_POINTS - 1)])
    U = aug.u.bounds
    u = rng.uniform(np.where(np.isfinite(U.lower), U.lower, -1.0), np.where(np.isfinite(U.upper), U.upper, 1.0),
                    (CHECK_POINTS, system.nu))  # fmt: skip
    dw = aug.w_range.sample(rng, CHECK_POINTS)
    x, w = z[:, :nx], z[:, nx:]
    want = np.hstack([system.step(x, u, w), w + dw])
    got = aug.step(z, u, dw)
    y_want, y_got = system.output(x), aug.output(z)
    close = np.allclose(got, want, rtol=1e-9, atol=1e-12) and np.allclose(y_got, y_want, rtol=1e-9, atol=1e-12)
    if not close:
        raise OptionError(f"certificate: expected {expected}; its system's f or h differs from the augmented model "
                          "of system at points of X x W")  # fmt: skip
    return aug


__all__ = ["DW_SIGMAS", "SmoothInputMHE", "certified_weights", "increments", "variance_weights"]
