r"""Near-zeros: frequencies at which an unknown input is nearly invisible in the outputs.

**The system matrix.** At each linearisation point (scaled coordinates, :mod:`uiest.analysis.points`)
the Rosenbrock matrix ``R(z) = [zI - A, -B_o; C, 0]``, with ``B_o`` an orthonormal basis of range(B)
times ``max(1, ||A||)`` (the zeros and this measure do not depend on how w is scaled). Its smallest
singular value over its largest, ``sigma(z)``, vanishes at an invariant zero; small values on the unit
circle ``|z| = 1`` (sustained oscillations) or in the ring ``sqrt(mu) <= |z| <= 1`` (modes decaying more
slowly than a certificate's rate mu allows) are near-zeros, also where several outputs leave no exact
zero.

**The noise amplification.** An unknown input ``w[k] = Re(omega z^k)`` with ``|z| = 1`` moves the
state by ``x[k] = Re(xi z^k)``, ``xi = (zI - A)^-1 B omega``, and the outputs by ``C xi``. With each output
disturbed by a noise of amplitude up to ``eps_i`` (half the range of ``dh/dv v`` over V, for an output
whose noise is its own), two such motions whose outputs differ by at most ``2 eps`` give the same
measurements, so any estimator that allows arbitrary unknown inputs errs on one of them by at least ::

    floor_i = max_omega |xi_i| / |diag(eps)^-1 C xi|     (state i's units)

the **error floor** reported: the largest over the frequencies and points, of the model linearised
there (a lower bound for small motions; it says nothing about motions that leave X). At an invariant zero ``z``
with ``|z| >= 1`` the motion ``xi z^k`` moves no output at all and does not decay: the floor is unbounded for the
states it moves (a linearisation's zero away from an equilibrium describes that linearisation only).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar

from uiest.analysis.points import Linearisations
from uiest.box import FloatArray
from uiest.detectability.linear import UNIT_CIRCLE_TOL, invariant_zeros
from uiest.system import System

__all__ = ["FrequencyMinimum", "NearZeros", "find_near_zeros"]

ANGLES = 721
"""Frequencies on the upper half of the unit circle (conjugates give the same values), ``0 .. pi``."""
RADII = 6
"""Circles between ``sqrt(mu)`` and 1 searched for the ring's minimum."""


@dataclass(frozen=True, kw_only=True)
class FrequencyMinimum:
    """Where ``sigma(z)`` (module docstring) is smallest over a region.

    Attributes
    ----------
    z : complex
    sigma : float
        Smallest singular value of the scaled system matrix over its largest, at z.
    point : ndarray (nx,)
        The linearisation point (state).

    """

    z: complex
    sigma: float
    point: FloatArray

    def to_dict(self) -> dict[str, object]:
        """Plain data for JSON."""
        return {"z": [self.z.real, self.z.imag], "sigma": self.sigma, "point": self.point.tolist()}


@dataclass(frozen=True, eq=False, kw_only=True)
class NearZeros:
    """The near-zeros of a model (module docstring).

    Attributes
    ----------
    unit_circle : FrequencyMinimum
        The smallest ``sigma(z)`` on ``|z| = 1``.
    ring : FrequencyMinimum or None
        The smallest over ``sqrt(mu) <= |z| <= 1`` for a certificate's rate mu (None without one).
    ring_radius : float or None
        ``sqrt(mu)``.
    noise : ndarray (ny,) or None
        ``eps``: each output's noise amplitude (y units); None where V is unbounded, an output has no
        noise or the noises mix (then there is no floor).
    error_floor : ndarray (nx,)
        The error floor per state (state units); NaN without ``noise``, inf at an exact zero on the circle.
    floor_z : complex or None
        The frequency at which the floor's largest share of X's width is reached.
    floor_point : ndarray (nx,) or None
        The linearisation point of ``floor_z``.
    state_z : tuple of complex or None, length nx
        The frequency at which each state's floor is reached; None without ``noise``, and for a state whose floor is
        the same at every frequency on the circle (a measured state's: its noise).
    state_point : tuple of ndarray (nx,) or None, length nx
        The linearisation point of each ``state_z``.

    """

    unit_circle: FrequencyMinimum
    ring: FrequencyMinimum | None
    ring_radius: float | None
    noise: FloatArray | None
    error_floor: FloatArray
    floor_z: complex | None
    floor_point: FloatArray | None
    state_z: tuple[complex | None, ...]
    state_point: tuple[FloatArray | None, ...]

    def to_dict(self) -> dict[str, object]:
        """Plain data for JSON (inf and NaN as floats)."""
        return {
            "unit_circle": self.unit_circle.to_dict(),
            "ring": None if self.ring is None else self.ring.to_dict(),
            "ring_radius": self.ring_radius,
            "noise": None if self.noise is None else self.noise.tolist(),
            "error_floor": [float(f) for f in self.error_floor],
            "floor_z": None if self.floor_z is None else [self.floor_z.real, self.floor_z.imag],
            "floor_point": None if self.floor_point is None else self.floor_point.tolist(),
            "state_z": [None if z is None else [z.real, z.imag] for z in self.state_z],
            "state_point": [None if x is None else x.tolist() for x in self.state_point],
        }


