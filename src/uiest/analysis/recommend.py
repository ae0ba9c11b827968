r"""Which estimator a model admits, why, and the sentence that says so.

:func:`decide` reads the analysis's data in this order:

1. the UISE's guarantee is informative (a bound below X's width for every state): **UISE**;
2. matching fails and the delayed UISE's guarantee is informative where it bounds (its states that
   depend on the invisible input directions have no bound): **delayed UISE**;
3. otherwise the estimators that allow arbitrary unknown inputs give no informative guarantee, and
   the first cause found is recorded (matching fails; a zero on or outside the unit circle; no
   certificate; a certified window longer than ``max_horizon``; a vacuous bound). Where the model
   with the unknown input as a random walk is detectable (:mod:`uiest.analysis.random_walk`), an
   estimator assuming a smooth unknown input: **smooth-input MHE**; else nothing has a guarantee:
   **EKF/UKF**.

:func:`reason` derives one sentence from the numbers: the cause, the zero that limits the rate
(the largest zero over the points when ``|z|^2`` is at least :data:`LIMITING_SHARE` of the smallest
certified rate, or of 1 without one), and for the smooth-input estimators what an unknown input
at the near-zero's frequency hides (:mod:`uiest.analysis.near_zeros`).
"""

from __future__ import annotations

import enum
import re
from typing import TYPE_CHECKING

import numpy as np

from uiest.analysis.designs import EstimatorDesign
from uiest.analysis.random_walk import RandomWalkDetectability
from uiest.analysis.zeros import Zero, Zeros
from uiest.detectability.certificate import CertificateStatus
from uiest.detectability.linear import off_unit_disk
from uiest.guarantee import Guarantee

if TYPE_CHECKING:
    from uiest.analysis.report import ModelAnalysis

__all__ = [
    "Cause",
    "Recommendation",
    "amount",
    "complex_number",
    "decide",
    "frequency_text",
    "number",
    "point_text",
    "reason",
]

LIMITING_SHARE = 0.9
"""A zero is named as what limits the certificate when ``|z|^2`` is at least this share of its smallest rate."""
FLOOR_SHARE = 0.01
"""The error floor is cited when it is at least this share of X's width for some state."""
NEAR_DISTANCE = 0.05
"""A channel's zero within this distance of the near-zero's frequency is named beside it."""


class Recommendation(enum.Enum):
    """The estimator the analysis recommends."""

    UISE = "UISE"
    """:class:`~uiest.estimators.UISE`: any unknown input, an informative certified bound."""
    DELAYED_UISE = "delayed UISE"
    """:class:`~uiest.estimators.DelayedUISE`: matching fails, the delayed system certifies."""
    SMOOTH_INPUT_MHE = "smooth-input MHE"
    """An MHE with the unknown input as a state with small increments (``uiest.estimators.SmoothInputMHE``)."""
    EKF_UKF = "EKF/UKF"
    """The Kalman filters with the unknown input as a random walk: nothing else applies."""


class Cause(enum.Enum):
    """Why :func:`decide` recommended what it did (module docstring)."""

    UISE_INFORMATIVE = "the UISE's guarantee is informative"
    DELAYED_INFORMATIVE = "matching fails and the delayed UISE's guarantee is informative"
    MATCHING_FAILS = "matching fails and the delayed UISE has no informative guarantee"
    ZERO_OUTSIDE = "a zero on or outside the unit circle"
    NOT_CERTIFIED = "strong detectability is not certified"
    WINDOW_TOO_LONG = "the certified window is longer than max_horizon"
    BEYOND_INFORMATION_HORIZON = "the certified window is longer than its weights' information horizon"
    VACUOUS = "the certified UISE's bound is not below X's width"


def informative_where_bounded(guarantee: Guarantee | None) -> bool:
    """The guarantee applies, bounds some state below X's width and no state at or above it."""
    return (guarantee is not None and guarantee.applies and bool(guarantee.informative_states.any())
            and not guarantee.vacuous_states.any())  # fmt: skip


