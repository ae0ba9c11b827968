r"""The model linearised at sampled points of X x U, in scaled coordinates.

At each point ``(x, u)`` (the reference point first, then uniform samples of X x U; infinite
sides replaced by the centre +- the scale), with w at its nominal value and v at V's centre::

    A = S_x^-1 df/dx S_x,   B = S_x^-1 df/dw S_w,   C = S_y^-1 dh/dx S_x,   D = S_y^-1 dh/dv S_v

and, for a system sampled from a continuous-time model (:attr:`System.sampled_from
<uiest.system.System.sampled_from>`), the continuous Jacobians ``A_c = S_x^-1 dF/dx S_x`` and
``G = S_x^-1 dF/dw S_w`` at the same points. Zeros and relative degrees do not depend on the
scaling; the scaled matrices keep their numbers of one size.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb

import casadi as ca
import numpy as np

from uiest.box import FloatArray, as_vector
from uiest.checks import check_samples, check_seed
from uiest.detectability.lmi import batched, finite_box
from uiest.detectability.structure import RANK_RTOL
from uiest.errors import ModelError
from uiest.system import System

__all__ = ["POINTS", "Linearisations", "euler_frobenius_roots", "input_degrees", "linearise", "relative_degrees"]

POINTS = 32
"""Points of X x U at which the model is linearised (the reference point included)."""


@dataclass(frozen=True, eq=False, kw_only=True)
class Linearisations:
    """Jacobians at m points, scaled (module docstring); the first point is the reference point.

    Attributes
    ----------
    x : ndarray (m, nx)
    u : ndarray (m, nu)
    A : ndarray (m, nx, nx)
    B : ndarray (m, nx, nw)
    C : ndarray (m, ny, nx)
    D : ndarray (m, ny, nv)
    A_c, G : ndarray (m, nx, nx), (m, nx, nw), or None
        The continuous-time model's Jacobians (None unless the system was sampled by ``from_ode``).
    dropped : int
        Sampled points left out because a Jacobian was not finite there.

    """

    x: FloatArray
    u: FloatArray
    A: FloatArray
    B: FloatArray
    C: FloatArray
    D: FloatArray
    A_c: FloatArray | None
    G: FloatArray | None
    dropped: int

    @property
    def count(self) -> int:
        """Number of points m."""
        return len(self.x)


def linearise(system: System, reference: FloatArray | None = None, *, points: int = POINTS,
              seed: int = 0) -> Linearisations:  # fmt: skip
    """The scaled Jacobians of ``system`` at ``reference`` (default X's centre) and ``points - 1`` samples.

    Raises
    ------
    ModelError
        A Jacobian is not finite at the reference point.

    """
    points, seed = check_samples(points, "points"), check_seed(seed)
    rng = np.random.default_rng(seed)
    X = finite_box(system.x.bounds, system.x.bounds.center, system.x.scale)
    U = finite_box(system.u.bounds, system.u.bounds.center, system.u.scale)
    V = finite_box(system.v.bounds, system.v.bounds.center, system.v.scale)
    first = X.center if reference is None else as_vector(reference, system.nx, "x0")
    x = np.vstack([first, X.sample(rng, points - 1)])
    u = np.vstack([U.center, U.sample(rng, points - 1)])
    w = np.tile(system.nominal_w, (points, 1))
    v = np.tile(V.center, (points, 1))
    A, _, B, C, D = batched(system.jacobian_function, [x, u, w, v])
    continuous = system.sampled_from
    A_c = G = None
    if continuous is not None:
        xs, us, ws = (ca.SX.sym(s, n) for s, n in (("x", system.nx), ("u", system.nu), ("w", system.nw)))
        dx = continuous.rhs(xs, us, ws)
        jacobians = ca.Function("continuous", [xs, us, ws], [ca.jacobian(dx, xs), ca.jacobian(dx, ws)])
        A_c, G = batched(jacobians, [x, u, w])
    parts = [m for m in (A, B, C, D, A_c, G) if m is not None]
    finite = np.all([np.all(np.isfinite(m.reshape(points, -1)), axis=1) for m in parts], axis=0)
    if not finite[0]:
        raise ModelError(f"x0: the model's Jacobians are not finite at the reference point {first.tolist()}")
    sx, sw, sy, sv = system.x.scale, system.w.scale, system.y.scale, system.v.scale
    keep = np.flatnonzero(finite)

    def scaled(M: FloatArray, rows: FloatArray, cols: FloatArray) -> FloatArray:
        return M[keep] * cols[None, None, :] / rows[None, :, None]

    return Linearisations(
        x=x[keep], u=u[keep], A=scaled(A, sx, sx), B=scaled(B, sx, sw), C=scaled(C, sy, sx), D=scaled(D, sy, sv),
        A_c=None if A_c is None else scaled(A_c, sx, sx), G=None if G is None else scaled(G, sx, sw),
        dropped=int(points - len(keep)),
    )  # fmt: skip


def relative_degrees(A: FloatArray, B: FloatArray, C: FloatArray) -> np.ndarray:
    """Per point and channel, the smallest r with ``C A^(r-1) B != 0`` (0: not within nx steps).

    ``A (m, n, n)``, ``B (m, n, q)``, ``C (m, p, n)``; returns integers of shape (m, p, q). An entry
    counts as nonzero above ``RANK_RTOL |c_i| |A|^(r-1) |b_j|`` (2-norms), the tolerance of the
    matching test. For a discrete model r is the number of steps until ``w_j`` moves ``y_i``; for
    a continuous one, the number of times ``y_i`` is differentiated until ``w_j`` appears.
    """
    m, n, q = B.shape
    p = C.shape[1]
    degree = np.zeros((m, p, q), dtype=int)
    row = np.linalg.norm(C, axis=2)[:, :, None]
    column = np.linalg.norm(B, axis=1)[:, None, :]
    norm_A = np.linalg.norm(A, ord=2, axis=(1, 2))[:, None, None]
    power = B
    for r in range(1, n + 1):
        reached = np.abs(C @ power) > RANK_RTOL * row * column * norm_A ** (r - 1)
        degree = np.where((degree == 0) & reached, r, degree)
        power = A @ power
    return degree


def input_degrees(degrees: np.ndarray) -> tuple[int | None, ...]:
    """Per unknown input, the largest over the points of its smallest degree to any output (None: not reached).

    ``degrees`` (m, p, q) from :func:`relative_degrees`.
    """
    reached = np.where(degrees > 0, degrees, np.iinfo(int).max).min(axis=1)  # (m, q)
    worst = reached.max(axis=0)
    return tuple(None if d == np.iinfo(int).max else int(d) for d in worst)


def euler_frobenius_roots(r: int) -> FloatArray:
    """The r - 1 zeros that sampling a relative-degree-r channel creates, in the limit dt -> 0 (ascending).

    The roots of the Euler-Frobenius polynomial ``sum_k A(r, k) z^k`` with the Eulerian numbers
    ``A(r, k) = sum_{j<=k} (-1)^j binom(r+1, j) (k+1-j)^r`` (Astrom, Hagander, Sternby 1984):
    r = 2: -1; r = 3: -3.732, -0.268; r = 4: -9.899, -1, -0.101.
    """
    if r < 2:
        return np.zeros(0)
    coefficients = [sum((-1) ** j * comb(r + 1, j) * (k + 1 - j) ** r for j in range(k + 1)) for k in range(r)]
    return np.sort(np.roots(coefficients).real)
