r"""Cost weights of the estimators and where they come from (certificates or the user).

- :class:`UISEWeights` ``(mu, P, R_y, R_v)``: the strong-detectability storage
  ``V = |x - x~|_P^2`` and ``sigma_y(dy) = |dy|_{R_y}^2``, ``sigma_v(dv) = |dv|_{R_v}^2``
  (Theorem 3.2 of Guo et al.; see the theory map), from a
  :class:`~uiest.detectability.StrongDetectability` certificate or given.
- :class:`MHEWeights` ``(eta, P, Q_w, Q_v, R)``: the delta-IOSS Lyapunov function of Schiller et
  al. 2023, Assumption 1 (``W = |x - x~|_P^2``,
  ``W+ <= eta W + |dw|_{Q_w}^2 + |dv|_{Q_v}^2 + |dy|_R^2``), from a ``DeltaIOSS`` certificate
  or given.
- :class:`TwoStageWeights` ``(mu, prior, R_y, R_v)``: the constants of Eq. (27) of a
  reduced-order model (Assumption 4.7), from a :class:`~uiest.detectability.ReducedIOSS` or given.

Certificates are duck-typed (:class:`StrongCertificate`, :class:`DeltaCertificate`,
:class:`ReducedCertificate`): any object
with those attributes works, so the estimators do not depend on how a certificate was computed.
All matrices are in original units.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike

from uiest.box import FloatArray, as_vector
from uiest.checks import check_int
from uiest.covariance import as_covariance, noise_variance, prior_variance
from uiest.errors import CertificationError, OptionError
from uiest.estimators.weight_range import check_weight_range
from uiest.reduction import ReducedModel
from uiest.system import System
from uiest.theory import REDUCED_IOSS, TWO_STAGE_GUARANTEE
from uiest.window.problem import WindowWeights, sqrt_psd

__all__ = [
    "DeltaCertificate",
    "MHEWeights",
    "ReducedCertificate",
    "Schedule",
    "StrongCertificate",
    "TwoStageWeights",
    "UISEWeights",
    "certificate_z_scale",
    "resolve_weights",
]

OUTPUT_RATIO = 100.0
""":meth:`MHEWeights.from_variances`: the output residual's weight over the noise's (mapped to y): the split of a
measurement's misfit between the two puts 1/51 of it on the residual, so the misfit costs 98 % of its Gaussian
weight ``2 Q_v``."""


@runtime_checkable
class StrongCertificate(Protocol):
    """What the UISE and the FIE read from a strong-detectability certificate."""

    certified: bool
    mu: float
    P: FloatArray
    R_y: FloatArray
    R_v: FloatArray

    def min_horizon(self) -> int:
        """Smallest horizon satisfying Eq. (13)."""
        ...


@runtime_checkable
class DeltaCertificate(Protocol):
    """What the standard MHE reads from a delta-IOSS certificate (Schiller et al. 2023)."""

    certified: bool
    eta: float
    P: FloatArray
    Q_w: FloatArray
    Q_v: FloatArray
    R: FloatArray

    def min_horizon(self) -> int:
        """Smallest horizon M with ``4 eta^M lambda_max(P2, P1) < 1`` (their eq. (16))."""
        ...


def _missing_attributes(certificate: object, names: tuple[str, ...]) -> list[str]:
    """Names ``certificate`` lacks, checked without evaluating properties (an uncertified one may fail to)."""
    own = getattr(certificate, "__dict__", {})
    return [n for n in names if n not in own and not hasattr(type(certificate), n)]


def _validate(weights: object, discount: str, matrices: tuple[str, ...]) -> None:
    """Check and freeze the discount and the PSD weight matrices of a frozen weights dataclass."""
    object.__setattr__(weights, discount, _discount(getattr(weights, discount), f"weights.{discount}"))
    for name in matrices:
        arr = np.array(getattr(weights, name), dtype=float)
        n = 1 if arr.ndim == 0 else arr.shape[0]
        object.__setattr__(weights, name, _psd(arr, n, f"weights.{name}"))


def _require_certified(certificate: object, names: tuple[str, ...], expected: str, not_certified: str) -> None:
    """OptionError when ``certificate`` lacks ``names``; CertificationError when it does not hold."""
    missing = _missing_attributes(certificate, names)
    if missing:
        raise OptionError(
            f"certificate: expected a {expected} certificate ({', '.join(names)}), "
            f"got {type(certificate).__name__} without {missing}"
        )
    if not certificate.certified:  # type: ignore[attr-defined]
        reason = getattr(certificate, "reason", "")
        raise CertificationError(f"certificate: {not_certified.format(reason=reason)}")


def _check_shapes(weights: object, sizes: tuple[tuple[str, int], ...]) -> None:
    """OptionError unless each named matrix of ``weights`` is (n, n)."""
    for name, n in sizes:
        if getattr(weights, name).shape != (n, n):
            raise OptionError(f"weights.{name}: expected shape ({n}, {n}), got {getattr(weights, name).shape}")


def _discount(value: float, name: str) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError) as exc:
        raise OptionError(f"{name}: expected a number in (0, 1), got {value!r}") from exc
    if not 0.0 < out < 1.0:
        raise OptionError(f"{name}: expected a number in (0, 1), got {value!r}")
    return out


def _psd(value: ArrayLike, n: int, name: str) -> FloatArray:
    arr = np.array(value, dtype=float)
    if arr.ndim == 0 and n == 1:
        arr = arr.reshape(1, 1)
    if arr.shape != (n, n):
        raise OptionError(f"{name}: expected shape ({n}, {n}), got {arr.shape}")
    sqrt_psd(arr, name)  # symmetric, PSD and finite, else OptionError
    arr = 0.5 * (arr + arr.T)
    arr.setflags(write=False)
    return arr


def _diag_scaled(weight: ArrayLike, scale: FloatArray, name: str) -> FloatArray:
    """``diag(weight / scale^2)``: a weight of ``weight`` per scaled unit; ``weight`` scalar or (n,)."""
    try:
        w = np.broadcast_to(np.asarray(weight, dtype=float), scale.shape)
    except (TypeError, ValueError):
        raise OptionError(f"{name}: expected a number or {scale.size} numbers, got {weight!r}") from None
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise OptionError(f"{name}: expected non-negative finite weights, got {np.asarray(weight).tolist()}")
    return np.diag(w / scale**2)


@dataclass(frozen=True, eq=False)
class Schedule:
    r"""A discounted weight schedule: the one form every window estimator's cost takes.

    For a window of ``L`` transitions (node ``i`` at time ``k - L + i``, ``j = L - i`` steps
    before the window's end), the residual weights are::

        prior:                       rate^L P
        output, noise at node i:     rate^(j - shift) R_y,  rate^(j - shift) R_v
        unknown input of transition i:  rate^(j - shift) Q_w        (only if ``w`` is given)

    with the paper's constants already in ``P, R_y, R_v, Q_w`` (``4 P, 2 R_y, 8 R_v`` for the
    UISE; see each weights class's :meth:`schedule`).
    """

    rate: float
    prior: FloatArray
    y: FloatArray
    v: FloatArray
    w: FloatArray | None = None
    shift: int = 1

    def window(self, length: int, measured: ArrayLike) -> WindowWeights:
        """The :class:`~uiest.window.WindowWeights` of a window of ``length`` transitions and these measured nodes."""
        nodes = length - np.asarray(measured, dtype=float).reshape(-1)
        transitions = length - np.arange(length, dtype=float)
        at = self.rate ** (nodes - self.shift)[:, None, None]
        return WindowWeights(
            prior=self.rate**length * self.prior,
            y=at * self.y,
            v=at * self.v,
            w=None if self.w is None else self.rate ** (transitions - self.shift)[:, None, None] * self.w,
        )


def resolve_weights(
    kind: type[Any],
    certificate: object | None,
    weights: object | None,
    N: int | None,
    fits: Callable[[Any], None],
    *,
    needs_horizon: bool = True,
) -> tuple[Any, Any, int | None]:
    """``(weights, certificate, N)`` from exactly one of a certificate and explicit weights of type ``kind``.

    ``fits(weights)`` checks the shapes against the model; N defaults to ``certificate.min_horizon()``
    and is required with explicit weights (unless ``needs_horizon`` is False: the FIE has none).
    """
    if (certificate is None) == (weights is None):
        raise OptionError("certificate, weights: expected exactly one of them")
    if weights is not None and not isinstance(weights, kind):
        raise OptionError(f"weights: expected a {kind.__name__}, got {type(weights).__name__}")
    resolved = kind.from_certificate(certificate) if certificate is not None else weights
    fits(resolved)
    if not needs_horizon:
        return resolved, certificate, None
    if N is None:
        if certificate is None:
            raise OptionError("N: required with explicit weights (no certificate to take min_horizon() from)")
        N = certificate.min_horizon()  # type: ignore[attr-defined]
    return resolved, certificate, check_int(N, "N", low=1)


@dataclass(frozen=True)
class UISEWeights:
    r"""Weights of Eq. (11) (and Eq. (7)) with quadratic functions.

    Attributes
    ----------
    mu : float
        Discount in (0, 1).
    P : ndarray (nx, nx)
        Storage matrix, ``V(x, x~) = |x - x~|_P^2`` (plays ``alpha_2``, see :class:`~uiest.estimators.UISE`).
    R_y : ndarray (ny, ny)
        ``sigma_y(dy) = |dy|_{R_y}^2``.
    R_v : ndarray (nv, nv)
        ``sigma_v(dv) = |dv|_{R_v}^2``.

    """

    mu: float
    P: FloatArray
    R_y: FloatArray
    R_v: FloatArray

    def __post_init__(self) -> None:
        _validate(self, "mu", ("P", "R_y", "R_v"))

    @classmethod
    def from_certificate(cls, certificate: StrongCertificate) -> UISEWeights:
        """The certificate's ``mu, P, R_y, R_v``; raises CertificationError if it does not hold."""
        _require_certified(
            certificate,
            ("certified", "mu", "P", "R_y", "R_v", "min_horizon"),
            "StrongDetectability",
            "strong detectability is not certified ({reason}); pass weights= to run the estimator without the "
            "theorem's guarantee",
        )
        return cls(mu=certificate.mu, P=certificate.P, R_y=certificate.R_y, R_v=certificate.R_v)

    @classmethod
    def from_scales(
        cls,
        system: System,
        mu: float,
        *,
        prior: ArrayLike = 1.0,
        output: ArrayLike = 1.0,
        noise: ArrayLike = 1.0,
    ) -> UISEWeights:
        """Diagonal weights per *scaled* unit: ``P = diag(prior / s_x^2)``, ``R_y = diag(output / s_y^2)``, ...

        ``s`` are the signals' nominal scales (``system.x.scale`` etc.). For models without a
        certificate (the crop model: the paper uses ``mu = 0.48``); scalars or per-component.
        """
        return cls(
            mu=mu,
            P=_diag_scaled(prior, system.x.scale, "prior"),
            R_y=_diag_scaled(output, system.y.scale, "output"),
            R_v=_diag_scaled(noise, system.v.scale, "noise"),
        )

    def schedule(self) -> Schedule:
        """Eq. (11): prior ``4 mu^L P``, node ``j``: ``2 mu^{j-1} R_y``, ``8 mu^{j-1} R_v``."""
        return Schedule(self.mu, 4.0 * self.P, 2.0 * self.R_y, 8.0 * self.R_v, shift=1)

    def check(self, system: System) -> None:
        """Raise OptionError unless the shapes fit ``system`` and the weights are in range (:mod:`.weight_range`)."""
        _check_shapes(self, (("P", system.nx), ("R_y", system.ny), ("R_v", system.nv)))
        check_weight_range(self.mu, "weights.mu", [
            ("weights.P", self.P, system.x.scale, True),
            ("weights.R_y", self.R_y, system.y.scale, False),
            ("weights.R_v", self.R_v, system.v.scale, False),
        ])  # fmt: skip


@dataclass(frozen=True)
class MHEWeights:
    r"""Weights of the standard MHE's cost (Schiller et al. 2023, eq. (6)).

    Attributes
    ----------
    eta : float
        Discount in (0, 1).
    P : ndarray (nx, nx)
        ``W(x, x~) = |x - x~|_P^2`` (their ``P_2``; ``P_1 = P_2 = P``).
    Q_w : ndarray (nw, nw)
        Weight of the unknown input, treated as a bounded disturbance.
    Q_v : ndarray (nv, nv)
        Weight of the measurement noise (part of their generalised disturbance).
    R : ndarray (ny, ny)
        Output weight.

    """

    eta: float
    P: FloatArray
    Q_w: FloatArray
    Q_v: FloatArray
    R: FloatArray

    def __post_init__(self) -> None:
        _validate(self, "eta", ("P", "Q_w", "Q_v", "R"))

    @classmethod
    def from_certificate(cls, certificate: DeltaCertificate) -> MHEWeights:
        """The certificate's ``eta, P, Q_w, Q_v, R``; raises CertificationError if it does not hold."""
        _require_certified(
            certificate,
            ("certified", "eta", "P", "Q_w", "Q_v", "R", "min_horizon"),
            "DeltaIOSS",
            "delta-IOSS is not certified ({reason}); pass weights= to run without the guarantee",
        )
        return cls(eta=certificate.eta, P=certificate.P, Q_w=certificate.Q_w, Q_v=certificate.Q_v, R=certificate.R)

    @classmethod
    def from_scales(
        cls,
        system: System,
        eta: float,
        *,
        prior: ArrayLike = 1.0,
        disturbance: ArrayLike = 1.0,
        noise: ArrayLike = 1.0,
        output: ArrayLike = 1.0,
    ) -> MHEWeights:
        """Diagonal weights per *scaled* unit (``Q_w = diag(disturbance / s_w^2)`` etc.)."""
        return cls(
            eta=eta,
            P=_diag_scaled(prior, system.x.scale, "prior"),
            Q_w=_diag_scaled(disturbance, system.w.scale, "disturbance"),
            Q_v=_diag_scaled(noise, system.v.scale, "noise"),
            R=_diag_scaled(output, system.y.scale, "output"),
        )

    @classmethod
    def from_variances(
        cls,
        system: System,
        eta: float,
        *,
        w_variance: ArrayLike,
        v_covariance: ArrayLike | None = None,
        P0: ArrayLike | None = None,
        at: ArrayLike | None = None,
    ) -> MHEWeights:
        r"""Weights of a Gaussian model: ``Q_w = Sigma_w^-1``, ``Q_v = Sigma_v^-1``, ``P = P0^-1``, a large R.

        With these weights and ``eta -> 1`` the cost (:meth:`schedule`) is four times the negative log-posterior
        of the window under ``w[k] ~ N(w_bar, Sigma_w)`` i.i.d., ``v[k] ~ N(v_bar, Sigma_v)``, the window's first
        state ``~ N(x_hat, P0)``, and ``y = h(x, v)`` (the output residual weighted ``R = OUTPUT_RATIO (D Sigma_v
        D^T)^-1`` with ``D = dh/dv`` at ``at``, default X's centre (0 on an infinite side): the output equation held to
        a small fraction of the noise). ``w_variance`` is ``Sigma_w`` (a number, (nw,) or (nw, nw), positive
        definite; :func:`uiest.tuning.fit_standard_mhe` chooses it by the likelihood of the record);
        ``v_covariance`` defaults to V's uniform variance and ``P0`` to ``x.scale^2 / 12``, as for the Kalman
        filters.
        """
        Sigma_w = as_covariance(w_variance, system.nw, np.zeros(system.nw), "w_variance")
        Sigma_v = as_covariance(v_covariance, system.nv, noise_variance(system), "v_covariance")
        P_0 = as_covariance(P0, system.nx, prior_variance(system), "P0")
        center = system.x.bounds.center
        x = np.where(np.isfinite(center), center, 0.0) if at is None else as_vector(at, system.nx, "at")
        v_bar = np.where(np.isfinite(system.v.bounds.center), system.v.bounds.center, 0.0)
        D = system.linearize(x, v=v_bar).D_v
        inverse = {}
        for name, matrix in (("w_variance", Sigma_w), ("v_covariance", Sigma_v), ("P0", P_0),
                             ("v_covariance mapped to y (D Sigma_v D^T)", D @ Sigma_v @ D.T)):  # fmt: skip
            if matrix.size and np.linalg.eigvalsh(matrix)[0] <= 0.0:
                raise OptionError(f"{name}: expected a positive definite covariance (its inverse is a weight)")
            inverse[name] = np.linalg.inv(matrix) if matrix.size else matrix
        return cls(eta=eta, P=inverse["P0"], Q_w=inverse["w_variance"], Q_v=inverse["v_covariance"],
                   R=OUTPUT_RATIO * inverse["v_covariance mapped to y (D Sigma_v D^T)"])  # fmt: skip

    def schedule(self) -> Schedule:
        """Schiller et al. eq. (6): prior ``2 eta^L P``; ``eta^{j-1} R``, ``2 eta^{j-1} Q_v``, ``2 eta^{j-1} Q_w``."""
        return Schedule(self.eta, 2.0 * self.P, self.R, 2.0 * self.Q_v, 2.0 * self.Q_w, shift=1)

    def check(self, system: System) -> None:
        """Raise OptionError unless the shapes fit ``system`` and the weights are in range (:mod:`.weight_range`)."""
        _check_shapes(self, (("P", system.nx), ("Q_w", system.nw), ("Q_v", system.nv), ("R", system.ny)))
        check_weight_range(self.eta, "weights.eta", [
            ("weights.P", self.P, system.x.scale, True),
            ("weights.Q_w", self.Q_w, system.w.scale, False),
            ("weights.Q_v", self.Q_v, system.v.scale, False),
            ("weights.R", self.R, system.y.scale, False),
        ])  # fmt: skip


@runtime_checkable
class ReducedCertificate(Protocol):
    """What the two-stage UISE reads from a reduced-order i-IOSS certificate (Assumption 4.7).

    ``c_x`` is in scaled norms ``|S_z^-1 dz|``; the scales are ``model.z_scale`` (as in
    :class:`~uiest.detectability.ReducedIOSS`) or an attribute ``z_scale``.
    """

    certified: bool
    mu: float
    c_x: float
    R_y: FloatArray
    R_v: FloatArray

    def min_horizon(self) -> int:
        """Smallest N with ``N > -log_mu(4 c_x)`` (Eq. (31))."""
        ...


def certificate_z_scale(certificate: object) -> FloatArray | None:
    """The z scales of a reduced certificate (``z_scale`` or ``model.z_scale``), None if it has none."""
    scale = getattr(certificate, "z_scale", None)
    if scale is None:
        scale = getattr(getattr(certificate, "model", None), "z_scale", None)
    return None if scale is None else np.asarray(scale, dtype=float).reshape(-1)


@dataclass(frozen=True)
class TwoStageWeights:
    r"""Weights of the two-stage UISE's cost Eq. (28), in original units.

    The window cost at time k (``N_k`` transitions, node times ``k-j``, ``j = 1 .. N_k``) is::

        J = 2 mu^{N_k} |z_{k-N_k|k} - z_hat_{k-N_k}|_{prior}^2
            + sum_{j=1}^{N_k} mu^j ( 2 |v_{k-j|k} - v_bar|_{R_v}^2
                                     + |y_{k-j} - h_sharp(z_{k-j|k}, y_{k-j}, v_{k-j|k})|_{R_y}^2 ).

    From a certificate: ``prior = c_x diag(1 / z_scale^2)`` (the constant ``c_x`` of
    Eq. (27), which holds in the scaled norm ``|S_z^-1 dz|``, written as a matrix in
    original units), ``R_v = c_v diag(1 / v_scale^2)`` and ``R_y = c_y diag(1 / y_scale^2)``
    (the certificate's ``R_v``, ``R_y``).

    Attributes
    ----------
    mu : float
        Discount in (0, 1).
    prior : ndarray (n_sharp, n_sharp)
    R_y : ndarray (ny, ny)
    R_v : ndarray (nv, nv)

    """

    mu: float
    prior: FloatArray
    R_y: FloatArray
    R_v: FloatArray

    def __post_init__(self) -> None:
        _validate(self, "mu", ("prior", "R_y", "R_v"))

    @classmethod
    def from_certificate(cls, certificate: ReducedCertificate) -> TwoStageWeights:
        """``mu``, ``c_x diag(1 / z_scale^2)``, ``R_y``, ``R_v``; CertificationError if it does not hold."""
        _require_certified(
            certificate,
            ("certified", "mu", "c_x", "R_y", "R_v", "min_horizon"),
            "ReducedIOSS",
            f"{REDUCED_IOSS} is not certified ({{reason}}); pass weights= to run without {TWO_STAGE_GUARANTEE}",
        )
        z_scale = certificate_z_scale(certificate)
        if z_scale is None:
            raise OptionError("certificate: expected z scales (model.z_scale or z_scale) to express c_x as a matrix")
        prior = float(certificate.c_x) * np.diag(1.0 / z_scale**2)
        return cls(mu=certificate.mu, prior=prior, R_y=certificate.R_y, R_v=certificate.R_v)

    @classmethod
    def from_scales(
        cls,
        reduced: ReducedModel,
        mu: float,
        *,
        prior: ArrayLike = 1.0,
        output: ArrayLike = 1.0,
        noise: ArrayLike = 1.0,
    ) -> TwoStageWeights:
        """Diagonal weights per *scaled* unit: ``prior = diag(prior / s_z^2)``, ``R_y = diag(output / s_y^2)``, ...

        ``s_z`` are the reduced state's scales (:attr:`ReducedModel.z_scale`, as the two-stage UISE's
        window uses), ``s_y``, ``s_v`` the system's
        output and noise scales. For models without a certificate (the crop model, whose
        certificate only gives mu ~ 0.9995: the paper uses mu = 0.48); scalars or per-component.
        """
        system = reduced.system
        return cls(
            mu=mu,
            prior=_diag_scaled(prior, reduced.z_scale, "prior"),
            R_y=_diag_scaled(output, system.y.scale, "output"),
            R_v=_diag_scaled(noise, system.v.scale, "noise"),
        )

    def schedule(self) -> Schedule:
        """Eq. (28): prior ``2 mu^L prior``, node ``j``: ``mu^j R_y``, ``2 mu^j R_v``."""
        return Schedule(self.mu, 2.0 * self.prior, self.R_y, 2.0 * self.R_v, shift=0)

    def check(self, system: System, n_sharp: int) -> None:
        """Raise OptionError unless the shapes fit ``system`` and the reduced state's size."""
        _check_shapes(self, (("prior", n_sharp), ("R_y", system.ny), ("R_v", system.nv)))
        # the prior is on the reduced state, whose scales the estimator sets: R_y and R_v are checked here
        check_weight_range(self.mu, "weights.mu", [
            ("weights.R_y", self.R_y, system.y.scale, False),
            ("weights.R_v", self.R_v, system.v.scale, False),
        ])  # fmt: skip
