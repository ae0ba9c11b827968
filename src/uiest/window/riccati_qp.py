r"""A stage-wise convex QP solved by a primal-dual interior point whose Newton systems are a Riccati recursion.

The QP has ``N + 1`` stages ``k = 0 .. N``; stage ``k`` owns the variables ``z_k`` (``n_k`` of them, contiguous
in ``z``), whose first ``nx`` entries are the stage's state ``x_k``. It reads::

    min   sum_k  1/2 z_k^T H_k z_k + q_k^T z_k
    s.t.  x_{k+1} = A_k z_k + b_k                         k = 0 .. N-1   (A_k: (nx, n_k))
          lb_k <= z_k <= ub_k,   lc_k <= C_k z_k <= uc_k   k = 0 .. N     (C_k: (nc_k, n_k))

(infinite sides absent). This is the Gauss-Newton QP of a multiple-shooting window (see
:mod:`uiest.window.problem`: stage ``k`` is ``[x_k, v_k, w_k]``, the residuals and the curvature are
stage-local, so ``H`` is block diagonal, and the dynamics couple stage ``k`` only to ``x_{k+1}``).

Each interior-point iteration (Mehrotra's predictor-corrector) eliminates the slacks and the inequality
multipliers, which adds ``Sigma = lambda / s`` to the stage Hessians, and solves the remaining
equality-constrained QP by a backward Riccati recursion over the stages: with the cost-to-go
``V_{k+1}(x) = 1/2 x^T P_{k+1} x + p_{k+1}^T x``, stage ``k`` minimises
``1/2 z^T M z + m^T z`` over its non-state part, ``M = H_k + A_k^T P_{k+1} A_k``, by a Cholesky
factorisation of that part's block, and passes the Schur complement on as ``P_k``; ``x_0`` is found
last. Work and memory are ``O(N)``. The recursion succeeds if and only if the barrier-augmented Hessian is
positive definite on the null space of the dynamics; where it is not (a direction the cost leaves flat
and no bound holds), the solve returns :attr:`QPStatus.SINGULAR` (add a regularisation and solve again).

Multipliers follow CasADi's sign convention for the Lagrangian ``1/2 z^T H z + q^T z + lam_x^T z +
lam_dyn^T (A z + b - x_next) + lam_c^T C z``: ``lam_x > 0`` where an upper bound is active, ``< 0`` at a lower
one (likewise ``lam_c``), and ``lam_dyn[k]`` is the gradient of the cost-to-go at ``x_{k+1}``.

The kernel is compiled by numba with an on-disk cache (``cache=True``): the first call in a fresh
environment compiles it (a few seconds, see ``docs/design-notes/riccati-qp.md``), later processes load it.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numba
import numpy as np
import numpy.typing as npt

from uiest.box import FloatArray
from uiest.errors import OptionError

IntArray = npt.NDArray[np.int64]


__all__ = [
    "CROSSOVER_BELOW",
    "DEFAULT_MAX_ITER",
    "DEFAULT_TOL",
    "QPStatus",
    "StageKernel",
    "StageLayout",
    "StageQPSolution",
    "solve_stage_qp",
]


class QPStatus(enum.IntEnum):
    """Outcome of :func:`solve_stage_qp`."""

    SOLVED = 0
    """The KKT conditions hold to the tolerance."""
    ITERATION_LIMIT = 1
    """The iteration limit came first."""
    SINGULAR = 2
    """A Riccati factorisation met a pivot that is not positive: the QP is not strictly convex on the dynamics'
    null space (an unbounded flat direction); regularise it."""
    CROSSED_BOUNDS = 3
    """A lower bound exceeds its upper bound: the QP is infeasible."""
    DIVERGED = 4
    """The iterates or multipliers grew beyond any meaningful size: the QP is infeasible or unbounded."""
    NOT_FINITE = 5
    """The data or an iterate hold NaN or infinite entries where finite ones are expected."""


@dataclass(frozen=True)
class StageLayout:
    """The sizes of a stage-wise QP.

    Parameters
    ----------
    nx : int
        State dimension (the first ``nx`` variables of each stage).
    stage_sizes : array_like of int, shape (N + 1,)
        ``n_k >= nx``: the variables of stage ``k``.
    constraint_sizes : array_like of int, shape (N + 1,), optional
        ``nc_k``: the general inequality rows of stage ``k`` (default none).

    Attributes
    ----------
    n_var, n_con : int
        Totals of the stage sizes and constraint sizes; ``n_dyn = N nx``.
    z_offset, h_offset, a_offset, c_offset, con_offset : ndarray of int
        Start of stage ``k`` in ``z``, in the packed Hessians (row-major ``n_k x n_k`` blocks), in the
        packed dynamics (``nx x n_k``, stages 0..N-1), in the packed constraint rows (``nc_k x n_k``)
        and in the constraint vector; each has ``N + 2`` entries (the last one is the total).

    """

    nx: int
    stage_sizes: IntArray
    constraint_sizes: IntArray

    def __init__(self, nx: int, stage_sizes: npt.ArrayLike, constraint_sizes: npt.ArrayLike | None = None) -> None:
        sizes = np.asarray(stage_sizes, dtype=np.int64).reshape(-1)
        if isinstance(nx, bool) or not isinstance(nx, int | np.integer) or nx < 0:
            raise OptionError(f"nx: expected a non-negative integer, got {nx!r}")
        if sizes.size == 0 or np.any(sizes < nx):
            raise OptionError(f"stage_sizes: expected at least one stage, each of size >= nx = {nx}, got {sizes}")
        cons = np.zeros_like(sizes) if constraint_sizes is None else np.asarray(constraint_sizes, dtype=np.int64)
        if cons.shape != sizes.shape or np.any(cons < 0):
            raise OptionError(f"constraint_sizes: expected {sizes.size} non-negative integers, got {cons}")
        object.__setattr__(self, "nx", int(nx))
        object.__setattr__(self, "stage_sizes", sizes)
        object.__setattr__(self, "constraint_sizes", cons)

    @property
    def n_stages(self) -> int:
        """``N + 1``."""
        return int(self.stage_sizes.size)

    @property
    def n_var(self) -> int:
        """Number of variables."""
        return int(self.stage_sizes.sum())

    @property
    def n_con(self) -> int:
        """Number of general inequality rows."""
        return int(self.constraint_sizes.sum())

    @property
    def n_dyn(self) -> int:
        """Number of dynamics rows ``N nx``."""
        return (self.n_stages - 1) * self.nx

    @property
    def z_offset(self) -> IntArray:
        """Start of each stage in ``z`` (and the total)."""
        return _offsets(self.stage_sizes)

    @property
    def h_offset(self) -> IntArray:
        """Start of each stage's Hessian block in the packed Hessians."""
        return _offsets(self.stage_sizes**2)

    @property
    def a_offset(self) -> IntArray:
        """Start of each stage's dynamics block (stages 0..N-1; the last stage's is empty)."""
        sizes = self.nx * self.stage_sizes.copy()
        sizes[-1] = 0
        return _offsets(sizes)

    @property
    def c_offset(self) -> IntArray:
        """Start of each stage's constraint block in the packed constraint rows."""
        return _offsets(self.constraint_sizes * self.stage_sizes)

    @property
    def con_offset(self) -> IntArray:
        """Start of each stage's rows in the constraint vector."""
        return _offsets(self.constraint_sizes)

    def kernel_sizes(
        self,
    ) -> tuple[np.int64, IntArray, IntArray, IntArray, IntArray, IntArray, IntArray, IntArray]:
        """The compiled kernel's size arguments: ``nx``, the stage sizes and the offsets, in its order."""
        return (
            np.int64(self.nx),
            self.stage_sizes,
            self.z_offset,
            self.h_offset,
            self.a_offset,
            self.constraint_sizes,
            self.c_offset,
            self.con_offset,
        )


