r"""A window point's Gauss-Newton terms: CasADi evaluates ``r, J, g, G``; one compiled pass forms the rest.

The Gauss-Newton solver needs at each point ``|r|^2``, ``J^T r``, ``J^T J`` (with its flat diagonal raised),
the violation of ``lbg <= g <= ubg`` and the KKT stationarity measure. The model's part is evaluated by CasADi
(through its buffer), and the products and tests, which as CasADi expressions would cost more than the model's part,
by one numba pass over index lists built once from the sparsities (design notes: estimator step).

Index convention: ``z`` is the window's stacked variables (``n_var``), ``r`` its residuals (``n_res``), ``g``
its constraint rows (``n_con``). Sparse matrices are their nonzeros in CasADi's column-major order: ``J``
(``n_res x n_var``), ``G`` (``n_con x n_var``), ``J^T J`` in :attr:`NormalTerms.h_sparsity`.
"""

from __future__ import annotations

from typing import NamedTuple

import casadi as ca
import numba
import numpy as np

from uiest.box import FloatArray
from uiest.window.buffered import BufferedFunction
from uiest.window.curvature import IndexArray
from uiest.window.problem import WindowProblem

__all__ = ["NormalTerms", "Point"]


class Point(NamedTuple):
    """An evaluated point.

    ``z`` (n_var), the slot whose arrays hold its terms, ``|r|^2``, the violation of ``lbg <= g <= ubg`` (the merit's:
    the sum of the rows' excess over the violation floor; and the largest row's, raw), the KKT measure, and the
    nonzeros of ``J^T r`` (n_var), ``J^T J`` (in ``h_sparsity``), ``g`` (n_con) and ``G``.
    """

    z: FloatArray
    slot: int
    cost: float
    violation: float
    worst: float
    stationarity: float
    q: FloatArray
    h: FloatArray
    g: FloatArray
    a: FloatArray


class NormalTerms:
    """The Gauss-Newton terms of ``problem`` at a point, into one of two sets of arrays that take turns.

    Parameters
    ----------
    problem : WindowProblem
        The window problem: residuals ``r``, constraints ``g``, bounds.
    flat_curvature : float
        A positive diagonal entry of ``J^T J`` below this times the largest is raised to it.
    violation_floor : float
        A row's violation up to this counts as none in the merit's violation.

    Notes
    -----
    ``J^T J`` is held in the sparsity of ``J^T J`` plus the whole diagonal (:attr:`h_sparsity`). The KKT measure is
    ``|s|_inf`` with ``s = J^T r + G^T lam_g``, where ``z`` is on its upper (lower) bound only the positive
    (negative) part of ``s``; a NaN anywhere makes the measure, ``|r|^2`` or the violations NaN.

    """

    def __init__(self, problem: WindowProblem, *, flat_curvature: float, violation_floor: float) -> None:
        z, p = problem.z, problem.p
        J, G = ca.jacobian(problem.r, z), ca.jacobian(problem.g, z)
        pattern = J.sparsity()
        self.h_sparsity: ca.Sparsity = ca.mtimes(pattern.T, pattern) + ca.Sparsity.diag(problem.n_var)
        self.a_sparsity: ca.Sparsity = G.sparsity()
        function = ca.Function("gn_model_terms", [z, p], [problem.r, J, ca.densify(problem.g), G])
        self._buffers = (BufferedFunction(function), BufferedFunction(function))
        self._products = _products(pattern, self.h_sparsity)
        self._columns = (_column_rows(pattern), _column_rows(G.sparsity()))
        self._bounds = tuple(np.asarray(b, dtype=float) for b in (problem.lbg, problem.ubg, problem.lbx, problem.ubx))
        self._settings = np.array([flat_curvature, violation_floor])
        h_rows, h_cols = (np.asarray(i) for i in self.h_sparsity.get_triplet())
        self._diagonal = np.flatnonzero(h_rows == h_cols)
        n_var, nnz_h = problem.n_var, self.h_sparsity.nnz()
        self._out = [(np.empty(4), np.empty(n_var), np.empty(nnz_h)) for _ in range(2)]

    def __call__(self, slot: int, z: FloatArray, p: FloatArray, lam_g: FloatArray) -> Point:
        """The point ``z`` (n_var) with parameters ``p`` and constraint multipliers ``lam_g`` (n_con).

        Written into ``slot``'s arrays (0 or 1), which the next call with the same slot overwrites.
        """
        r, j, g, a = self._buffers[slot](z, p)
        tests, q, h = self._out[slot]
        _terms(z, r, j, g, a, lam_g, self._products, self._columns, self._diagonal, self._bounds, self._settings,
               tests, q, h)  # fmt: skip
        cost, violation, worst, stationarity = tests.tolist()
        return Point(z, slot, cost, violation, worst, stationarity, q, h, g, a)


