r"""The Gauss-Newton QP of a window problem in stage form, for :mod:`uiest.window.riccati_qp`.

A :class:`~uiest.window.problem.WindowProblem` stacks its variables stage by stage,
``z_k = [x_k, v_k, w_k]`` (``v_k`` at measured nodes, ``w_k`` for ``k < L``), so no permutation of the
variables is needed: stage ``k`` is the slice from ``x_index[k][0]`` to ``x_index[k+1][0]``. The QP's
Hessian (``J^T J``, with the curvature ``S_+`` or a damping) is block diagonal by stage, since every residual
and every constraint is nonlinear in one node only. Its constraint rows are

- the dynamics ``g_k = (f(x_k, ...) - x_{k+1}) / s_x``, ``k = 0 .. L-1``: row ``k nx + r`` has the Jacobian of
  ``f`` in stage ``k``'s columns and ``e_r`` (``-1`` by construction) at ``x_{k+1, r}``, an equality; it becomes
  ``x_{k+1} = A_k z_k + b_k`` with ``A_k = -(row) / e``, ``b_k = lbg_row / e``;
- output and node constraints at measured nodes, each in one stage's columns: the stage's rows ``C_k``,
  reordered stage by stage (the problem orders them by kind).

:class:`StageForm` checks this structure once, from the sparsities (a matrix that breaks it raises
:class:`~uiest.errors.OptionError`), and keeps the index maps that scatter CasADi's nonzeros into the packed
stage blocks, so that a QP costs one compiled call: the scatter, the guessed active set, the kernel and the
multipliers back in the problem's row order (``_solve_form``).
"""

from __future__ import annotations

import math

import casadi as ca
import numba
import numpy as np

from uiest.box import FloatArray
from uiest.errors import OptionError
from uiest.window.problem import WindowProblem
from uiest.window.riccati_qp import DEFAULT_MAX_ITER, DEFAULT_TOL, QPStatus, StageLayout, _ipm

__all__ = ["EQUALITY_TOL", "GUESS_FLOOR", "StageForm"]

GUESS_FLOOR = 1e-9
"""Multipliers below this fraction of the largest are not taken as active in a guess: an interior point's
inactive sides keep multipliers of about ``mu / s`` (1e-11 relative at its tolerance)."""

_STATUS_OF = {int(status): status for status in QPStatus}
"""The kernel's status codes as :class:`QPStatus` (a lookup; the enum's call costs a microsecond)."""

EQUALITY_TOL = 1e-14
"""Dynamics rows whose bounds differ by more than this are not equalities: such a QP is not put in stage form."""


