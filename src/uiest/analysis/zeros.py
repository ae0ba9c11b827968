r"""Invariant zeros of the linearised model, and the ones sampling created.

The invariant zeros of ``[zI - A, -B; C, 0]`` (:func:`~uiest.detectability.invariant_zeros`) at each
linearisation point; the strong-detectability rate of any quadratic certificate is at least
``max |z|^2`` over them. Per unknown-input-to-output channel ``w_j -> y_i`` the zeros at the
reference point.

**Sampling zeros.** A continuous-time model sampled with the input held has, besides the images
``exp(s dt)`` of its own zeros s, zeros that sampling creates (r - 1 for a channel of relative
degree r; they tend to the roots of the Euler-Frobenius polynomial as dt -> 0,
:func:`~uiest.analysis.points.euler_frobenius_roots`). For a system from ``from_ode`` the
continuous model's zeros at the same point are mapped by ``exp(s dt)`` and paired with the
sampled model's zeros by least total distance (:func:`scipy.optimize.linear_sum_assignment`); the
sampled zeros left unpaired are the ones sampling created.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import expm
from scipy.optimize import linear_sum_assignment

from uiest.analysis.points import Linearisations, euler_frobenius_roots, relative_degrees
from uiest.box import FloatArray
from uiest.detectability.linear import invariant_zeros
from uiest.ode import rk4_grows
from uiest.system import System

__all__ = ["Channel", "Zero", "Zeros", "find_zeros"]

ComplexArray = NDArray[np.complex128]


@dataclass(frozen=True, kw_only=True)
class Zero:
    """One invariant zero.

    Attributes
    ----------
    value : complex
    from_sampling : bool or None
        Created by sampling (True), the image ``exp(s dt)`` of a zero s of the continuous model
        (False), or unknown: the model was not sampled by ``from_ode``, or, for a zero that is no such image, its
        integration step is unstable where the zero was found (None).
    limit : float or None
        For a channel's zero created by sampling: the Euler-Frobenius root it tends to as dt -> 0.
    unstable_step : bool
        The model's RK4 step grows where the ODE decays at the point of the zero (``System.from_ode`` warns): a
        zero that is not the image of a continuous one may come from the integrator, not from sampling the plant.
    exact : complex or None
        The zero of the continuous linearisation sampled exactly (:func:`exactly_sampled_zeros`) that this one pairs
        with, where they lie apart (:data:`DISCRETISATION_TOL`): the model's discretisation (its integrator, or the
        unknown input's direction fixed at X's centre) moved the zero, or, away from an equilibrium, the motion
        within a sample (which the frozen linearisation leaves out) does.

    """

    value: complex
    from_sampling: bool | None = None
    limit: float | None = None
    unstable_step: bool = False
    exact: complex | None = None

    @property
    def modulus(self) -> float:
        """``|value|``."""
        return abs(self.value)

    def to_dict(self) -> dict[str, object]:
        """Plain data for JSON."""
        return {"real": self.value.real, "imag": self.value.imag, "modulus": self.modulus,
                "from_sampling": self.from_sampling, "limit": self.limit, "unstable_step": self.unstable_step,
                "exact": None if self.exact is None else [self.exact.real, self.exact.imag]}  # fmt: skip


@dataclass(frozen=True, kw_only=True)
class Channel:
    """The channel from unknown input ``w_j`` to output ``y_i`` at the reference point.

    Attributes
    ----------
    input, output : str
        The names of w_j and y_i.
    steps : int or None
        Samples until w_j moves y_i (None: not within nx).
    continuous_degree : int or None
        The continuous model's relative degree of the channel (None: not sampled by ``from_ode``,
        or not reached within nx differentiations).
    zeros : tuple of Zero
        The channel's zeros, by decreasing modulus.

    """

    input: str
    output: str
    steps: int | None
    continuous_degree: int | None
    zeros: tuple[Zero, ...]

    def to_dict(self) -> dict[str, object]:
        """Plain data for JSON."""
        return {"input": self.input, "output": self.output, "steps": self.steps,
                "continuous_degree": self.continuous_degree, "zeros": [z.to_dict() for z in self.zeros]}  # fmt: skip


@dataclass(frozen=True, eq=False, kw_only=True)
class Zeros:
    """The linearised model's invariant zeros over the points, and its channels' zeros.

    Attributes
    ----------
    reference : tuple of Zero
        The zeros at the reference point (x0 or X's centre), by decreasing modulus.
    largest : Zero or None
        The zero of largest modulus over all points (None: no point has a zero).
    largest_at : ndarray (nx,) or None
        The state where it is.
    points : int
        Points searched.
    dropped : int
        Sampled points left out (a Jacobian not finite there).
    channels : tuple of Channel
        Every ``w_j -> y_i`` at the reference point (inputs outer, outputs inner).

    """

    reference: tuple[Zero, ...]
    largest: Zero | None
    largest_at: FloatArray | None
    points: int
    channels: tuple[Channel, ...]
    dropped: int = 0

    @property
    def largest_modulus(self) -> float:
        """``max |z|`` over the points (0 when there is no zero)."""
        return 0.0 if self.largest is None else self.largest.modulus

    def to_dict(self) -> dict[str, object]:
        """Plain data for JSON."""
        return {
            "reference": [z.to_dict() for z in self.reference],
            "largest": None if self.largest is None else self.largest.to_dict(),
            "largest_at": None if self.largest_at is None else self.largest_at.tolist(),
            "points": self.points,
            "dropped": self.dropped,
            "channels": [c.to_dict() for c in self.channels],
        }


def paired(found: ComplexArray, reference: ComplexArray) -> ComplexArray:
    """(len(found),) complex: the zero of ``reference`` paired with each of ``found`` (NaN where none is).

    Pairs minimise the total distance (an assignment).
    """
    pairs = np.full(len(found), complex(np.nan, np.nan))
    if len(found) and len(reference):
        rows, cols = linear_sum_assignment(np.abs(np.asarray(found)[:, None] - np.asarray(reference)[None, :]))
        pairs[rows] = np.asarray(reference)[cols]
    return pairs


def exactly_sampled_zeros(A_c: FloatArray, G: FloatArray, C: FloatArray, dt: float) -> ComplexArray:
    """The zeros of the continuous linearisation ``(A_c, G, C)`` sampled exactly (zero-order hold on w) every ``dt``."""
    n, m = G.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A_c * dt, G * dt
    E = expm(M)
    return invariant_zeros(E[:n, :n], E[:n, n:], C)


DISCRETISATION_TOL = (1e-3, 0.5)
"""A zero of the sampled model lies apart from the exactly sampled linearisation's (:attr:`Zero.exact`) where they
differ by more than the larger of the first and the second times the exact zero's distance to the unit circle
(``|1 - |z||``): then they disagree on how fast the zero's motion decays or grows."""


def _apart(z: complex, exact: complex) -> bool:
    absolute, relative = DISCRETISATION_TOL
    return bool(abs(z - exact) > max(absolute, relative * abs(1.0 - abs(exact))))


def _zeros_at(A: FloatArray, B: FloatArray, C: FloatArray, A_c: FloatArray | None, G: FloatArray | None,
              dt: float, degree: int | None = None, step: float | None = None) -> tuple[Zero, ...]:  # fmt: skip
    """The zeros of (A, B, C), classified against the continuous (A_c, G, C) when given.

    The ones sampling created get their Euler-Frobenius limits when the continuous relative degree is given.
    ``step``: the RK4 step of a model integrated by RK4; where it grows a decaying mode of ``A_c``, the zeros not
    paired with continuous ones are not attributed to sampling (:attr:`Zero.unstable_step`).
    """
    found = invariant_zeros(A, B, C)
    if A_c is None or G is None:
        return tuple(Zero(value=complex(z)) for z in found)
    sampling = np.isnan(paired(found, np.exp(invariant_zeros(A_c, G, C) * dt)))
    # a zero apart from the exactly sampled linearisation's: the discretisation (or the motion in a sample) moved it
    exact = paired(found, exactly_sampled_zeros(A_c, G, C, dt))
    moved = {i: complex(exact[i]) for i in range(len(found)) if np.isfinite(exact[i]) and _apart(found[i], exact[i])}
    if step is not None and rk4_grows(np.linalg.eigvals(A_c), step).any():
        return tuple(Zero(value=complex(z), from_sampling=None if sampling[i] else False, unstable_step=True,
                          exact=moved.get(i)) for i, z in enumerate(found))  # fmt: skip
    limits: dict[int, float] = {}
    roots = euler_frobenius_roots(degree) if degree else np.zeros(0)
    created = np.flatnonzero(sampling)
    if len(created) and len(roots):
        rows, cols = linear_sum_assignment(np.abs(found[created][:, None] - roots[None, :]))
        limits = {int(created[r]): float(roots[c]) for r, c in zip(rows, cols, strict=True)}
    return tuple(
        Zero(
            value=complex(z),
            from_sampling=bool(sampling[i]),
            limit=limits.get(i),
            exact=moved.get(i),
        )
        for i, z in enumerate(found)
    )


def find_zeros(system: System, lin: Linearisations) -> Zeros:
    """The zeros of ``system`` linearised at the points of ``lin`` (module docstring)."""
    dt = system.dt
    moduli = []
    for i in range(lin.count):
        z = invariant_zeros(lin.A[i], lin.B[i], lin.C[i])
        moduli.append(float(np.abs(z).max(initial=-1.0)))
    best = int(np.argmax(moduli))

    def continuous(i: int) -> tuple[FloatArray | None, FloatArray | None]:
        return (None, None) if lin.A_c is None or lin.G is None else (lin.A_c[i], lin.G[i])

    origin = system.sampled_from
    step = origin.substeps and dt / origin.substeps if origin is not None and origin.method == "rk4" else None
    reference = _zeros_at(lin.A[0], lin.B[0], lin.C[0], *continuous(0), dt, step=step)
    largest = largest_at = None
    if moduli[best] >= 0.0:
        largest = _zeros_at(lin.A[best], lin.B[best], lin.C[best], *continuous(best), dt, step=step)[0]
        largest_at = lin.x[best] * 1.0
    steps = relative_degrees(lin.A[:1], lin.B[:1], lin.C[:1])[0]
    degrees = None if lin.A_c is None or lin.G is None else relative_degrees(lin.A_c[:1], lin.G[:1], lin.C[:1])[0]
    channels = []
    for j, w_name in enumerate(system.w.names):
        for i, y_name in enumerate(system.y.names):
            degree = None if degrees is None or degrees[i, j] == 0 else int(degrees[i, j])
            A_c, G = continuous(0)
            zeros = _zeros_at(lin.A[0], lin.B[0][:, j : j + 1], lin.C[0][i : i + 1], A_c,
                              None if G is None else G[:, j : j + 1], dt, degree, step)  # fmt: skip
            channels.append(
                Channel(
                    input=w_name, output=y_name, steps=int(steps[i, j]) or None, continuous_degree=degree, zeros=zeros
                )
            )
    return Zeros(
        reference=reference,
        largest=largest,
        largest_at=largest_at,
        points=lin.count,
        channels=tuple(channels),
        dropped=lin.dropped,
    )
