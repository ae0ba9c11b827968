"""The analysis of one model as data (:class:`ModelAnalysis`), its text and its JSON form."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from uiest.analysis.designs import EstimatorDesign
from uiest.analysis.near_zeros import FrequencyMinimum, NearZeros
from uiest.analysis.random_walk import RandomWalkDetectability
from uiest.analysis.recommend import (
    Cause,
    Recommendation,
    amount,
    complex_number,
    frequency_text,
    number,
    point_text,
    reason,
)
from uiest.analysis.zeros import Zero, Zeros
from uiest.box import FloatArray

__all__ = ["ModelAnalysis"]


@dataclass(frozen=True, eq=False, kw_only=True)
class ModelAnalysis:
    """Which estimator a model admits and why: structure, zeros, near-zeros, certificates, recommendation.

    Made by :func:`uiest.analyse`. Coordinates: the state ``x (nx,)``; zeros are of the model
    linearised at sampled points of X x U (:mod:`uiest.analysis.points`).

    Attributes
    ----------
    system_name : str
    state_names, state_units, input_names, output_names, output_units : tuple of str
    dt : float
    time_unit : str
    continuous_method : str or None
        The integrator of the continuous-time model the system was sampled from (None: discrete-time).
    x_width : ndarray (nx,)
        X's width (the state scale where X is unbounded).
    x_bounded : bool
        Every side of X is finite (a certificate needs it).
    linear : bool
        The model's Jacobians are the same at every point linearised (a linear or affine model): its zeros are the
        model's, not one point's.
    reference : ndarray (nx,)
        The reference point (x0, or X's centre): the first linearisation point.
    rank_CB, rank_B : int
        Matching ranks (:func:`uiest.delay.matching_ranks`).
    steps : tuple of (int or None), one per unknown input
        Samples until the unknown input moves an output (the largest over the points; None: not within nx).
    continuous_degree : tuple of (int or None) or None
        The continuous model's relative degree of each unknown input (largest over the points; None
        without a continuous model).
    zeros : Zeros
    near_zeros : NearZeros
    random_walk : RandomWalkDetectability
        Whether the model with w as a random walk is detectable (what smooth-input estimators need).
    strong : EstimatorDesign
        The strong-detectability certificate and the UISE's guarantee.
    delayed : EstimatorDesign or None
        The same for the delayed UISE (None when matching holds: not needed).
    recommendation : Recommendation
    cause : Cause
    max_horizon : int
        The longest window considered.
    cpu_time : float
        CPU seconds (this thread) the analysis took.

    """

    system_name: str
    state_names: tuple[str, ...]
    state_units: tuple[str, ...]
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    output_units: tuple[str, ...]
    dt: float
    time_unit: str
    continuous_method: str | None
    x_width: FloatArray
    x_bounded: bool
    linear: bool
    reference: FloatArray
    rank_CB: int  # noqa: N815
    rank_B: int  # noqa: N815
    steps: tuple[int | None, ...]
    continuous_degree: tuple[int | None, ...] | None
    zeros: Zeros
    near_zeros: NearZeros
    random_walk: RandomWalkDetectability
    strong: EstimatorDesign
    delayed: EstimatorDesign | None
    recommendation: Recommendation
    cause: Cause
    max_horizon: int
    cpu_time: float

    @property
    def matching(self) -> bool:
        """``rank(C B) = rank(B)``: every unknown input shows in the next output."""
        return self.rank_CB == self.rank_B

    @property
    def sampling_zeros(self) -> tuple[Zero, ...]:
        """The zeros at the reference point that sampling created."""
        return tuple(z for z in self.zeros.reference if z.from_sampling)

    @property
    def reason(self) -> str:
        """The recommendation and why, in one sentence (:func:`uiest.analysis.recommend.reason`)."""
        return reason(self)

    # ------------------------------------------------------------------ text
    def _zeros_text(self, zeros: tuple[Zero, ...]) -> str:
        if not zeros:
            return "none"
        parts = []
        for z in zeros:
            notes = []
            if z.from_sampling is not None:
                notes.append("created by sampling" if z.from_sampling else "from the continuous model")
            elif z.unstable_step:
                notes.append("where the RK4 step grows a decaying mode: it may come from the integrator")
            if z.limit is not None:
                notes.append(f"{number(z.limit)} as dt -> 0")
            if z.exact is not None:
                notes.append(f"the continuous linearisation sampled exactly has it at {complex_number(z.exact)}: "
                             "the model's discretisation, or the motion within a sample away from an equilibrium, "
                             "moves it")  # fmt: skip
            parts.append(complex_number(z.value) + (f" ({'; '.join(notes)})" if notes else ""))
        return ", ".join(parts)

    def _minimum_text(self, label: str, minimum: FrequencyMinimum) -> str:
        return (f"  {label}: {minimum.sigma:.3g} at z = {complex_number(minimum.z)} ({frequency_text(minimum.z)}), "
                f"linearised at {point_text(self.state_names, minimum.point)}")  # fmt: skip

    def _design_text(self, design: EstimatorDesign, label: str) -> list[str]:
        cert = design.certificate
        if cert is None:
            return [f"{label}: not applicable: {design.not_applicable}"]
        if not design.certified:
            return [f"{label}: {cert.status}: {cert.reason}"]
        lines = [f"{label}: certified, mu = {number(cert.mu)} (mu_min = {number(cert.mu_min)}), cond(P) = "
                 f"{number(cert.condition)}, min horizon {design.min_horizon}"]  # fmt: skip
        if design.guarantee is not None:
            lines.append(f"  {design.estimator} with N = {design.N}: {design.guarantee.text}")
        return lines

    def text(self) -> str:
        """The analysis for display, one topic per block (derived from the data)."""
        n = len(self.state_names)
        sizes = (f"{n} state{'s' * (n != 1)}, {len(self.input_names)} unknown input{'s' * (len(self.input_names) != 1)}"
                 f", {len(self.output_names)} output{'s' * (len(self.output_names) != 1)}")  # fmt: skip
        every = f"every {self.dt:g} " + (self.time_unit if self.time_unit not in ("", "-") else "time units")
        sampled = (f"; sampled {every} from a continuous-time model ({self.continuous_method})"
                   if self.continuous_method else f"; discrete-time, dt = {self.dt:g} {self.time_unit}")  # fmt: skip
        lines = [f"{self.system_name}: {sizes}{sampled}", "structure"]
        shows = (
            "every unknown input shows in the next output"
            if self.matching
            else ("some unknown input directions do not show in the next output (matching fails)")
        )
        lines.append(f"  matching: rank(C B) = {self.rank_CB}, rank(B) = {self.rank_B}: {shows}")
        for j, name in enumerate(self.input_names):
            steps = self.steps[j]
            reach = (
                f"reaches an output after {steps} sample{'s' * (steps != 1)}"
                if steps
                else (f"does not reach an output within {n} samples")
            )
            degree = (
                ""
                if self.continuous_degree is None
                else (f" (continuous-time relative degree {self.continuous_degree[j]})")
            )
            lines.append(f"  {name}: {reach}{degree}")
        zeros = self.zeros
        left_out = f"; {zeros.dropped} left out: Jacobians not finite there" if zeros.dropped else ""
        lines.append(f"invariant zeros (the model linearised at {zeros.points} points of X x U{left_out})")
        reference = point_text(self.state_names, self.reference)
        lines.append(f"  at the reference point {reference}: {self._zeros_text(zeros.reference)}")
        if zeros.largest is not None and zeros.largest_at is not None:
            lines.append(f"  largest modulus {number(zeros.largest_modulus)}: {self._zeros_text((zeros.largest,))} at "
                         f"{point_text(self.state_names, zeros.largest_at)}")  # fmt: skip
        lines.append("channels w -> y at the reference point (samples until w moves y; zeros)")
        for c in zeros.channels:
            degree = "" if c.continuous_degree is None else f", continuous relative degree {c.continuous_degree}"
            reach = "not reached" if c.steps is None else f"{c.steps} sample{'s' * (c.steps != 1)}"
            lines.append(f"  {c.input} -> {c.output}: {reach}{degree}; zeros {self._zeros_text(c.zeros)}")
        near = self.near_zeros
        lines.append("near-zeros (smallest singular value of the scaled system matrix [zI - A, -B; C, 0] over its "
                     "largest)")  # fmt: skip
        lines.append(self._minimum_text("on |z| = 1", near.unit_circle))
        if near.ring is not None and near.ring_radius is not None:
            lines.append(self._minimum_text(f"on {number(near.ring_radius)} <= |z| <= 1 (sqrt(mu))", near.ring))
        if near.noise is None:
            lines.append("  error floor: not computed (V unbounded, or an output without its own noise)")
        else:

            def notes(f: float, w: float, z: complex | None) -> str:
                said = [] if z is None or z == near.floor_z else [f"at z = {complex_number(z)}"]
                said += ["more than X's width"] if f > w else []
                return f" ({', '.join(said)})" if said else ""

            floors = ", ".join(
                f"{name} {'unbounded' if np.isinf(f) else amount(f, unit)}{notes(f, w, z)}"
                for name, f, unit, w, z in zip(self.state_names, near.error_floor, self.state_units, self.x_width,
                                               near.state_z, strict=True)
            )  # fmt: skip
            where = "" if near.floor_z is None else f" at z = {complex_number(near.floor_z)}"
            lines.append(f"  error floor of any estimator allowing arbitrary unknown inputs{where}: {floors}")
        lines += self._design_text(self.strong, "strong detectability")
        if self.delayed is None:
            lines.append("delayed UISE: not needed (matching holds)")
        else:
            lines += self._design_text(self.delayed, "delayed system (relative degree 2)")
        walk = self.random_walk
        lines.append(
            "w as a random walk: "
            + (
                "detectable at every point"
                if walk.detectable
                else (
                    f"not detectable: mode {complex_number(walk.mode or 0j)} unseen at "
                    f"{point_text(self.state_names, walk.point if walk.point is not None else np.zeros(n))}"
                )
            )
        )
        lines.append(f"recommended: {self.reason}")
        lines.append(f"analysis: {self.cpu_time:.2f} s CPU")
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.text()

    def __repr__(self) -> str:
        return f"ModelAnalysis({self.system_name!r}: {self.recommendation.value}, {self.cause.name})"

    def to_dict(self) -> dict[str, object]:
        """Plain data for JSON (NaN and inf as floats)."""
        return {
            "system": self.system_name,
            "states": list(self.state_names),
            "state_units": list(self.state_units),
            "unknown_inputs": list(self.input_names),
            "outputs": list(self.output_names),
            "dt": self.dt,
            "time_unit": self.time_unit,
            "continuous_method": self.continuous_method,
            "x_width": self.x_width.tolist(),
            "x_bounded": self.x_bounded,
            "linear": self.linear,
            "reference": self.reference.tolist(),
            "rank_CB": self.rank_CB,
            "rank_B": self.rank_B,
            "matching": self.matching,
            "steps": list(self.steps),
            "continuous_degree": None if self.continuous_degree is None else list(self.continuous_degree),
            "zeros": self.zeros.to_dict(),
            "near_zeros": self.near_zeros.to_dict(),
            "random_walk": self.random_walk.to_dict(),
            "strong": self.strong.to_dict(),
            "delayed": None if self.delayed is None else self.delayed.to_dict(),
            "recommendation": self.recommendation.value,
            "cause": self.cause.name,
            "reason": self.reason,
            "max_horizon": self.max_horizon,
            "cpu_time_s": self.cpu_time,
        }