class StageForm:
    """A window QP's sparsities mapped onto :class:`~uiest.window.riccati_qp.StageLayout`.

    Parameters
    ----------
    problem : WindowProblem
    h_sparsity : casadi.Sparsity
        The QP Hessian's, (n_var, n_var); every nonzero must lie in one stage's diagonal block.
    a_sparsity : casadi.Sparsity
        The constraint Jacobian's, (n_con, n_var), rows as the problem orders them.

    Attributes
    ----------
    layout : StageLayout
    last_status : QPStatus or None
        The status of the last :meth:`solve` (None: a dynamics row was not an equality).
    last_counts : (int, int)
        The last :meth:`solve`'s active-set steps from its guess and interior-point iterations (0, 0 where the
        kernel refused the data).

    """

    def __init__(self, problem: WindowProblem, h_sparsity: ca.Sparsity, a_sparsity: ca.Sparsity) -> None:
        nx, L, n = problem.model.nx, problem.length, problem.n_var
        if nx == 0:
            raise OptionError("problem: expected a model with states (nx >= 1) for the stage-wise QP")
        starts = np.append(problem.x_index[:, 0], n).astype(np.int64)
        sizes = np.diff(starts)
        stage_of = np.repeat(np.arange(L + 1), sizes)
        if not all(np.array_equal(problem.x_index[k], np.arange(starts[k], starts[k] + nx)) for k in range(L + 1)):
            raise OptionError("problem: expected each stage's state first in its variables")
        # Hessian nonzeros -> packed row-major stage blocks
        rows, cols = (np.asarray(index, dtype=np.int64) for index in h_sparsity.get_triplet())
        if np.any(stage_of[rows] != stage_of[cols]):
            raise OptionError("h_sparsity: expected a Hessian block diagonal by stage")
        stage = stage_of[rows]
        h_offset = np.concatenate(([0], np.cumsum(sizes**2)))
        self._h_target = h_offset[stage] + (rows - starts[stage]) * sizes[stage] + (cols - starts[stage])
        self._h = np.zeros(int(h_offset[-1]))
        # constraint nonzeros: dynamics rows -> A_k (and e at x_{k+1}); the other rows -> C_k, stage-ordered
        a_rows, a_cols = (np.asarray(index, dtype=np.int64) for index in a_sparsity.get_triplet())
        n_dyn = problem.n_dyn
        dynamic = a_rows < n_dyn
        d_rows, d_cols = a_rows[dynamic], a_cols[dynamic]
        d_stage = d_rows // nx
        own = stage_of[d_cols] == d_stage
        nxt = ~own & (stage_of[d_cols] == d_stage + 1) & (d_cols - starts[np.minimum(d_stage + 1, L)] == d_rows % nx)
        if not np.all(own | nxt) or np.count_nonzero(nxt) != n_dyn:
            raise OptionError("a_sparsity: expected dynamics rows in their stage's columns and x_{k+1} only")
        a_offset = np.concatenate(([0], np.cumsum(nx * sizes[:-1]), [nx * sizes[:-1].sum()]))
        positions = np.flatnonzero(dynamic)
        self._a_source = positions[own]
        self._a_row = d_rows[own]
        self._a_target = (
            a_offset[d_stage[own]] + (d_rows[own] % nx) * sizes[d_stage[own]] + (d_cols[own] - starts[d_stage[own]])
        )
        self._e_source = positions[nxt][np.argsort(d_rows[nxt])]  # e of row r, in row order
        self._a = np.zeros(int(a_offset[-1]))
        other = ~dynamic
        c_rows, c_cols = a_rows[other] - n_dyn, a_cols[other]
        n_other = problem.n_con - n_dyn
        row_stage = np.zeros(n_other, dtype=np.int64)
        for row in range(n_other):
            in_row = stage_of[c_cols[c_rows == row]]
            if in_row.size and np.any(in_row != in_row[0]):
                raise OptionError(f"a_sparsity: constraint row {n_dyn + row} spans more than one stage")
            row_stage[row] = in_row[0] if in_row.size else 0
        order = np.argsort(row_stage, kind="stable")  # stage-ordered position -> problem row (after the dynamics)
        position = np.empty(n_other, dtype=np.int64)
        position[order] = np.arange(n_other)
        c_sizes = np.bincount(row_stage, minlength=L + 1).astype(np.int64)
        self.layout = StageLayout(nx, sizes, c_sizes)
        c_offset, con_offset = self.layout.c_offset, self.layout.con_offset
        c_stage = row_stage[c_rows]
        self._c_source = np.flatnonzero(other)
        self._c_target = (
            c_offset[c_stage] + (position[c_rows] - con_offset[c_stage]) * sizes[c_stage] + (c_cols - starts[c_stage])
        )
        self._c = np.zeros(int(c_offset[-1]))
        self._c_rows = (n_dyn + order).astype(np.int64)  # problem rows in stage order
        self._n_var, self._n_con = n, problem.n_con
        maps = (self._h_target, self._a_source, self._a_row, self._a_target, self._e_source, self._c_source,
                self._c_target, self._c_rows)  # fmt: skip
        self._maps = tuple(np.ascontiguousarray(index, dtype=np.int64) for index in maps)
        self._kernel_sizes = self.layout.kernel_sizes()
        self._no_guess = np.zeros(0)
        self._info = np.zeros(5)
        self.last_status: QPStatus | None = None
        self.last_counts = (0, 0)

    def solve(
        self,
        h: FloatArray,
        q: FloatArray,
        a: FloatArray,
        bounds: tuple[FloatArray, ...],
        guess: tuple[FloatArray, FloatArray] | None = None,
        scale: float = 1.0,
        at: tuple[FloatArray, FloatArray] | None = None,
    ) -> tuple[FloatArray, float, FloatArray, FloatArray] | None:
        """``(dz, cost, lam_x, lam_a)`` of ``min 1/2 dz^T H dz + q^T dz``, ``lba <= A dz <= uba``, ``lbx <= dz <= ubx``.

        Parameters
        ----------
        h, a : ndarray
            The nonzeros of ``H`` and ``A`` in the sparsities' (CasADi's) order.
        q : ndarray (n_var,)
        bounds : (lba, uba, lbx, ubx)
            ``lba, uba`` (n_con,) in the problem's row order; ``lbx, ubx`` (n_var,).
        guess : (lam_x, lam_a), optional
            Multipliers whose signs, where above :data:`GUESS_FLOOR` of the largest, are the active set to try
            first, as qrqp's warm start: a previous QP's multipliers, or marks of the sides the linearisation
            point sits on.
        scale : float
            The kernel solves the QP with ``H`` and ``q`` times ``scale`` (its tolerances are absolute at that
            scale); the cost and multipliers returned are the unscaled QP's.
        at : (g, z), optional
            The point a Gauss-Newton step is taken from, ``g`` (n_con,) and ``z`` (n_var,): ``bounds`` are then the
            problem's ``(lbg, ubg, lbx, ubx)`` and the QP's are them minus ``(g, g, z, z)`` (taken inside the
            compiled call).

        Returns
        -------
        tuple or None
            The minimiser, the QP's cost, and the multipliers in CasADi's convention; None when the
            kernel does not report :attr:`QPStatus.SOLVED` (then :attr:`last_status` says why) or the
            dynamics rows are not equalities.

        """
        if not (math.isfinite(scale) and scale > 0.0):
            raise OptionError(f"scale: expected a finite number > 0, got {scale!r}")
        lba, uba, lbx, ubx = bounds
        guess_x, guess_a = (self._no_guess, self._no_guess) if guess is None else guess
        g_at, z_at = (self._no_guess, self._no_guess) if at is None else at
        z, lam_x, lam_a = np.empty(self._n_var), np.empty(self._n_var), np.empty(self._n_con)
        info = self._info
        code = _solve_form(h, q, a, lba, uba, lbx, ubx, g_at, z_at, guess_x, guess_a, scale, self._maps, EQUALITY_TOL,
                           GUESS_FLOOR, *self._kernel_sizes, self._h, self._a, self._c, z, lam_x, lam_a,
                           info)  # fmt: skip
        self.last_status = None if code < 0 else _STATUS_OF[code]
        self.last_counts = int(info[4]), int(info[1])
        if code != QPStatus.SOLVED:
            return None
        return z, float(info[0]) / scale, lam_x, lam_a


