"""What the report says of the certificates of a study's estimators (computed by its StudyModel)."""

from __future__ import annotations

import math

from uiest.detectability import Certificate
from uiest.experiments.scenario import EstimatorSpec
from uiest.experiments.study_model import KIND_CERTIFICATE
from uiest.guarantee import Guarantee

__all__ = ["describe", "summary"]


def summary(spec: EstimatorSpec, certificate: Certificate | None, error: str = "") -> dict[str, object]:
    """What the report says of one certified estimator's certificate: rate, horizon, noise gain, coverage."""
    row: dict[str, object] = {"estimator": spec.name, "certificate": KIND_CERTIFICATE[spec.kind], "N": spec.N}
    if certificate is None:
        return {**row, "status": "not available", "reason": error}
    horizon = certificate.min_horizon() if certificate.certified else None
    if spec.N == 0:
        row["N"] = horizon
    # per state of x; a reduced certificate's gains are per state of z_sharp, an augmented model's per state of
    # (x, w): the report's columns are neither
    per_x = certificate.kind != "reduced_eioss" and spec.kind != "smooth-mhe"
    noise_gain = getattr(certificate, "noise_gain", None) if per_x else None
    return {
        **row,
        "status": certificate.status,
        "rate": certificate.rate,
        "rate_min": certificate.rate_min,
        "rate_requested": spec.mu,
        "min_horizon": horizon,
        "noise_gain": None if noise_gain is None else [float(g) for g in noise_gain],
        "coverage": certificate.cover_kind + (", proved" if certificate.sound else ", partly sampled"),
        "sound": certificate.sound,
        "solve_time_s": certificate.solve_time,
        "reason": certificate.reason,
    }


def describe(row: dict[str, object], guarantee: Guarantee | None) -> str:
    """One sentence for report.md: the certificate, and the estimator's guarantee (None: no run to take it from)."""
    if row["status"] != "certified":
        return f"{row['estimator']}: no certificate ({row['reason']})."
    rate, requested = float(row["rate"]), float(row["rate_requested"])  # type: ignore[arg-type]
    at = (
        f"at the requested mu = {requested:g}"
        if math.isclose(rate, requested)
        else f"at mu = {rate:.6g} (the requested {requested:g} is below its smallest rate {row['rate_min']:.6g})"
    )
    verdict = "guarantee: none of its runs finished" if guarantee is None else f"guarantee: {guarantee.text}"
    return f"{row['estimator']}: {row['certificate']} certified {at}, {row['coverage']}; {verdict}."