def decide(matching: bool, zeros: Zeros, strong: EstimatorDesign, delayed: EstimatorDesign | None,
           random_walk: RandomWalkDetectability) -> tuple[Recommendation, Cause]:  # fmt: skip
    """The recommendation and its cause (module docstring)."""
    if matching and strong.guarantee is not None and strong.guarantee.informative:
        return Recommendation.UISE, Cause.UISE_INFORMATIVE
    if not matching and delayed is not None and informative_where_bounded(delayed.guarantee):
        return Recommendation.DELAYED_UISE, Cause.DELAYED_INFORMATIVE
    if not matching:
        cause = Cause.MATCHING_FAILS
    elif off_unit_disk(zeros.largest_modulus):
        cause = Cause.ZERO_OUTSIDE
    elif not strong.certified:
        cause = Cause.NOT_CERTIFIED
    elif strong.guarantee is not None and not strong.guarantee.applies and strong.guarantee.capped:
        cause = Cause.BEYOND_INFORMATION_HORIZON
    elif strong.guarantee is None or not strong.guarantee.applies:
        cause = Cause.WINDOW_TOO_LONG
    else:
        cause = Cause.VACUOUS
    return (Recommendation.SMOOTH_INPUT_MHE if random_walk.detectable else Recommendation.EKF_UKF), cause


# ---------------------------------------------------------------------------------------------- text
def number(value: float) -> str:
    """Four significant digits."""
    return f"{value:.4g}"


def complex_number(z: complex) -> str:
    """``-0.9967`` or ``0.9932+0.0976j`` (four significant digits)."""
    if abs(z.imag) <= 1e-6 * max(1.0, abs(z)):
        return number(z.real)
    return f"{z.real:.4g}{z.imag:+.4g}j"


def amount(value: float, unit: str) -> str:
    """A number with its unit (none for "" and "-")."""
    return f"{number(value)} {unit}" if unit not in ("", "-") else number(value)


def point_text(names: tuple[str, ...], x: np.ndarray) -> str:
    """``(angle, rate) = (0.5, 1.8)``."""
    return f"({', '.join(names)}) = ({', '.join(f'{v:.4g}' for v in x)})"


def frequency_text(z: complex) -> str:
    """What an input ``Re(omega z^k)`` does: alternates every sample, drifts, or oscillates; grows where ``|z| > 1``."""
    theta = abs(float(np.angle(z)))
    growing = abs(z) > 1.0 + 1e-9
    growth = f"growing {number(abs(z))}-fold per sample"
    if theta >= 0.95 * np.pi:
        return "alternating every sample" + (f" and {growth}" if growing else "")
    if theta <= 1e-3:
        return growth if growing else "constant or slowly drifting"
    return f"oscillating with a period of {2 * np.pi / theta:.3g} samples" + (f" and {growth}" if growing else "")


def zero_text(a: ModelAnalysis, zero: Zero, degree: int | None = None) -> str:
    """``a zero at -0.9967, created by sampling a continuous-time relative degree of 2``.

    ``degree``: the channel's continuous relative degree (default: the unknown inputs', when they share one).
    """
    text = f"a zero at {complex_number(zero.value)}"
    if zero.from_sampling:
        degrees = {d for d in (a.continuous_degree or ()) if d is not None}
        if degree is None and len(degrees) == 1:
            degree = degrees.pop()
        text += (
            f", created by sampling a continuous-time relative degree of {degree}"
            if degree
            else (", created by sampling")
        )
    elif zero.unstable_step and zero.from_sampling is None:
        text += (
            ", where the model's RK4 step grows a mode the ODE damps (the zero may come from the integrator, not the "
            "plant: analyse again with more substeps or method='collocation')"
        )
    if zero.exact is not None:
        text += (f" (the continuous linearisation sampled exactly has it at {complex_number(zero.exact)}: the "
                 "model's discretisation, see System.from_ode's warnings, or the motion within a sample away from an "
                 "equilibrium moves it)")  # fmt: skip
    return text


def limiting_zero(a: ModelAnalysis) -> Zero | None:
    """The largest zero when it limits the rate (module docstring), else None."""
    zero = a.zeros.largest
    if zero is None:
        return None
    reference = a.strong.certificate.rate_min if a.strong.certified else 1.0
    return zero if zero.modulus**2 >= LIMITING_SHARE * reference else None