@numba.njit(cache=True, error_model="numpy")
def _solve_form(h, q, a, lba, uba, lbx, ubx, g_at, z_at, guess_x, guess_a, scale, maps, equality_tol, guess_floor,
                nx, nz, zo, ho, ao, ncs, co, cro, H, A, C, z, lam_x, lam_a, info):  # pragma: no cover  # fmt: skip
    """:meth:`StageForm.solve` in one compiled call: scatter, guess, kernel, multipliers in the problem's row order.

    The kernel solves the QP with ``H`` and ``q`` times ``scale``; ``lam_x``, ``lam_a`` are divided by it again.
    Returns the kernel's :class:`QPStatus` code, or -1 (nothing solved) if a dynamics row is not an equality.
    ``guess_x`` empty: no guess; ``z_at`` not empty: the bounds are taken relative to ``g_at``, ``z_at``. ``info``: the
    kernel's (cost of the scaled QP, iterations, residual, exact, active-set steps).
    """
    info[:] = 0.0
    if z_at.size:  # (a one-node window has no constraint rows: g_at is empty there too)
        lba, uba, lbx, ubx = lba - g_at, uba - g_at, lbx - z_at, ubx - z_at
    c_rows = maps[7]
    n_dyn = (nz.size - 1) * nx
    n_c = c_rows.size
    b, lc, uc = np.empty(n_dyn), np.empty(n_c), np.empty(n_c)
    if not _scatter(h, scale, a, lba, uba, maps, equality_tol, H, A, C, b, lc, uc):
        return -1
    start = np.empty(z.size + n_c if guess_x.size else 0)
    if guess_x.size:
        _guess_sides(guess_x, guess_a, c_rows, guess_floor, start)
    lam_dyn, lam_c, side = np.empty(n_dyn), np.empty(n_c), np.empty(z.size + n_c)
    qs = np.empty(q.size)
    for i in range(q.size):
        qs[i] = scale * q[i]
    code = _ipm(nx, nz, zo, ho, ao, ncs, co, cro, H, qs, A, b, lbx, ubx, C, lc, uc, 0.0, DEFAULT_TOL,
                DEFAULT_MAX_ITER, start, z, lam_x, lam_dyn, lam_c, side, info)  # fmt: skip
    if code == 0:
        _constraint_multipliers(lam_dyn, lam_c, a, maps[4], c_rows, lam_a)
        for i in range(lam_x.size):
            lam_x[i] = lam_x[i] / scale
        for i in range(lam_a.size):
            lam_a[i] = lam_a[i] / scale
    return code


