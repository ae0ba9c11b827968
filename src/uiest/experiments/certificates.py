"""Certificates for the estimators of a study: computed once per process, summarised for the report."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Any

from uiest import models
from uiest.detectability import Certificate, certify_delta_ioss, certify_strong_detectability
from uiest.errors import CertificationError, OptionError
from uiest.experiments.scenario import EstimatorSpec

KIND_CERTIFICATE = {
    "uise": "strong detectability (theo:Lyapunov)",
    "fie": "strong detectability (theo:Lyapunov)",
    "two-stage": "reduced model's e-IOSS (ass:e-ioss)",
    "standard-mhe": "delta-IOSS (Schiller et al. 2023)",
}


@functools.lru_cache(maxsize=32)
def certificate_for(model: str, kind: str, mu: float) -> Certificate:
    """The certificate that designs the weights of an estimator of ``kind`` on a registered model.

    Certified at ``mu`` when ``mu`` is at least the smallest rate found, else at the
    certificate's default rate. Raises :class:`CertificationError` when it does not hold.
    """
    entry = models.load(model)
    make: Callable[[float | None], Certificate]
    if kind in ("uise", "fie"):
        system = entry.build()
        parameters = entry.jacobian_parameters() if entry.jacobian_parameters is not None else None
        make = functools.partial(_strong, system, parameters)
    elif kind == "two-stage":
        if entry.reduction is None:
            raise OptionError(f"estimators: the two-stage UISE needs a reduction; model {model!r} registers none")
        reduced = entry.reduction()
        make = lambda rate: reduced.certify(mu=rate)  # noqa: E731
    elif kind == "standard-mhe":
        system = entry.build()
        make = lambda rate: certify_delta_ioss(system, rate)  # noqa: E731
    else:
        raise OptionError(f"estimators.kind: no certificate for {kind!r}")
    default = make(None)
    if not default.certified:
        raise CertificationError(
            f"{KIND_CERTIFICATE[kind]} of {model!r} does not hold ({default.status}: {default.reason}); "
            "use explicit weights"
        )
    if default.rate_min <= mu < 1.0 and mu != default.rate:
        at_mu = make(mu)
        if at_mu.certified:
            return at_mu
    return default


def _strong(system: Any, parameters: Any, rate: float | None) -> Certificate:
    return certify_strong_detectability(system, rate, parameters=parameters)


def summary(spec: EstimatorSpec, certificate: Certificate | None, error: str = "") -> dict[str, object]:
    """What the report says of one certified estimator: rate, horizon, guarantee, noise gain."""
    row: dict[str, object] = {"estimator": spec.name, "certificate": KIND_CERTIFICATE[spec.kind], "N": spec.N}
    if certificate is None:
        return {**row, "status": "not available", "reason": error}
    horizon = certificate.min_horizon() if certificate.certified else None
    if spec.N == 0:
        row["N"] = horizon
    noise_gain = getattr(certificate, "noise_gain", None)
    return {
        **row,
        "status": certificate.status,
        "rate": certificate.rate,
        "rate_min": certificate.rate_min,
        "rate_requested": spec.mu,
        "min_horizon": horizon,
        "guarantee": horizon is not None and (spec.kind == "fie" or int(row["N"]) >= horizon),  # type: ignore[call-overload]
        "noise_gain": None if noise_gain is None else [float(g) for g in noise_gain],
        "coverage": certificate.coverage.split(" (")[0] + (", proved" if certificate.sound else ", partly sampled"),
        "sound": certificate.sound,
        "solve_time_s": certificate.solve_time,
        "reason": certificate.reason,
    }


def describe(row: dict[str, object]) -> str:
    """One sentence for report.md."""
    if row["status"] != "certified":
        return f"{row['estimator']}: no certificate ({row['reason']})."
    rate, requested = float(row["rate"]), float(row["rate_requested"])  # type: ignore[arg-type]
    at = (
        f"at the requested mu = {requested:g}"
        if math.isclose(rate, requested)
        else f"at mu = {rate:.6g} (the requested {requested:g} is below its smallest rate {row['rate_min']:.6g})"
    )
    verdict = (
        f"the theorem applies (N = {row['N']} >= {row['min_horizon']})"
        if row["guarantee"]
        else f"the theorem does NOT apply: it needs N >= {row['min_horizon']}, the study runs N = {row['N']}"
    )
    return f"{row['estimator']}: {row['certificate']} certified {at}, {row['coverage']}; {verdict}."