def _offsets(sizes: IntArray) -> IntArray:
    return np.concatenate(([0], np.cumsum(sizes))).astype(np.int64)


@dataclass(frozen=True, kw_only=True)
class StageQPSolution:
    """The result of :func:`solve_stage_qp`.

    Attributes
    ----------
    z : ndarray (n_var,)
        The minimiser (the last iterate unless ``status`` is SOLVED).
    lam_x : ndarray (n_var,)
        Bound multipliers (> 0 upper side active, < 0 lower). Unless ``exact_active_set``, the interior iterate's
        on the rows of its active-set estimate (``active_set``) and zero on the others, so that their signs are
        that estimate (a guess for the next, similar QP).
    lam_dyn : ndarray (N, nx)
        Multipliers of ``A_k z_k + b_k - x_{k+1} = 0``.
    lam_c : ndarray (n_con,)
        Multipliers of the general inequality rows (sign and zeros as ``lam_x``).
    cost : float
        ``1/2 z^T (H + regularisation I) z + q^T z``.
    status : QPStatus
    iterations : int
        Interior-point iterations.
    residual : float
        The interior point's largest scaled KKT residual (stationarity, dynamics, bounds, complementarity) at its
        last iterate.
    exact_active_set : bool
        Whether ``z`` and the multipliers are the exact solution of an active set (its rows held as equalities,
        optimality checked to ``tol``), rather than the last interior iterate.
    active_set : ndarray (n_var + n_con,)
        -1 / 0 / +1 per inequality row (the bounds, then the general rows): lower side active, free, upper side
        active; a ``guess`` for the next, similar QP.
    active_set_steps : int
        Primal-dual active-set steps taken from the ``guess`` (0 without one).

    """

    z: FloatArray
    lam_x: FloatArray
    lam_dyn: FloatArray
    lam_c: FloatArray
    cost: float
    status: QPStatus
    iterations: int
    residual: float
    exact_active_set: bool
    active_set: FloatArray
    active_set_steps: int

    @property
    def solved(self) -> bool:
        """Whether ``status`` is SOLVED."""
        return self.status is QPStatus.SOLVED


DEFAULT_TOL = 1e-11
"""Interior-point stopping tolerance on the scaled KKT residuals and the mean complementarity."""

DEFAULT_MAX_ITER = 60
"""Interior-point iterations per solve."""

_NO_GUESS = np.zeros(0)


def solve_stage_qp(
    layout: StageLayout,
    H: npt.ArrayLike,
    q: npt.ArrayLike,
    A: npt.ArrayLike,
    b: npt.ArrayLike,
    lb: npt.ArrayLike,
    ub: npt.ArrayLike,
    C: npt.ArrayLike | None = None,
    lc: npt.ArrayLike | None = None,
    uc: npt.ArrayLike | None = None,
    *,
    regularisation: float = 0.0,
    tol: float = DEFAULT_TOL,
    max_iter: int = DEFAULT_MAX_ITER,
    guess: npt.ArrayLike | None = None,
) -> StageQPSolution:
    """Solve the stage-wise QP of the module docstring.

    Parameters
    ----------
    layout : StageLayout
    H : array_like, shape (sum n_k^2,)
        The stage Hessians ``H_k`` (symmetric positive semidefinite), row-major, stage after stage.
    q : array_like, shape (n_var,)
    A : array_like, shape (sum_{k<N} nx n_k,)
        The dynamics blocks ``A_k``, row-major, stage after stage.
    b : array_like, shape (N nx,)
        ``b_k`` stacked.
    lb, ub : array_like, shape (n_var,)
        Bounds on ``z`` (``-inf``/``inf``: none).
    C : array_like, shape (sum nc_k n_k,), optional
        The stage constraint rows ``C_k``, row-major, stage after stage (required when ``layout.n_con > 0``).
    lc, uc : array_like, shape (n_con,), optional
        Their bounds.
    regularisation : float
        Added to every diagonal entry of ``H`` (>= 0).
    tol : float
        Stopping tolerance (> 0).
    max_iter : int
        Interior-point iterations (>= 1).
    guess : array_like, shape (n_var + n_con,), optional
        An active set to try first (-1 / 0 / +1 per row, as :attr:`StageQPSolution.active_set`): up to
        :data:`_ACTIVE_SET_ROUNDS` primal-dual active-set steps from it, each one Riccati factorisation; the
        interior point runs only if they do not reach the optimum.

    Returns
    -------
    StageQPSolution
        Never raises for an infeasible, unbounded or singular QP: its ``status`` says so.

    """
    n, nc = layout.n_var, layout.n_con
    arrays = {
        "H": (H, int((layout.stage_sizes**2).sum())),
        "q": (q, n),
        "A": (A, int(layout.a_offset[-1])),
        "b": (b, layout.n_dyn),
        "lb": (lb, n),
        "ub": (ub, n),
        "C": (np.zeros(0) if C is None else C, int(layout.c_offset[-1])),
        "lc": (np.zeros(0) if lc is None else lc, nc),
        "uc": (np.zeros(0) if uc is None else uc, nc),
    }
    data = {}
    for name, (value, size) in arrays.items():
        arr = np.ascontiguousarray(value, dtype=float).reshape(-1)
        if arr.size != size:
            raise OptionError(f"{name}: expected {size} values for this layout, got {arr.size}")
        data[name] = arr
    if not (math.isfinite(regularisation) and regularisation >= 0.0):
        raise OptionError(f"regularisation: expected a finite number >= 0, got {regularisation!r}")
    if not (math.isfinite(tol) and tol > 0.0):
        raise OptionError(f"tol: expected a finite number > 0, got {tol!r}")
    if isinstance(max_iter, bool) or not isinstance(max_iter, int | np.integer) or max_iter < 1:
        raise OptionError(f"max_iter: expected an integer >= 1, got {max_iter!r}")
    start = None
    if guess is not None:
        start = np.ascontiguousarray(guess, dtype=float).reshape(-1)
        if start.size != n + nc or not np.isin(start, (-1.0, 0.0, 1.0)).all():
            raise OptionError(f"guess: expected {n + nc} entries from -1, 0, 1, got {np.asarray(guess).tolist()}")
    kernel = StageKernel(layout)
    return kernel.solve(
        **data, regularisation=float(regularisation), tol=float(tol), max_iter=int(max_iter), guess=start
    )