def _input_basis(A: FloatArray, B: FloatArray) -> FloatArray:
    """Orthonormal basis of range(B) times ``max(1, ||A||)``, shape (n, rank)."""
    if not B.size:
        return np.zeros((A.shape[0], 0))
    U, s, _ = np.linalg.svd(B, full_matrices=False)
    rank = int(np.sum(s > 1e-12 * s[0])) if s[0] > 0 else 0
    return U[:, :rank] * max(1.0, float(np.linalg.norm(A, 2)))


def sigma(A: FloatArray, Q: FloatArray, C: FloatArray, z: np.ndarray) -> FloatArray:
    """``sigma(z)`` (module docstring) for ``Q`` from :func:`_input_basis`, at every z of a 1-D array."""
    n, q, p = A.shape[0], Q.shape[1], C.shape[0]
    R = np.zeros((len(z), n + p, n + q), dtype=complex)
    R[:, :n, :n] = z[:, None, None] * np.eye(n) - A
    R[:, :n, n:] = -Q
    R[:, n:, :n] = C
    s = np.linalg.svd(R, compute_uv=False)
    return s[:, -1] / s[:, 0]


def _floor(
    A: FloatArray, Q: FloatArray, C_noise: FloatArray, scale: FloatArray, z: np.ndarray, unseen_rtol: float = 1e-14
) -> FloatArray:
    """The floor per state (state units) at each z: shape (len(z), nx); inf where the outputs do not move.

    An input direction moves no output where its outputs' motion is below ``unseen_rtol`` times the largest, or
    times what ``C_noise`` would show of its state motion.
    """
    n = A.shape[0]
    if not Q.shape[1]:  # no unknown input: nothing is hidden
        return np.zeros((len(z), n))
    floors = np.zeros((len(z), n))  # at an eigenvalue of A on the circle the input does not set the motion: no claim
    shifted = z[:, None, None] * np.eye(n) - A
    eigenvalues = np.linalg.eigvals(A)
    regular = np.min(np.abs(z[:, None] - eigenvalues[None, :]), axis=1, initial=np.inf) > 1e-9
    T = _solved(shifted[regular], Q)
    solved = np.all(np.isfinite(T), axis=(1, 2))  # zI - A singular to working precision: no claim either
    regular[regular] = solved
    T = T[solved]
    if not regular.any():
        return floors
    Y = C_noise @ T  # outputs over their noise amplitudes
    _, s, Vh = np.linalg.svd(Y, full_matrices=False)
    moved = T @ np.conj(np.swapaxes(Vh, 1, 2))  # each state's motion along each input direction
    shown = np.linalg.norm(C_noise, 2) * np.linalg.norm(moved, axis=1)  # what the outputs could show of it
    unseen = ~((s > unseen_rtol * s[:, :1]) & (s > unseen_rtol * shown))  # input directions that move no output
    inverse = np.where(unseen, 0.0, 1.0 / np.where(unseen, 1.0, s))
    # floor_i^2 = x_i (Y^H Y)^-1 x_i^H with x_i the i-th row of T (state units): |x_i V diag(1/s)|
    values = np.sqrt(np.sum(np.abs(moved * inverse[:, None, :]) ** 2, axis=2)) * scale[None, :]
    # a direction no output sees leaves the states it moves unbounded, and no others (a measured state's
    # motion along it is zero, to rounding)
    size = np.max(np.abs(T), axis=(1, 2), initial=0.0)[:, None, None]
    hidden = np.any(unseen[:, None, :] & (np.abs(moved) > UNSEEN_MOTION * size), axis=2)
    floors[regular] = np.where(hidden, np.inf, values)
    return floors


SAME_FLOOR = 1e-3
"""Two floors of a state within this share of each other are the same: a state's floor is named with the frequency
that sets the largest share where it reaches its own floor there, and with none where it is the same at every
frequency on the circle."""