@numba.njit(cache=True, error_model="numpy")
def _scatter(h, scale, a, lba, uba, maps, equality_tol, H, A, C, b, lc, uc):  # pragma: no cover (compiled)
    """The stage blocks ``H`` (times ``scale``), ``A``, ``C`` and ``b, lc, uc`` from CasADi's nonzeros (``maps``).

    False, with nothing written, if a dynamics row's bounds differ by more than ``equality_tol``.
    """
    h_target, a_source, a_row, a_target, e_source, c_source, c_target, c_rows = maps
    n_dyn = b.size
    for i in range(n_dyn):
        if abs(uba[i] - lba[i]) > equality_tol:
            return False
    for i in range(h.size):
        H[h_target[i]] = scale * h[i]
    for j in range(a_source.size):  # A_k = -(row) / e, e the row's entry at x_{k+1} (-1 for a window problem)
        A[a_target[j]] = -a[a_source[j]] / a[e_source[a_row[j]]]
    for j in range(c_source.size):
        C[c_target[j]] = a[c_source[j]]
    for i in range(n_dyn):
        b[i] = lba[i] / a[e_source[i]]
    for j in range(c_rows.size):
        lc[j] = lba[c_rows[j]]
        uc[j] = uba[c_rows[j]]
    return True


@numba.njit(cache=True, error_model="numpy")
def _guess_sides(lam_x, lam_a, c_rows, floor, out):  # pragma: no cover (compiled)
    """``out``: the signs of ``[lam_x; lam_a[c_rows]]`` where above ``floor`` times the largest, else 0."""
    n = lam_x.size
    largest = 0.0
    for i in range(n):
        largest = max(largest, abs(lam_x[i]))
    for j in range(c_rows.size):
        largest = max(largest, abs(lam_a[c_rows[j]]))
    threshold = floor * largest
    for i in range(n + c_rows.size):
        value = lam_x[i] if i < n else lam_a[c_rows[i - n]]
        out[i] = (1.0 if value > 0.0 else -1.0) if abs(value) > threshold else 0.0


@numba.njit(cache=True, error_model="numpy")
def _constraint_multipliers(lam_dyn, lam_c, a, e_source, c_rows, lam_a):  # pragma: no cover (compiled)
    """``lam_a`` in the problem's row order: the dynamics rows' ``-lam_dyn / e``, the others' ``lam_c``."""
    for i in range(lam_dyn.size):
        lam_a[i] = -lam_dyn[i] / a[e_source[i]]
    for j in range(c_rows.size):
        lam_a[c_rows[j]] = lam_c[j]