class StageKernel:
    """:func:`solve_stage_qp` without the argument checks, for a layout solved again and again."""

    def __init__(self, layout: StageLayout) -> None:
        self.layout = layout
        self._sizes = layout.kernel_sizes()
        self._counts = (layout.n_var, layout.n_dyn, layout.n_con, layout.n_stages, layout.nx)  # computed once

    def solve(
        self,
        H: FloatArray,
        q: FloatArray,
        A: FloatArray,
        b: FloatArray,
        lb: FloatArray,
        ub: FloatArray,
        C: FloatArray,
        lc: FloatArray,
        uc: FloatArray,
        regularisation: float = 0.0,
        tol: float = DEFAULT_TOL,
        max_iter: int = DEFAULT_MAX_ITER,
        guess: FloatArray | None = None,
    ) -> StageQPSolution:
        """Solve with contiguous float arrays of the sizes :func:`solve_stage_qp` checks."""
        n_var, n_dyn, n_con, n_stages, nx = self._counts
        z = np.zeros(n_var)
        lam_x = np.zeros(n_var)
        lam_dyn = np.zeros(n_dyn)
        lam_c = np.zeros(n_con)
        info = np.zeros(5)
        side = np.zeros(n_var + n_con)
        start = _NO_GUESS if guess is None else guess
        code = _ipm(*self._sizes, H, q, A, b, lb, ub, C, lc, uc, regularisation, tol, max_iter, start,
                    z, lam_x, lam_dyn, lam_c, side, info)  # fmt: skip
        return StageQPSolution(
            z=z,
            lam_x=lam_x,
            lam_dyn=lam_dyn.reshape(n_stages - 1, nx),
            lam_c=lam_c,
            cost=float(info[0]),
            status=QPStatus(code),
            iterations=int(info[1]),
            residual=float(info[2]),
            exact_active_set=bool(info[3]),
            active_set=side,
            active_set_steps=int(info[4]),
        )


# ---------------------------------------------------------------------- compiled kernel
_FASTMATH = {"reassoc", "contract", "nsz", "arcp"}
"""LLVM's fast-math flags the kernel allows: reordered sums and fused multiply-adds, but not ``nnan``/``ninf``
(absent bounds are infinite, and the kernel tests for NaN)."""

# Dense helpers on small row-major blocks; the kernel allocates its workspace once per call.

_BIG = 1e20
"""Iterates or multipliers beyond this (relative to the data's size) mean an infeasible or unbounded QP."""

_PENALTY = 1e6
"""The active rows' penalty in :func:`_solve_active`, relative to the largest Hessian entry."""

_MULTIPLIER_ROUNDS = 5
"""Multiplier updates :func:`_solve_active` tries before it gives up on an active set."""

_START_SLACK = 0.1
"""Smallest starting slack of a bound (scaled units); the interior point starts from ``z = 0``, multipliers 1."""

_ACTIVE_SET_ROUNDS = 3
"""Primal-dual active-set steps tried from a guessed active set before the interior point (fewer when a step
changes as many rows as the one before)."""