ZERO_RTOL = 1e-8
"""At a computed invariant zero, the outputs' gain along the zero's input direction is rounding: below this share of
the largest it counts as none (:func:`invariant_zeros` finds zeros to a relative 1e-9)."""

UNSEEN_MOTION = 1e-9
"""A state moves along an input direction no output sees when its motion exceeds this share of the largest
(relative to ``|(zI - A)^-1 Q|``): below it the motion is rounding, and the direction bounds the state."""


class _Floor:
    """The error floor per state as frequencies and points are searched, with where each state's is reached."""

    def __init__(self, nx: int) -> None:
        self.value = np.zeros(nx)
        self.z: list[complex | None] = [None] * nx
        self.point: list[FloatArray | None] = [None] * nx

    def raise_to(self, floor: FloatArray, z: complex, point: FloatArray) -> None:
        """Take ``floor`` (nx,) at ``z`` and ``point`` where it is larger than the floor so far."""
        for i in np.flatnonzero(floor > self.value):
            self.value[i], self.z[i], self.point[i] = floor[i], z, point

    def unname_flat(self, floors: FloatArray, points: FloatArray) -> None:
        """No frequency for a state whose floor is reached at every frequency on the circle (to :data:`SAME_FLOOR`).

        ``floors`` (points, frequencies, nx), the floors on the circle at the linearisation ``points`` (points, nx).
        A measured state's floor is its noise at every frequency: the largest of them is no frequency of its own.
        """
        for i, point in enumerate(self.point):
            at = next((k for k in range(len(points)) if point is not None and np.array_equal(points[k], point)), None)
            if at is None:
                continue
            low, high = np.min(floors[at, :, i]), np.max(floors[at, :, i])
            if low >= (1.0 - SAME_FLOOR) * high > 0.0 and self.value[i] <= (1.0 + SAME_FLOOR) * high:
                self.z[i] = None

    def attribute(self, floor: FloatArray, z: complex, point: FloatArray) -> None:
        """Name ``z`` and ``point`` for the states whose floor ``floor`` (nx,) there reaches, to :data:`SAME_FLOOR`."""
        for i in np.flatnonzero(floor >= (1.0 - SAME_FLOOR) * self.value):
            self.z[i], self.point[i] = z, point


def _floor_at_outer_zeros(
    lin: Linearisations, bases: list[FloatArray], C_noise: list[FloatArray], scale: FloatArray, width: FloatArray,
    found: _Floor,
) -> tuple[complex, FloatArray, FloatArray] | None:  # fmt: skip
    """Raise ``found`` to the floor at the invariant zeros with ``|z| >= 1`` (module docstring).

    Returns the zero whose floor has the largest share of X's ``width``, with its point and that floor (nx,), or
    None where there is no such zero.
    """
    best, share = None, -1.0
    for i in range(lin.count):
        zeros = invariant_zeros(lin.A[i], lin.B[i], lin.C[i])
        for z in zeros[np.abs(zeros) >= 1.0 - UNIT_CIRCLE_TOL]:  # on the circle to rounding, or outside
            at = _floor(lin.A[i], bases[i], C_noise[i], scale, np.array([z]), unseen_rtol=ZERO_RTOL)[0]
            found.raise_to(at, complex(z), lin.x[i] * 1.0)
            if np.max(at / width) > share:
                share, best = float(np.max(at / width)), (complex(z), lin.x[i] * 1.0, at)
    return best


def _solved(M: np.ndarray, Q: FloatArray) -> np.ndarray:
    """``M[i]^-1 Q`` for each matrix of ``M`` (m, n, n); NaN for those singular to working precision."""
    rhs = np.broadcast_to(Q, (len(M), *Q.shape))
    try:
        return np.linalg.solve(M, rhs)
    except np.linalg.LinAlgError:  # e.g. a Jacobian of 1e28 where an explicit integrator is unstable
        out = np.full(rhs.shape, np.nan, dtype=np.result_type(M, Q))
        for i, matrix in enumerate(M):
            with contextlib.suppress(np.linalg.LinAlgError):
                out[i] = np.linalg.solve(matrix, Q)
        return out


def output_noise(system: System, D: FloatArray) -> FloatArray | None:
    """``eps`` (y units) from the scaled ``dh/dv`` at the reference point, or None (:class:`NearZeros`)."""
    V = system.v.bounds
    nonzero = D != 0
    if not (np.all(np.isfinite(V.width)) and np.all(nonzero.sum(axis=1) == 1) and np.all(nonzero.sum(axis=0) <= 1)):
        return None
    eps = 0.5 * system.y.scale * (np.abs(D) @ (V.width / system.v.scale))  # D = S_y^-1 dh/dv S_v
    return eps if np.all(eps > 0) else None