def hidden_motion(a: ModelAnalysis) -> str | None:
    """What an unknown input at the near-zero's frequency hides (module docstring of near_zeros), or None."""
    near = a.near_zeros
    if near.noise is None or near.floor_z is None:
        return None
    width = a.x_width
    share = near.error_floor / width
    if not np.any(share > 0):
        return None
    if not np.max(share) >= FLOOR_SHARE:
        return None
    floor_z = near.floor_z
    # each state's frequency; None: its floor is reached at every one (a measured state's noise)
    frequency = [floor_z if z is None else z for z in near.state_z]
    moved = [i for i in range(len(share)) if share[i] >= 0.5 * np.max(share)]
    groups: dict[tuple[complex, tuple[float, ...]], list[str]] = {}  # the states each frequency and point moves
    for i in sorted(moved, key=lambda i: frequency[i] != floor_z):  # floor_z's states first
        floor, unit, at = near.error_floor[i], a.state_units[i], near.state_point[i]
        beyond = f" (more than X's width {amount(width[i], unit)})" if floor > width[i] else ""
        key = frequency[i], () if at is None else tuple(at)
        groups.setdefault(key, []).append(
            f"{a.state_names[i]} by {'any amount' if np.isinf(floor) else amount(floor, unit)}{beyond}"
        )
    noise = ", ".join(f"{y} {amount(e, u)}" for y, e, u in zip(a.output_names, near.noise, a.output_units,
                                                                strict=True))  # fmt: skip
    inputs = ", ".join(a.input_names)
    clauses: list[str] = []
    said: tuple[float, ...] = ()  # the linearisation point the clauses so far named
    for (z, point), parts in groups.items():
        where = ""
        if not a.linear and point and point != said:
            prefix = "at" if clauses else "in the model linearised at"
            where, said = f"{prefix} {point_text(a.state_names, np.array(point))}, ", point
        near_zero = "" if z != floor_z or limiting_zero(a) is not None else _near_zero_text(a, z)
        subject = f"an unknown input ({inputs})" if not clauses else "one"
        clauses.append(f"{where}{subject} {frequency_text(z)}{near_zero} moves {' and '.join(parts)}")
    return (f"{'; '.join(clauses)} while the outputs move within their noise ({noise}), an error no estimator that "
            "allows arbitrary unknown inputs can rule out")  # fmt: skip


def _near_zero_text(a: ModelAnalysis, z: complex) -> str:
    """`` (a near-zero: ...; the channel w -> y alone has a zero at ...)`` for the frequency z."""
    circle = a.near_zeros.unit_circle
    text = (f" (a near-zero: on |z| = 1 the system matrix's smallest singular value is {circle.sigma:.2g} of its "
            f"largest, at z = {complex_number(circle.z)}")  # fmt: skip
    nearest = min(((abs(zero.value - z), channel, zero) for channel in a.zeros.channels for zero in channel.zeros),
                  key=lambda item: item[0], default=None)  # fmt: skip
    if nearest is not None and nearest[0] <= NEAR_DISTANCE:
        _, channel, zero = nearest
        alone = zero_text(a, zero, channel.continuous_degree)
        text += f"; the channel {channel.input} -> {channel.output} alone has {alone}"
    return text + ")"


FIRST_CLAUSE = r" \(|; "
"""Where an error message's first clause ends (the reason quotes only that)."""


STATUS_PHRASE = {
    CertificateStatus.SOLVER_FAILED: "undecided: the LMI solver failed",
    CertificateStatus.RECHECK_FAILED: "undecided: the solution failed its independent re-check",
    CertificateStatus.BELOW_RATE: "not certified at the rate asked: it is below the smallest certifiable rate",
}
"""How "strong detectability is ..." reads for a status whose name is no predicate."""


def _certificate_text(design: EstimatorDesign) -> str:
    if design.certificate is None:
        first = re.split(FIRST_CLAUSE, design.not_applicable, maxsplit=1)[0]
        return f"not applicable: {first}"
    status = design.status
    assert status is not None
    return STATUS_PHRASE.get(status, str(status))


def _window_text(design: EstimatorDesign, max_horizon: int) -> str:
    cert = design.certificate
    return (f"certified with mu = {number(cert.mu)} (mu_min = {number(cert.mu_min)}), but its window "
            f"{design.min_horizon} exceeds max_horizon {max_horizon}")  # fmt: skip