CROSSOVER_BELOW = 1e-6
"""The interior point tries its active set's exact solution (:func:`_crossover`) once its residual is below this."""


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _cholesky(M: FloatArray, moff: int, stride: int, n: int, L: FloatArray, loff: int) -> bool:  # pragma: no cover
    """Lower Cholesky factor of ``M[moff + r * stride + c]`` (r, c < n) into ``L[loff + r * n + c]``.

    False if a pivot is not positive.
    """
    for j in range(n):
        s = M[moff + j * stride + j]
        for k in range(j):
            s -= L[loff + j * n + k] * L[loff + j * n + k]
        if not (s > 0.0):
            return False
        d = math.sqrt(s)
        L[loff + j * n + j] = d
        for i in range(j + 1, n):
            t = M[moff + i * stride + j]
            for k in range(j):
                t -= L[loff + i * n + k] * L[loff + j * n + k]
            L[loff + i * n + j] = t / d
        for i in range(j):
            L[loff + i * n + j] = 0.0
    return True


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _chol_solve(L: FloatArray, loff: int, n: int, x: FloatArray, xoff: int) -> None:  # pragma: no cover
    """``x[xoff : xoff + n] <- (L L^T)^{-1} x[xoff : xoff + n]`` in place, ``L`` at ``loff``."""
    for i in range(n):
        t = x[xoff + i]
        for k in range(i):
            t -= L[loff + i * n + k] * x[xoff + k]
        x[xoff + i] = t / L[loff + i * n + i]
    for i in range(n - 1, -1, -1):
        t = x[xoff + i]
        for k in range(i + 1, n):
            t -= L[loff + k * n + i] * x[xoff + k]
        x[xoff + i] = t / L[loff + i * n + i]


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _factor(nx, N1, nz, ho, ao, A, Hm, M, L, K, P, Lx, W):  # pragma: no cover (compiled)
    """Backward Riccati factorisation of the Newton matrix; False where a pivot is not positive.

    Stage k: ``M_k = Hm_k + A_k^T P_{k+1} A_k`` (row-major, at ``ho[k]``), the Cholesky factor of its input
    block ``M_uu`` in ``L`` (``nu x nu``, at ``ho[k]``), ``K_k = M_uu^{-1} M_ux`` (row-major ``nu x nx`` at
    ``ho[k]``), ``P_k`` (``nx x nx`` at ``k nx^2``); ``Lx`` the Cholesky factor of ``P_0``. ``W``: scratch of
    at least ``nx max(n_k) + max(n_k)`` entries.
    """
    for k in range(N1 - 1, -1, -1):
        n = nz[k]
        nu = n - nx
        h0 = ho[k]
        for i in range(n * n):
            M[h0 + i] = Hm[h0 + i]
        if k < N1 - 1:
            a0 = ao[k]
            p1 = (k + 1) * nx * nx
            for r in range(nx):  # W = P_{k+1} A_k, (nx, n)
                for c in range(n):
                    s = 0.0
                    for j in range(nx):
                        s += P[p1 + r * nx + j] * A[a0 + j * n + c]
                    W[r * n + c] = s
            for r in range(n):
                for c in range(r, n):
                    s = 0.0
                    for j in range(nx):
                        s += A[a0 + j * n + r] * W[j * n + c]
                    M[h0 + r * n + c] += s
                    if c != r:
                        M[h0 + c * n + r] += s
        pk = k * nx * nx
        if nu > 0:
            if not _cholesky(M, h0 + nx * n + nx, n, nu, L, h0):
                return False
            col = nx * n  # K = M_uu^{-1} M_ux, column by column, through W[col : col + nu]
            for c in range(nx):
                for r in range(nu):
                    W[col + r] = M[h0 + (nx + r) * n + c]
                _chol_solve(L, h0, nu, W, col)
                for r in range(nu):
                    K[h0 + r * nx + c] = W[col + r]
            for r in range(nx):
                for c in range(r, nx):
                    s = M[h0 + r * n + c]
                    for j in range(nu):
                        s -= M[h0 + r * n + nx + j] * K[h0 + j * nx + c]
                    P[pk + r * nx + c] = s
                    P[pk + c * nx + r] = s
        else:
            for r in range(nx):
                for c in range(nx):
                    P[pk + r * nx + c] = M[h0 + r * n + c]
    if nx > 0:
        return _cholesky(P, 0, nx, nx, Lx, 0)
    return True


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _riccati_solve(nx, N1, nz, zo, ho, ao, A, M, L, K, P, Lx, rq, b, dz, pi, W, p):  # pragma: no cover
    """Solve ``min 1/2 dz^T Hm dz + rq^T dz`` s.t. ``x_{k+1} = A_k z_k + b_k`` with the factors of :func:`_factor`.

    Writes ``dz`` and the dynamics multipliers ``pi`` (``N nx``). ``W``: scratch of at least
    ``max(n_k) + nx`` entries; ``p``: scratch of ``(N + 1) nx`` (the cost-to-go's gradients). The input parts of
    ``dz`` hold ``M_uu^{-1} m_u`` between the sweeps.
    """
    for k in range(N1 - 1, -1, -1):
        n = nz[k]
        nu = n - nx
        h0 = ho[k]
        z0 = zo[k]
        for i in range(n):  # m = rq_k + A_k^T (P_{k+1} b_k + p_{k+1}) in W[:n]
            W[i] = rq[z0 + i]
        if k < N1 - 1:
            a0 = ao[k]
            p1 = (k + 1) * nx * nx
            for r in range(nx):
                s = p[(k + 1) * nx + r]
                for j in range(nx):
                    s += P[p1 + r * nx + j] * b[k * nx + j]
                W[n + r] = s
            for c in range(n):
                s = 0.0
                for j in range(nx):
                    s += A[a0 + j * n + c] * W[n + j]
                W[c] += s
        if nu > 0:
            for r in range(nu):
                dz[z0 + nx + r] = W[nx + r]
            _chol_solve(L, h0, nu, dz, z0 + nx)
            for r in range(nx):
                s = W[r]
                for j in range(nu):
                    s -= M[h0 + r * n + nx + j] * dz[z0 + nx + j]
                p[k * nx + r] = s
        else:
            for r in range(nx):
                p[k * nx + r] = W[r]
    for r in range(nx):  # x_0 = -P_0^{-1} p_0, into dz's first stage
        dz[r] = -p[r]
    if nx > 0:
        _chol_solve(Lx, 0, nx, dz, 0)
    for k in range(N1):
        n = nz[k]
        nu = n - nx
        h0 = ho[k]
        z0 = zo[k]
        for r in range(nu):
            s = dz[z0 + nx + r]
            for c in range(nx):
                s += K[h0 + r * nx + c] * dz[z0 + c]
            dz[z0 + nx + r] = -s
        if k < N1 - 1:
            a0 = ao[k]
            p1 = (k + 1) * nx * nx
            z1 = zo[k + 1]
            for r in range(nx):
                s = b[k * nx + r]
                for c in range(n):
                    s += A[a0 + r * n + c] * dz[z0 + c]
                dz[z1 + r] = s
            for r in range(nx):
                s = p[(k + 1) * nx + r]
                for j in range(nx):
                    s += P[p1 + r * nx + j] * dz[z1 + j]
                pi[k * nx + r] = s


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _constraint_rows(nx, N1, nz, zo, ncs, co, cro, C, z, out):  # pragma: no cover
    """``out = C z`` (the general rows, stage by stage)."""
    for k in range(N1):
        n = nz[k]
        for r in range(ncs[k]):
            s = 0.0
            for c in range(n):
                s += C[co[k] + r * n + c] * z[zo[k] + c]
            out[cro[k] + r] = s


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _constraint_rows_t(nx, N1, nz, zo, ncs, co, cro, C, y, out):  # pragma: no cover
    """``out += C^T y``."""
    for k in range(N1):
        n = nz[k]
        for r in range(ncs[k]):
            yr = y[cro[k] + r]
            if yr != 0.0:
                for c in range(n):
                    out[zo[k] + c] += C[co[k] + r * n + c] * yr


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _barrier_hessian(N1, nz, zo, ho, ncs, co, cro, H, C, reg, sigma, Hm):  # pragma: no cover (compiled)
    """``Hm = H + reg I + diag(sigma_box) + C^T diag(sigma_c) C``, stage by stage (``sigma``: boxes, then rows)."""
    n = zo[N1]
    for k in range(N1):
        nk = nz[k]
        h0 = ho[k]
        z0 = zo[k]
        for i in range(nk * nk):
            Hm[h0 + i] = H[h0 + i]
        for r in range(nk):
            Hm[h0 + r * nk + r] += reg + sigma[z0 + r]
        for j in range(ncs[k]):
            sig = sigma[n + cro[k] + j]
            if sig != 0.0:
                c0 = co[k] + j * nk
                for r in range(nk):
                    cr = C[c0 + r] * sig
                    if cr != 0.0:
                        for c in range(nk):
                            Hm[h0 + r * nk + c] += cr * C[c0 + c]


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _gradient(nx, N1, nz, zo, ho, ao, H, q, A, reg, z, pi, out):  # pragma: no cover (compiled)
    """``out = (H + reg I) z + q + E^T pi``, ``E`` the dynamics ``A_k z_k - x_{k+1}``."""
    for k in range(N1):
        nk = nz[k]
        h0 = ho[k]
        z0 = zo[k]
        for r in range(nk):
            s = q[z0 + r] + reg * z[z0 + r]
            for c in range(nk):
                s += H[h0 + r * nk + c] * z[z0 + c]
            out[z0 + r] = s
        if k < N1 - 1:
            a0 = ao[k]
            for c in range(nk):
                s = 0.0
                for j in range(nx):
                    s += A[a0 + j * nk + c] * pi[k * nx + j]
                out[z0 + c] += s
        if k > 0:
            for r in range(nx):
                out[z0 + r] -= pi[(k - 1) * nx + r]


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH, inline="always")
def _largest_abs(x, count, floor):  # pragma: no cover (compiled)
    """``max(floor, |x_0|, ..., |x_{count-1}|)``."""
    s = floor
    for i in range(count):
        s = max(s, abs(x[i]))
    return s


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _factor_workspace(nx, N1, nz, h_size):  # pragma: no cover (compiled)
    """The arrays :func:`_factor` and :func:`_riccati_solve` work in: ``M, L, K, P, Lx, W, p``."""
    nmax = 0
    for k in range(N1):
        nmax = max(nmax, nz[k])
    return (
        np.empty(h_size),
        np.empty(h_size),
        np.empty(h_size),
        np.empty(N1 * nx * nx),
        np.empty(nx * nx),
        np.empty(nx * nmax + nmax + nx),
        np.empty(N1 * nx),
    )


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH, inline="always")
def _stacked_rows(nx, N1, nz, zo, ncs, co, cro, C, z, cz, out):  # pragma: no cover (compiled)
    """``out = [z; C z]``, the inequality rows' values (the boxes, then the general rows); ``cz`` is work."""
    n = zo[N1]
    _constraint_rows(nx, N1, nz, zo, ncs, co, cro, C, z, cz)
    for i in range(n):
        out[i] = z[i]
    for i in range(cz.size):
        out[n + i] = cz[i]


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _active_targets(side, lo, hi, lam, target):  # pragma: no cover (compiled)
    """``target``: the bound each active row is held at; ``lam`` zeroed on free rows. Returns whether any is active."""
    any_active = False
    for i in range(side.size):
        if side[i] > 0.0:
            target[i] = hi[i]
            any_active = True
        elif side[i] < 0.0:
            target[i] = lo[i]
            any_active = True
        else:
            target[i] = 0.0
            lam[i] = 0.0
    return any_active


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _hold_active_rows(nx, N1, nz, zo, ho, ao, ncs, co, cro, q, A, b, C, rho, tol, side, target, lam, z, pi, Dz,
                      factors):  # pragma: no cover (compiled)  # fmt: skip
    """Hold the active rows at their targets by the method of multipliers; returns whether they hold to ``tol``.

    Each round is one solve with the penalised factorisation ``factors`` (at most :data:`_MULTIPLIER_ROUNDS`
    rounds); ``lam`` is updated, ``Dz`` receives the rows' values.
    """
    Mw, Lw, Kw, Pw, Lx, W, pw = factors
    n = zo[N1]
    m = side.size
    rq = np.empty(n)
    w = np.empty(m)
    cz = np.empty(m - n)
    for _ in range(_MULTIPLIER_ROUNDS):
        for i in range(m):
            w[i] = (lam[i] - rho * target[i]) if side[i] != 0.0 else 0.0
        for i in range(n):
            rq[i] = q[i] + w[i]
        _constraint_rows_t(nx, N1, nz, zo, ncs, co, cro, C, w[n:], rq)
        _riccati_solve(nx, N1, nz, zo, ho, ao, A, Mw, Lw, Kw, Pw, Lx, rq, b, z, pi, W, pw)
        _stacked_rows(nx, N1, nz, zo, ncs, co, cro, C, z, cz, Dz)
        held = True
        for i in range(m):
            if side[i] != 0.0:
                err = Dz[i] - target[i]
                lam[i] += rho * err
                if abs(err) > tol * (1.0 + abs(target[i])):
                    held = False
        if held:
            return True
    return False


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _box_multipliers(nx, N1, nz, zo, ho, ao, ncs, co, cro, H, q, A, C, reg, side, lam, z, pi):  # pragma: no cover
    """The active boxes' multipliers read off stationarity; the general rows' multipliers are kept.

    (``rho`` times the rows' rounding would otherwise stay in them.)
    """
    n = zo[N1]
    m = side.size
    w = np.empty(m)
    grad = np.empty(n)
    for i in range(m):
        w[i] = lam[i] if (i >= n and side[i] != 0.0) else 0.0
    _gradient(nx, N1, nz, zo, ho, ao, H, q, A, reg, z, pi, grad)
    _constraint_rows_t(nx, N1, nz, zo, ncs, co, cro, C, w[n:], grad)
    for i in range(n):
        if side[i] != 0.0:
            lam[i] = -grad[i]


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _active_set_step(side, lam, Dz, lo, hi, tol, scale):  # pragma: no cover (compiled)
    """One primal-dual active-set step on ``side``; returns whether none changed (optimal to ``tol``).

    Violated rows are made active, wrong-signed ones released.
    """
    optimal = True
    for i in range(side.size):
        if side[i] != 0.0:
            if side[i] * lam[i] < -tol * scale:
                side[i] = 0.0
                optimal = False
        elif lo[i] > -math.inf and Dz[i] < lo[i] - tol * (1.0 + abs(lo[i])):
            side[i] = -1.0
            optimal = False
        elif hi[i] < math.inf and Dz[i] > hi[i] + tol * (1.0 + abs(hi[i])):
            side[i] = 1.0
            optimal = False
    return optimal


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _solve_active(nx, N1, nz, zo, ho, ao, ncs, co, cro, H, q, A, b, C, lo, hi, reg, tol, scale,
                  side, lam, z, pi):  # pragma: no cover (compiled)  # fmt: skip
    """Solve the QP with the rows ``side != 0`` held at their bounds (-1 lower, +1 upper) and the others free.

    The active rows are held by the method of multipliers (augmented Lagrangian, penalty :data:`_PENALTY` times
    the Hessian's size, ``lam`` the multipliers' start) on the Riccati recursion: one factorisation, then one
    solve per round, each round contracting the rows' error by about the penalty's inverse. The bounds'
    multipliers are then read off stationarity. Returns 0 when the solution is the QP's optimum (the active
    rows hold their bounds, the others their boxes, the active multipliers have the right sign, each to
    ``tol``; ``z``, ``pi``, ``lam`` written, ``lam`` zero on free rows); 1 when it is not, with ``side``
    updated as a primal-dual active-set step (violated rows made active, wrong-signed ones released); 2 when
    the active set's QP is singular or its rows inconsistent.
    """
    m = side.size
    target = np.empty(m)
    any_active = _active_targets(side, lo, hi, lam, target)
    rho = _PENALTY * _largest_abs(H, H.size, 1.0) if any_active else 0.0
    penalty = np.empty(m)
    for i in range(m):
        penalty[i] = rho if side[i] != 0.0 else 0.0
    Hm = np.empty(H.size)
    _barrier_hessian(N1, nz, zo, ho, ncs, co, cro, H, C, reg, penalty, Hm)
    factors = _factor_workspace(nx, N1, nz, H.size)
    Mw, Lw, Kw, Pw, Lx, W, _ = factors
    if not _factor(nx, N1, nz, ho, ao, A, Hm, Mw, Lw, Kw, Pw, Lx, W):
        return 2
    Dz = np.empty(m)
    if not _hold_active_rows(nx, N1, nz, zo, ho, ao, ncs, co, cro, q, A, b, C, rho, tol, side, target, lam, z, pi,
                             Dz, factors):  # fmt: skip
        return 2
    _box_multipliers(nx, N1, nz, zo, ho, ao, ncs, co, cro, H, q, A, C, reg, side, lam, z, pi)
    return 0 if _active_set_step(side, lam, Dz, lo, hi, tol, scale) else 1


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _inequality_rows(lb, ub, lc, uc):  # pragma: no cover (compiled)
    """The inequality rows' bounds ``lo, hi`` (the boxes, then the general rows)."""
    n = lb.size
    nc = lc.size
    lo = np.empty(n + nc)
    hi = np.empty(n + nc)
    for i in range(n):
        lo[i] = lb[i]
        hi[i] = ub[i]
    for i in range(nc):
        lo[n + i] = lc[i]
        hi[n + i] = uc[i]
    return lo, hi


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _check_data(lo, hi, H, q, A, b, C, info):  # pragma: no cover (compiled)
    """0 when the data are usable; else the :class:`QPStatus` code, with ``info`` written.

    3: crossed bounds; 5: NaN bounds or NaN or infinite data.
    """
    for i in range(lo.size):
        if lo[i] > hi[i] or math.isnan(lo[i]) or math.isnan(hi[i]):
            info[1] = 0
            info[2] = math.inf
            return 3 if lo[i] > hi[i] else 5
    for arr in (H, q, A, b, C):
        for i in range(arr.size):
            if not math.isfinite(arr[i]):
                info[2] = math.inf
                return 5
    return 0


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _warm_active_set(nx, N1, nz, zo, ho, ao, ncs, co, cro, H, q, A, b, C, lo, hi, has_lo, has_hi, reg, tol,
                     scale, guess, side, lam, z, pi):  # pragma: no cover (compiled)  # fmt: skip
    """Active-set steps from the guessed active set (its sides without a bound dropped).

    At most :data:`_ACTIVE_SET_ROUNDS`, fewer once a step changes as many rows as the one before. Returns
    ``(code, rounds)``, ``code`` that of the last :func:`_solve_active`; ``z``, ``pi`` zeroed unless it is 0.
    """
    m = side.size
    for i in range(m):
        side[i] = guess[i] if (guess[i] < 0.0 and has_lo[i]) or (guess[i] > 0.0 and has_hi[i]) else 0.0
    before = np.empty(m)
    changed = m + 1
    code = 2
    rounds = 0
    for rounds in range(1, _ACTIVE_SET_ROUNDS + 1):  # noqa: B007 (reported)
        before[:] = side
        code = _solve_active(nx, N1, nz, zo, ho, ao, ncs, co, cro, H, q, A, b, C, lo, hi, reg, tol, scale,
                             side, lam, z, pi)  # fmt: skip
        if code != 1:
            break
        previous = changed
        changed = 0
        for i in range(m):
            changed += int(side[i] != before[i])
        if changed >= previous:  # the steps do not settle: leave it to the interior point
            break
    if code != 0:
        z[:] = 0.0
        pi[:] = 0.0
    return code, rounds


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _start_point(lo, hi, has_lo, has_hi, z, yl, yu):  # pragma: no cover (compiled)
    """``z`` (zero) moved inside the finite boxes; the multipliers 1 where a side exists, else 0."""
    for i in range(z.size):
        if has_lo[i] and has_hi[i]:
            if z[i] < lo[i] or z[i] > hi[i]:
                z[i] = 0.5 * (lo[i] + hi[i])
        elif has_lo[i] and z[i] < lo[i]:
            z[i] = lo[i]
        elif has_hi[i] and z[i] > hi[i]:
            z[i] = hi[i]
    for i in range(yl.size):
        yl[i] = 1.0 if has_lo[i] else 0.0
        yu[i] = 1.0 if has_hi[i] else 0.0


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _start_slacks(lo, hi, has_lo, has_hi, Dz, sl, su):  # pragma: no cover (compiled)
    """Slacks from the rows' values ``Dz``, at least :data:`_START_SLACK` (1 where a side is absent)."""
    for i in range(Dz.size):
        sl[i] = max(Dz[i] - lo[i], _START_SLACK) if has_lo[i] else 1.0
        su[i] = max(hi[i] - Dz[i], _START_SLACK) if has_hi[i] else 1.0


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH, inline="always")
def _dual_residual(nx, N1, nz, zo, ho, ao, ncs, co, cro, H, q, A, C, reg, z, pi, yl, yu, w,
                   rd):  # pragma: no cover (compiled)  # fmt: skip
    """Stationarity's residual ``rd = (H + reg I) z + q + E^T pi + D^T (yu - yl)``, ``D = [I; C]`` (``w`` work)."""
    n = zo[N1]
    _gradient(nx, N1, nz, zo, ho, ao, H, q, A, reg, z, pi, rd)
    for i in range(w.size):
        w[i] = yu[i] - yl[i]
    for i in range(n):
        rd[i] += w[i]
    _constraint_rows_t(nx, N1, nz, zo, ncs, co, cro, C, w[n:], rd)


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH, inline="always")
def _dynamics_residual(nx, N1, nz, zo, ao, A, b, z, re):  # pragma: no cover (compiled)
    """``re_k = A_k z_k + b_k - x_{k+1}``."""
    for k in range(N1 - 1):
        nk = nz[k]
        a0 = ao[k]
        for r in range(nx):
            s = b[k * nx + r] - z[zo[k + 1] + r]
            for c in range(nk):
                s += A[a0 + r * nk + c] * z[zo[k] + c]
            re[k * nx + r] = s


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH, inline="always")
def _bound_residuals(lo, hi, has_lo, has_hi, Dz, sl, su, yl, yu, rl, ru):  # pragma: no cover (compiled)
    """``rl = Dz - sl - lo``, ``ru = Dz + su - hi`` on the sides that exist.

    Returns the complementarity gap ``sum s y`` and the largest relative bound residual.
    """
    gap = 0.0
    pres = 0.0
    for i in range(Dz.size):
        if has_lo[i]:
            rl[i] = Dz[i] - sl[i] - lo[i]
            gap += sl[i] * yl[i]
            pres = max(pres, abs(rl[i]) / (1.0 + abs(lo[i])))
        if has_hi[i]:
            ru[i] = Dz[i] + su[i] - hi[i]
            gap += su[i] * yu[i]
            pres = max(pres, abs(ru[i]) / (1.0 + abs(hi[i])))
    return gap, pres


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _crossover(nx, N1, nz, zo, ho, ao, ncs, co, cro, H, q, A, b, C, lo, hi, has_lo, has_hi, reg, tol, scale,
               sl, su, yl, yu, side, lam, z, pi):  # pragma: no cover (compiled)  # fmt: skip
    """The exact solution of the interior point's active set; returns whether it is the optimum.

    A side is active where ``y > s``; then up to :data:`_ACTIVE_SET_ROUNDS` active-set steps. On success ``z``,
    ``pi``, ``lam`` hold the optimum (else ``z``, ``pi`` are scratch).
    """
    for i in range(side.size):
        side[i] = 1.0 if has_hi[i] and yu[i] > su[i] else (-1.0 if has_lo[i] and yl[i] > sl[i] else 0.0)
        lam[i] = yu[i] - yl[i]
    code = 2
    for _ in range(_ACTIVE_SET_ROUNDS):
        code = _solve_active(nx, N1, nz, zo, ho, ao, ncs, co, cro, H, q, A, b, C, lo, hi, reg, tol, scale,
                             side, lam, z, pi)  # fmt: skip
        if code != 1:
            break
    return code == 0


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH, inline="always")
def _barrier_weights(has_lo, has_hi, sl, su, yl, yu, sigma):  # pragma: no cover (compiled)
    """``sigma = yl / sl + yu / su`` on the sides that exist: the barrier's curvature per row."""
    for i in range(sigma.size):
        sig = 0.0
        if has_lo[i]:
            sig += yl[i] / sl[i]
        if has_hi[i]:
            sig += yu[i] / su[i]
        sigma[i] = sig


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH, inline="always")
def _complementarity_targets(has_lo, has_hi, sl, su, yl, yu, dsl, dsu, dyl, dyu, target_mu, corrector, corr_l,
                             corr_u):  # pragma: no cover (compiled)  # fmt: skip
    """Predictor: ``s y -> 0``; corrector: ``s y + ds dy - target_mu`` (the affine step's ``ds, dy``)."""
    for i in range(sl.size):
        if not corrector:
            corr_l[i] = sl[i] * yl[i] if has_lo[i] else 0.0
            corr_u[i] = su[i] * yu[i] if has_hi[i] else 0.0
        else:
            corr_l[i] = sl[i] * yl[i] + dsl[i] * dyl[i] - target_mu if has_lo[i] else 0.0
            corr_u[i] = su[i] * yu[i] + dsu[i] * dyu[i] - target_mu if has_hi[i] else 0.0


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH, inline="always")
def _bound_steps(has_lo, has_hi, sl, su, yl, yu, rl, ru, Ddz, corr_l, corr_u, dsl, dsu, dyl,
                 dyu):  # pragma: no cover (compiled)  # fmt: skip
    """The slacks' and multipliers' steps from the rows' step ``Ddz``.

    Returns the largest primal and dual step lengths (at most 1) that keep them nonnegative.
    """
    alpha_p = 1.0
    alpha_d = 1.0
    for i in range(sl.size):
        if has_lo[i]:
            dsl[i] = Ddz[i] + rl[i]
            dyl[i] = (-corr_l[i] - yl[i] * dsl[i]) / sl[i]
            if dsl[i] < 0.0:
                alpha_p = min(alpha_p, -sl[i] / dsl[i])
            if dyl[i] < 0.0:
                alpha_d = min(alpha_d, -yl[i] / dyl[i])
        if has_hi[i]:
            dsu[i] = -ru[i] - Ddz[i]
            dyu[i] = (-corr_u[i] - yu[i] * dsu[i]) / su[i]
            if dsu[i] < 0.0:
                alpha_p = min(alpha_p, -su[i] / dsu[i])
            if dyu[i] < 0.0:
                alpha_d = min(alpha_d, -yu[i] / dyu[i])
    return alpha_p, alpha_d


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH, inline="always")
def _affine_gap(has_lo, has_hi, sl, su, yl, yu, dsl, dsu, dyl, dyu, alpha_p, alpha_d):  # pragma: no cover
    """The complementarity gap after the predictor's step."""
    gap = 0.0
    for i in range(sl.size):
        if has_lo[i]:
            gap += (sl[i] + alpha_p * dsl[i]) * (yl[i] + alpha_d * dyl[i])
        if has_hi[i]:
            gap += (su[i] + alpha_p * dsu[i]) * (yu[i] + alpha_d * dyu[i])
    return gap


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH, inline="always")
def _predictor_corrector(nx, N1, nz, zo, ho, ao, ncs, co, cro, A, C, factors, has_lo, has_hi, n_sides, mu, rd,
                         re, rl, ru, it, st, work):  # pragma: no cover (compiled)  # fmt: skip
    """Mehrotra's step on the factorised Newton matrix ``factors``.

    A predictor (affine) direction, then the corrector with centring ``sigma = (gap_aff / gap)^3``.
    ``it = (z, pi, sl, su, yl, yu)``: the iterates; ``st = (dz, dpi, dsl, dsu, dyl, dyu)`` receives the
    direction; ``work = (corr_l, corr_u, w, Ddz, rq, cdz)`` is scratch. Returns the step lengths to the boundary
    ``(alpha_p, alpha_d)``.
    """
    Mw, Lw, Kw, Pw, Lx, W, pw = factors
    _, _, sl, su, yl, yu = it
    dz, dpi, dsl, dsu, dyl, dyu = st
    n = zo[N1]
    m = sl.size
    corr_l, corr_u, w, Ddz, rq, cdz = work
    sigma = 0.0
    alpha_p = 1.0
    alpha_d = 1.0
    for phase in range(2):
        _complementarity_targets(has_lo, has_hi, sl, su, yl, yu, dsl, dsu, dyl, dyu, sigma * mu, phase == 1,
                                 corr_l, corr_u)  # fmt: skip
        # rq = rd + D^T [(-corr_u + yu ru)/su + (corr_l + yl rl)/sl]
        for i in range(m):
            t = 0.0
            if has_lo[i]:
                t += (corr_l[i] + yl[i] * rl[i]) / sl[i]
            if has_hi[i]:
                t += (-corr_u[i] + yu[i] * ru[i]) / su[i]
            w[i] = t
        for i in range(n):
            rq[i] = rd[i] + w[i]
        _constraint_rows_t(nx, N1, nz, zo, ncs, co, cro, C, w[n:], rq)
        _riccati_solve(nx, N1, nz, zo, ho, ao, A, Mw, Lw, Kw, Pw, Lx, rq, re, dz, dpi, W, pw)
        _stacked_rows(nx, N1, nz, zo, ncs, co, cro, C, dz, cdz, Ddz)
        alpha_p, alpha_d = _bound_steps(has_lo, has_hi, sl, su, yl, yu, rl, ru, Ddz, corr_l, corr_u, dsl, dsu,
                                        dyl, dyu)  # fmt: skip
        if phase == 0:
            if n_sides == 0:
                break
            gap_aff = _affine_gap(has_lo, has_hi, sl, su, yl, yu, dsl, dsu, dyl, dyu, alpha_p, alpha_d)
            ratio = gap_aff / (n_sides * mu) if mu > 0.0 else 0.0
            sigma = ratio * ratio * ratio
    return alpha_p, alpha_d


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH, inline="always")
def _take_step(has_lo, has_hi, n_sides, alpha_p, alpha_d, it, st):  # pragma: no cover (compiled)
    """Move the iterates ``it`` along ``st`` (see :func:`_predictor_corrector`), a fraction short of the boundary."""
    z, pi, sl, su, yl, yu = it
    dz, dpi, dsl, dsu, dyl, dyu = st
    if n_sides > 0:
        alpha_p = min(1.0, 0.995 * alpha_p)
        alpha_d = min(1.0, 0.995 * alpha_d)
    for i in range(z.size):
        z[i] += alpha_p * dz[i]
    for i in range(pi.size):
        pi[i] += alpha_d * dpi[i]
    for i in range(sl.size):
        if has_lo[i]:
            sl[i] += alpha_p * dsl[i]
            yl[i] += alpha_d * dyl[i]
        if has_hi[i]:
            su[i] += alpha_p * dsu[i]
            yu[i] += alpha_d * dyu[i]


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _quadratic_cost(N1, nz, zo, ho, H, q, reg, z):  # pragma: no cover (compiled)
    """``z^T (H + reg I) z / 2 + q^T z``."""
    cost = 0.0
    for k in range(N1):
        nk = nz[k]
        h0 = ho[k]
        z0 = zo[k]
        for r in range(nk):
            s = reg * z[z0 + r]
            for c in range(nk):
                s += H[h0 + r * nk + c] * z[z0 + c]
            cost += z[z0 + r] * (0.5 * s + q[z0 + r])
    return cost


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _interior_point(nx, N1, nz, zo, ho, ao, ncs, co, cro, H, q, A, b, C, lo, hi, has_lo, has_hi, reg, tol, max_iter,
                    q_scale, it, side, lam):  # pragma: no cover (compiled)  # fmt: skip
    """The interior point's iterations from ``it = (z, pi, sl, su, yl, yu)`` (slacks set here from ``z``).

    One :func:`_crossover` is tried once the residual is below :data:`CROSSOVER_BELOW`. Returns ``(status,
    iterations, residual, crossed)``; when crossed, ``z``, ``pi``, ``side``, ``lam`` hold the active set's exact
    solution.
    """
    n = zo[N1]
    nc = cro[N1]
    m = n + nc
    ndyn = (N1 - 1) * nx
    z, pi, sl, su, yl, yu = it
    st = (np.empty(n), np.empty(ndyn), np.zeros(m), np.zeros(m), np.zeros(m), np.zeros(m))  # the step
    n_sides = int(has_lo.sum() + has_hi.sum())
    h_scale = _largest_abs(H, H.size, 1.0)
    b_scale = _largest_abs(b, ndyn, 1.0)
    status = 1
    res = math.inf
    crossed = False
    # work
    Hm = np.empty(H.size)
    factors = _factor_workspace(nx, N1, nz, H.size)
    Mw, Lw, Kw, Pw, Lx, W, _ = factors
    pc_work = (np.zeros(m), np.zeros(m), np.empty(m), np.empty(m), np.empty(n), np.empty(nc))
    rd = np.empty(n)
    re = np.empty(ndyn)
    rl = np.zeros(m)
    ru = np.zeros(m)
    Dz = np.empty(m)
    cz = np.empty(nc)
    w = np.empty(m)
    zt = np.empty(n)
    pit = np.empty(ndyn)
    tried = False
    _stacked_rows(nx, N1, nz, zo, ncs, co, cro, C, z, cz, Dz)
    _start_slacks(lo, hi, has_lo, has_hi, Dz, sl, su)
    k = 0
    for k in range(max_iter + 1):
        # residuals: stationarity rd, dynamics re, bounds rl/ru
        _stacked_rows(nx, N1, nz, zo, ncs, co, cro, C, z, cz, Dz)
        _dual_residual(nx, N1, nz, zo, ho, ao, ncs, co, cro, H, q, A, C, reg, z, pi, yl, yu, w, rd)
        _dynamics_residual(nx, N1, nz, zo, ao, A, b, z, re)
        gap, pres = _bound_residuals(lo, hi, has_lo, has_hi, Dz, sl, su, yl, yu, rl, ru)
        mu = gap / n_sides if n_sides > 0 else 0.0
        dres = _largest_abs(rd, n, 0.0)
        eres = _largest_abs(re, ndyn, 0.0)
        ymax = max(_largest_abs(yl, m, 0.0), _largest_abs(yu, m, 0.0))  # y >= 0
        zmax = _largest_abs(z, n, 0.0)
        if not (math.isfinite(dres) and math.isfinite(eres) and math.isfinite(pres) and math.isfinite(mu)):
            status = 5
            break
        res = max(dres / (q_scale + ymax), eres / b_scale, pres, mu / (q_scale + ymax))
        if (res <= CROSSOVER_BELOW and not tried) or res <= tol:
            tried = True
            if _crossover(nx, N1, nz, zo, ho, ao, ncs, co, cro, H, q, A, b, C, lo, hi, has_lo, has_hi, reg, tol,
                          q_scale + ymax, sl, su, yl, yu, side, lam, zt, pit):  # fmt: skip
                z[:] = zt
                pi[:] = pit
                status = 0
                crossed = True
                break
        if res <= tol:
            status = 0
            break
        if ymax > _BIG * (q_scale + h_scale) or zmax > _BIG * (1.0 + b_scale):
            status = 4
            break
        if k == max_iter:
            status = 1
            break
        # the Newton matrix H + reg I + diag(Sigma_box) + C^T Sigma_c C, then Mehrotra's step
        _barrier_weights(has_lo, has_hi, sl, su, yl, yu, w)
        _barrier_hessian(N1, nz, zo, ho, ncs, co, cro, H, C, reg, w, Hm)
        if not _factor(nx, N1, nz, ho, ao, A, Hm, Mw, Lw, Kw, Pw, Lx, W):
            status = 2
            break
        alpha_p, alpha_d = _predictor_corrector(nx, N1, nz, zo, ho, ao, ncs, co, cro, A, C, factors, has_lo, has_hi,
                                                n_sides, mu, rd, re, rl, ru, it, st, pc_work)  # fmt: skip
        _take_step(has_lo, has_hi, n_sides, alpha_p, alpha_d, it, st)
    return status, k, res, crossed