def _refine(objective: Callable[[float], float], angles: FloatArray, best: int) -> float:
    """The angle minimising ``objective(theta)`` between the grid neighbours of ``angles[best]``."""
    low, high = angles[max(best - 1, 0)], angles[min(best + 1, len(angles) - 1)]
    if high <= low:
        return float(angles[best])
    found = minimize_scalar(objective, bounds=(low, high), method="bounded", options={"xatol": 1e-10})
    return float(found.x) if found.fun <= objective(float(angles[best])) else float(angles[best])


def find_near_zeros(system: System, lin: Linearisations, rate: float | None = None) -> NearZeros:
    """The near-zeros of ``system`` at the points of ``lin`` (module docstring); ``rate`` a certificate's mu."""
    angles = np.linspace(0.0, np.pi, ANGLES)
    circle = np.exp(1j * angles)
    bases = [_input_basis(lin.A[i], lin.B[i]) for i in range(lin.count)]
    sigmas = np.array([sigma(lin.A[i], bases[i], lin.C[i], circle) for i in range(lin.count)])
    point, k = np.unravel_index(int(np.argmin(sigmas)), sigmas.shape)
    A, Q, C = lin.A[point], bases[point], lin.C[point]
    theta = _refine(lambda t: float(sigma(A, Q, C, np.array([np.exp(1j * t)]))[0]), angles, int(k))
    z = complex(np.exp(1j * theta))
    unit = FrequencyMinimum(z=z, sigma=float(sigma(A, Q, C, np.array([z]))[0]), point=lin.x[point] * 1.0)

    ring = radius = None
    if rate is not None and np.isfinite(rate) and 0.0 < rate < 1.0:
        radius = float(np.sqrt(rate))
        grid = (np.linspace(radius, 1.0, RADII)[:, None] * np.exp(1j * angles[::4])[None, :]).ravel()
        values = np.array([sigma(lin.A[i], bases[i], lin.C[i], grid) for i in range(lin.count)])
        p, j = np.unravel_index(int(np.argmin(values)), values.shape)
        ring = FrequencyMinimum(z=complex(grid[j]), sigma=float(values[p, j]), point=lin.x[p] * 1.0)

    eps = output_noise(system, lin.D[0])
    found = _Floor(system.nx)
    floor_z = floor_point = None
    if eps is not None:
        C_noise = [lin.C[i] * (system.y.scale / eps)[:, None] for i in range(lin.count)]
        width = np.where(np.isfinite(system.x.bounds.width), system.x.bounds.width, system.x.scale)
        floors = np.array([_floor(lin.A[i], bases[i], C_noise[i], system.x.scale, circle) for i in range(lin.count)])
        for i in range(lin.count):
            for j in np.unique(np.argmax(floors[i], axis=0)):
                found.raise_to(floors[i, j], complex(circle[j]), lin.x[i] * 1.0)
        share = np.max(floors / width[None, None, :], axis=2)
        p, j = np.unravel_index(int(np.argmax(share)), share.shape)
        A, Q = lin.A[p], bases[p]

        def negative_share(t: float) -> float:
            value = _floor(A, Q, C_noise[p], system.x.scale, np.array([np.exp(1j * t)]))[0] / width
            return -float(np.max(value))

        theta = _refine(negative_share, angles, int(j)) if np.isfinite(share[p, j]) else float(angles[j])
        floor_z = complex(np.exp(1j * theta))
        floor_point = lin.x[p] * 1.0
        at_floor_z = _floor(A, Q, C_noise[p], system.x.scale, np.array([floor_z]))[0]
        found.raise_to(at_floor_z, floor_z, floor_point)
        on_circle = float(np.max(found.value / width))
        outside = _floor_at_outer_zeros(lin, bases, C_noise, system.x.scale, width, found)
        if outside is not None and np.max(found.value / width) > on_circle:
            floor_z, floor_point, at_floor_z = outside
        found.attribute(at_floor_z, floor_z, floor_point)
        found.unname_flat(floors, lin.x)
    return NearZeros(
        unit_circle=unit,
        ring=ring,
        ring_radius=radius,
        noise=eps,
        error_floor=found.value if eps is not None else np.full(system.nx, np.nan),
        floor_z=floor_z,
        floor_point=floor_point,
        state_z=tuple(found.z),
        state_point=tuple(found.point),
    )