_Columns = tuple[IndexArray, IndexArray]
"""A CSC sparsity's column pointers and row indices."""


def _column_rows(sparsity: ca.Sparsity) -> _Columns:
    return np.asarray(sparsity.colind(), dtype=np.int64), np.asarray(sparsity.row(), dtype=np.int64)


def _products(j_sparsity: ca.Sparsity, h_sparsity: ca.Sparsity) -> tuple[IndexArray, IndexArray, IndexArray]:
    """``(target, left, right)``: ``J^T J``'s nonzero ``target[t]`` gains ``J[left[t]] J[right[t]]``.

    One entry per pair of ``J``'s nonzeros in the same row, ordered by target (then by row).
    """
    j_rows, j_cols = (np.asarray(i, dtype=np.int64) for i in j_sparsity.get_triplet())
    h_rows, h_cols = (np.asarray(i, dtype=np.int64) for i in h_sparsity.get_triplet())
    position = {(int(i), int(k)): n for n, (i, k) in enumerate(zip(h_rows, h_cols, strict=True))}
    by_row: dict[int, list[int]] = {}
    for n, row in enumerate(j_rows):
        by_row.setdefault(int(row), []).append(n)
    pairs = [
        (position[int(j_cols[a]), int(j_cols[b])], row, a, b)
        for row, entries in by_row.items()
        for a in entries
        for b in entries
    ]
    pairs.sort()
    table = np.array([(t, a, b) for t, _, a, b in pairs], dtype=np.int64).reshape(-1, 3)
    return table[:, 0].copy(), table[:, 1].copy(), table[:, 2].copy()


@numba.njit(cache=True)
def _terms(z, r, j, g, a, lam_g, products, columns, diagonal, bounds, settings, tests, q, h):  # pragma: no cover
    """Fill ``tests`` (``|r|^2``, violation, worst row, KKT measure), ``q = J^T r`` and ``h = J^T J`` (raised)."""
    lbg, ubg, lbx, ubx = bounds
    flat_curvature, violation_floor = settings[0], settings[1]
    cost = 0.0
    for value in r:
        cost += value * value
    violation, worst, undefined = 0.0, 0.0, False
    for i in range(g.size):
        if g[i] < lbg[i]:
            excess = lbg[i] - g[i]
        elif g[i] > ubg[i]:
            excess = g[i] - ubg[i]
        else:
            excess = 0.0
            undefined = undefined or g[i] != g[i]
        if excess > violation_floor:
            violation += excess - violation_floor
        if excess > worst:
            worst = excess
    if undefined:
        violation, worst = np.nan, np.nan
    target, left, right = products
    h[:] = 0.0
    for t in range(target.size):
        h[target[t]] += j[left[t]] * j[right[t]]
    largest = 0.0
    for d in diagonal:
        if h[d] > largest:
            largest = h[d]
    floor = flat_curvature * largest
    for d in diagonal:
        if 0.0 < h[d] < floor:
            h[d] = floor
    (j_start, j_row), (g_start, g_row) = columns
    stationarity, undefined = 0.0, False
    for k in range(z.size):
        gradient = 0.0
        for n in range(j_start[k], j_start[k + 1]):
            gradient += j[n] * r[j_row[n]]
        q[k] = gradient
        s = gradient
        for n in range(g_start[k], g_start[k + 1]):
            s += a[n] * lam_g[g_row[n]]
        if z[k] >= ubx[k]:  # the bound's multiplier takes the part pointing inwards
            s = max(s, 0.0) if s == s else s
        elif z[k] <= lbx[k]:
            s = min(s, 0.0) if s == s else s
        undefined = undefined or s != s
        if abs(s) > stationarity:
            stationarity = abs(s)
    tests[0], tests[1], tests[2] = cost, violation, worst
    tests[3] = np.nan if undefined else stationarity
