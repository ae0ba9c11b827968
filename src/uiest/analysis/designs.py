r"""The certified estimators a model admits, and their guarantees: the UISE and the delayed UISE.

For each: the strong-detectability certificate (:func:`~uiest.detectability.certify_strong_detectability`,
of the model or of its delayed system, :func:`~uiest.delay.delayed_system`) at its default rate; when
its ``min_horizon()`` exceeds ``max_horizon``, once more with cond(P) bounded so that it fits, as
:func:`uiest.design.design_uise` does. The estimator's N is the one in ``min_horizon() .. max_horizon``
whose guarantee has the smallest largest bound relative to the state scales, and the guarantee is
that estimator's (:attr:`UISE.guarantee <uiest.estimators.UISE.guarantee>`). Where no N fits, the
guarantee is the one of N = ``max_horizon``: none, and why.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from uiest.box import FloatArray
from uiest.delay import delayed_system
from uiest.design import CONDITION_MARGIN
from uiest.detectability import certify_strong_detectability
from uiest.detectability.certificate import CertificateStatus, horizon_condition
from uiest.errors import CertificationError, ModelError
from uiest.estimators import UISE, DelayedUISE
from uiest.guarantee import Guarantee
from uiest.system import System

__all__ = ["EstimatorDesign", "delayed_design", "strong_design"]


@dataclass(frozen=True, eq=False, kw_only=True)
class EstimatorDesign:
    """A certificate and the guarantee of the estimator it designs.

    Attributes
    ----------
    estimator : str
        ``"UISE"`` or ``"DelayedUISE"``.
    certificate : Certificate or None
        The strong-detectability certificate (of the delayed system for the delayed UISE); None
        when none could be made.
    not_applicable : str
        Why no certificate could be made (the ModelError's message; empty otherwise).
    N : int or None
        The estimator's horizon (None without a certificate).
    guarantee : Guarantee or None
        Its guarantee (None without a certificate).

    """

    estimator: str
    certificate: Any
    not_applicable: str
    N: int | None
    guarantee: Guarantee | None

    @property
    def status(self) -> CertificateStatus | None:
        """The certificate's status (None without a certificate)."""
        return None if self.certificate is None else self.certificate.status

    @property
    def certified(self) -> bool:
        """The certificate holds."""
        return self.certificate is not None and bool(self.certificate.certified)

    @property
    def min_horizon(self) -> int | None:
        """The certificate's ``min_horizon()`` (None unless certified)."""
        return self.certificate.min_horizon() if self.certified else None

    def to_dict(self) -> dict[str, object]:
        """Plain data for JSON."""
        cert = self.certificate
        return {
            "estimator": self.estimator,
            "not_applicable": self.not_applicable,
            "status": None if cert is None else str(cert.status),
            "certified": self.certified,
            "reason": None if cert is None else cert.reason,
            "mu": None if cert is None else cert.rate,
            "mu_min": None if cert is None else cert.rate_min,
            "condition": cert.condition if self.certified else None,
            "min_horizon": self.min_horizon,
            "N": self.N,
            "guarantee": None if self.guarantee is None else self.guarantee.to_dict(),
        }


def _certify(system: System, max_horizon: int) -> Any:
    """The certificate at the default rate, once more with cond(P) bounded when its window exceeds ``max_horizon``."""
    cert = certify_strong_detectability(system)
    if cert.certified and cert.min_horizon() > max_horizon:
        fitting = CONDITION_MARGIN * horizon_condition(cert.mu, max_horizon)
        if fitting > 1.0:
            conditioned = certify_strong_detectability(system, mu=cert.mu, max_condition=fitting)
            if conditioned.certified:
                return conditioned
    return cert


def _largest_relative(guarantee: Guarantee, scale: FloatArray) -> float:
    """The largest finite bound over the state scales (inf when the theorem does not apply or bounds nothing)."""
    if not guarantee.applies or guarantee.error_bound is None:
        return float("inf")
    relative = guarantee.error_bound / scale
    return float(np.nanmax(relative)) if np.isfinite(relative).any() else float("inf")


def _design(name: str, system: System, certified_system: System, build: Callable[[Any, int], Any], *,
            max_horizon: int, shortest: int = 1) -> EstimatorDesign:  # fmt: skip
    try:
        cert = _certify(certified_system, max_horizon)
    except (ModelError, CertificationError) as exc:
        return EstimatorDesign(estimator=name, certificate=None, not_applicable=str(exc), N=None, guarantee=None)
    if not cert.certified:
        return EstimatorDesign(estimator=name, certificate=cert, not_applicable="", N=None, guarantee=None)
    horizons = range(max(cert.min_horizon(), shortest), max_horizon + 1)
    if not horizons:
        guarantee = build(cert, max(max_horizon, shortest)).guarantee
        return EstimatorDesign(estimator=name, certificate=cert, not_applicable="", N=_used(guarantee),
                               guarantee=guarantee)  # fmt: skip
    guarantees = {N: build(cert, N).guarantee for N in horizons}
    N = min(horizons, key=lambda n: _largest_relative(guarantees[n], system.x.scale))
    return EstimatorDesign(estimator=name, certificate=cert, not_applicable="", N=_used(guarantees[N]),
                           guarantee=guarantees[N])  # fmt: skip


def _used(guarantee: Guarantee) -> int:
    """The window the estimator runs (its information horizon where that capped the N asked for)."""
    assert guarantee.horizon is not None  # a window estimator's guarantee
    return guarantee.horizon


def strong_design(system: System, x0: FloatArray, max_horizon: int) -> EstimatorDesign:
    """The UISE's certificate, N and guarantee (module docstring)."""
    return _design("UISE", system, system, lambda cert, N: UISE(system, certificate=cert, N=N, x0_prior=x0),
                   max_horizon=max_horizon)  # fmt: skip


def delayed_design(system: System, x0: FloatArray, max_horizon: int) -> EstimatorDesign:
    """The delayed UISE's (lag 1): the certificate of the delayed system, N and the guarantee (module docstring)."""
    try:
        inner = delayed_system(system).system
    except ModelError as exc:
        return EstimatorDesign(
            estimator="DelayedUISE", certificate=None, not_applicable=str(exc), N=None, guarantee=None
        )
    return _design(
        "DelayedUISE", system, inner,
        lambda cert, N: DelayedUISE(system, certificate=cert, N=N, lag=1, x0_prior=x0),
        max_horizon=max_horizon, shortest=2,
    )  # fmt: skip