def reason(a: ModelAnalysis) -> str:
    """The recommendation's reason in one sentence (module docstring)."""
    rec, cause = a.recommendation, a.cause
    strong, delayed = a.strong, a.delayed
    if cause is Cause.UISE_INFORMATIVE:
        assert strong.guarantee is not None
        return (f"UISE: strong detectability is certified (mu = {number(strong.certificate.mu)}, N = {strong.N}) and "
                f"the UISE's guarantee {strong.guarantee.text}, for any unknown input")  # fmt: skip
    if cause is Cause.DELAYED_INFORMATIVE:
        assert delayed is not None and delayed.guarantee is not None
        return (f"delayed UISE: the unknown input does not show in the next output (rank(C B) = {a.rank_CB} < "
                f"rank(B) = {a.rank_B}), but the delayed system is certified (mu = {number(delayed.certificate.mu)}, "
                f"N = {delayed.N}) and the delayed UISE's guarantee {delayed.guarantee.text}")  # fmt: skip
    head = f"{rec.value}: "
    limiting = limiting_zero(a)
    if cause is Cause.MATCHING_FAILS:
        assert delayed is not None
        if delayed.certificate is None or not delayed.certified:
            why = f"its delayed system is {_certificate_text(delayed)}"
        elif delayed.guarantee is None or not delayed.guarantee.applies:
            why = f"its delayed system is {_window_text(delayed, a.max_horizon)}"
        else:
            why = f"the delayed UISE's guarantee {delayed.guarantee.text}"
        text = (f"the unknown input does not show in the next output (rank(C B) = {a.rank_CB} < rank(B) = "
                f"{a.rank_B}) and {why}")  # fmt: skip
    elif cause is Cause.ZERO_OUTSIDE:
        zero = a.zeros.largest
        assert zero is not None and a.zeros.largest_at is not None
        if a.linear:
            text = (f"the model has {zero_text(a, zero)}, |z| = {number(zero.modulus)} >= 1, so it is not strongly "
                    "detectable")  # fmt: skip
        else:
            text = (f"the model linearised at {point_text(a.state_names, a.zeros.largest_at)} has "
                    f"{zero_text(a, zero)}, |z| = {number(zero.modulus)} >= 1, so strong detectability has no "
                    "certificate over X of the kind uiest computes (a quadratic storage; its rate would be at least "
                    f"|z|^2 = {number(zero.modulus**2)}); the zero is that linearisation's, and the model's "
                    "trajectories may still determine the state")  # fmt: skip
        limiting = None
    elif cause is Cause.NOT_CERTIFIED:
        text = f"strong detectability is {_certificate_text(strong)}"
        if not a.x_bounded and not off_unit_disk(a.zeros.largest_modulus):  # no zero speaks against a certificate
            text += ("; no zero of the model lies on or outside the unit circle: give X bounds (x_bounds) and "
                     "analyse again, as a certificate may then exist")  # fmt: skip
    elif cause is Cause.WINDOW_TOO_LONG:
        text = f"strong detectability is {_window_text(strong, a.max_horizon)}"
    elif cause is Cause.BEYOND_INFORMATION_HORIZON:
        assert strong.guarantee is not None
        text = (f"strong detectability is certified with mu = {number(strong.certificate.mu)}, but its window "
                f"{strong.min_horizon} is longer than its weights' information horizon "
                f"{strong.guarantee.information_horizon} (older cost terms fall below double precision)")  # fmt: skip
    else:
        assert strong.guarantee is not None
        text = f"the certified UISE's guarantee {strong.guarantee.text}"
    if limiting is not None and strong.certified:
        text += f", limited by {zero_text(a, limiting)} (|z|^2 = {number(limiting.modulus**2)})"
    elif limiting is not None:
        text += (f"; any certificate's rate is at least |z|^2 = {number(limiting.modulus**2)} for "
                 f"{zero_text(a, limiting)}")  # fmt: skip
    hidden = hidden_motion(a)
    if hidden is not None:
        text += f"; {hidden}"
    elif cause is Cause.VACUOUS and a.near_zeros.noise is not None:
        text += (f", while the error floor of an estimator allowing arbitrary unknown inputs is below "
                 f"{FLOOR_SHARE:.0%} of X's width in every state: the bound is wide, not the model")  # fmt: skip
    if rec is Recommendation.SMOOTH_INPUT_MHE:
        text += "; an estimator assuming a smooth unknown input (small steps w[k+1] - w[k]) suits it"
    else:
        mode = a.random_walk.mode
        where = "" if a.random_walk.point is None else f" at {point_text(a.state_names, a.random_walk.point)}"
        text += (f"; the model with w as a random walk is not detectable either (its mode {complex_number(mode or 0j)} "
                 f"does not show in the outputs{where}), so no estimator here has a guarantee")  # fmt: skip
    return head + text