@numba.njit(cache=True, error_model="numpy", fastmath=_FASTMATH)
def _ipm(nx, nz, zo, ho, ao, ncs, co, cro, H, q, A, b, lb, ub, C, lc, uc, reg, tol, max_iter, guess,
         z_out, lam_x_out, lam_dyn_out, lam_c_out, side_out, info):  # pragma: no cover (compiled)  # fmt: skip
    """Mehrotra predictor-corrector interior point; returns a :class:`QPStatus` code. See :func:`solve_stage_qp`.

    ``guess`` (empty, or -1/0/+1 per inequality row, the boxes first): an active set to try first, with up to
    :data:`_ACTIVE_SET_ROUNDS` primal-dual active-set steps (:func:`_solve_active`); the interior point runs only
    if they do not reach the optimum. ``side_out``: the active set found (-1/0/+1 per row).
    """
    N1 = nz.size
    n = zo[N1]
    m = n + cro[N1]  # inequality rows: the boxes, then the general rows
    ndyn = (N1 - 1) * nx
    lo, hi = _inequality_rows(lb, ub, lc, uc)
    bad = _check_data(lo, hi, H, q, A, b, C, info)
    if bad != 0:
        return bad
    has_lo = lo > -math.inf
    has_hi = hi < math.inf
    q_scale = _largest_abs(q, n, 1.0)
    # the iterates z, pi, sl, su, yl, yu
    it = (np.zeros(n), np.zeros(ndyn), np.ones(m), np.ones(m), np.zeros(m), np.zeros(m))
    z, pi, sl, su, yl, yu = it
    _start_point(lo, hi, has_lo, has_hi, z, yl, yu)
    lam = np.zeros(m)
    side = np.zeros(m)
    status, k, res, crossed, rounds = 1, 0, math.inf, False, 0
    if guess.size == m:
        code, rounds = _warm_active_set(nx, N1, nz, zo, ho, ao, ncs, co, cro, H, q, A, b, C, lo, hi, has_lo, has_hi,
                                        reg, tol, q_scale, guess, side, lam, z, pi)  # fmt: skip
        if code == 0:
            status, res, crossed = 0, 0.0, True
    if not crossed:
        status, k, res, crossed = _interior_point(nx, N1, nz, zo, ho, ao, ncs, co, cro, H, q, A, b, C, lo, hi, has_lo,
                                                  has_hi, reg, tol, max_iter, q_scale, it, side, lam)  # fmt: skip
    if not crossed:  # the interior iterate: multipliers on the rows its active-set estimate holds
        for i in range(m):
            side[i] = 1.0 if has_hi[i] and yu[i] > su[i] else (-1.0 if has_lo[i] and yl[i] > sl[i] else 0.0)
            lam[i] = yu[i] - yl[i] if side[i] != 0.0 else 0.0
    side_out[:] = side
    z_out[:] = z
    lam_x_out[:] = lam[:n]
    lam_dyn_out[:] = pi
    lam_c_out[:] = lam[n:]
    info[0] = _quadratic_cost(N1, nz, zo, ho, H, q, reg, z)
    info[1] = k
    info[2] = res
    info[3] = 1.0 if crossed else 0.0
    info[4] = rounds
    return status
