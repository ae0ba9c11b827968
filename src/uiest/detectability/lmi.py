"""Shared LMI machinery: scaled Jacobian samples, point sets, bisection, eigenvalue re-checks.

All certificates are computed in scaled coordinates ``x = S_x x~`` (``S = diag(scale)`` of each
signal, see :class:`uiest.signal.Signal`) and mapped back. Pointwise LMIs are imposed on an
*active set* of sample points (box corners plus a coarse grid), then checked on a dense *pool*
(finer grid plus uniform samples) with batched ``numpy.linalg.eigvalsh``; the worst violators
are added to the active set and the problem is solved again (cutting plane).
"""

from __future__ import annotations

import itertools
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import cvxpy as cp
import numpy as np

from uiest.box import Box, FloatArray

SOLVER = "CLARABEL"
"""cvxpy solver for every LMI (SCS returns 'optimal' for violated LMIs; never trusted here)."""

OK_STATUSES = ("optimal",)
"""Statuses accepted before the independent re-check; 'optimal_inaccurate' is not accepted."""


@dataclass(frozen=True)
class Points:
    """Sample points of a box product, shape (m, d), and how they were made."""

    values: FloatArray
    description: str


def grid_points(box: Box, per_axis: int) -> FloatArray:
    """A tensor grid with ``per_axis`` points per finite axis, endpoints (corners) included.

    A degenerate axis (lower == upper) contributes its single value. Shape (m, n).
    """
    axes = [
        np.array([lo]) if lo == hi else np.linspace(lo, hi, per_axis)
        for lo, hi in zip(box.lower, box.upper, strict=True)
    ]
    if not axes:
        return np.zeros((1, 0))
    return np.array(list(itertools.product(*axes)), dtype=float).reshape(-1, box.size)


def sampling_box(box: Box, center: FloatArray, half_width: FloatArray) -> Box:
    """``box`` with infinite sides replaced by ``center -/+ half_width``."""
    lower = np.where(np.isfinite(box.lower), box.lower, center - half_width)
    upper = np.where(np.isfinite(box.upper), box.upper, center + half_width)
    return Box(lower, upper)


def point_sets(box: Box, coarse: int, fine: int, n_random: int, seed: int) -> tuple[Points, Points]:
    """Active starting set (coarse grid with corners) and dense pool (fine grid + random) of a box."""
    active = grid_points(box, coarse)
    rng = np.random.default_rng(seed)
    pool = np.vstack([grid_points(box, fine), box.sample(rng, n_random)])
    return (
        Points(active, f"{coarse}-point grid per axis incl. corners ({len(active)} points)"),
        Points(pool, f"{fine}-point grid per axis + {n_random} uniform samples ({len(pool)} points)"),
    )


def batched(fun: ca.Function, columns: list[FloatArray]) -> list[FloatArray]:
    """Evaluate a CasADi Function on m points at once.

    ``columns[i]`` has shape (m, n_i); returns one array of shape (m, rows, cols) per output.
    """
    m = columns[0].shape[0]
    mapped = fun.map(m, "serial")
    outs = mapped(*[c.T for c in columns])
    outs = outs if isinstance(outs, tuple | list) else [outs]
    result = []
    for i, out in enumerate(outs):
        rows, cols = fun.size_out(i)
        arr = np.asarray(out, dtype=float).reshape(rows, m, cols)  # map() stacks [M_1, ..., M_m] horizontally
        result.append(np.transpose(arr, (1, 0, 2)))
    return result


def min_eig(matrices: FloatArray) -> FloatArray:
    """Smallest eigenvalue of each symmetric matrix in a batch (m, k, k) -> (m,)."""
    sym = 0.5 * (matrices + np.swapaxes(matrices, -1, -2))
    return np.linalg.eigvalsh(sym)[..., 0]


def symmetric(expr: cp.Expression) -> cp.Expression:
    """``(M + M^T) / 2`` so that cvxpy accepts ``>> 0`` on block matrices."""
    return 0.5 * (expr + expr.T)


def solve(problem: cp.Problem) -> str:
    """Solve with the default LMI solver; return the status ('solver_error' if it raised)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # 'inaccurate' shows up in the status instead
            problem.solve(solver=SOLVER)
    except cp.error.SolverError:
        return "solver_error"
    return str(problem.status)


def bisect(feasible: Callable[[float], bool], lower: float, upper: float, tol: float) -> float | None:
    """Smallest value in (lower, upper] for which ``feasible`` holds (monotone), to ``tol``.

    Returns None when ``feasible(upper)`` is False.
    """
    if not feasible(upper):
        return None
    lo, hi = lower, upper
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if feasible(mid):
            hi = mid
        else:
            lo = mid
    return hi


def is_constant(fun: ca.Function, output: int, wrt: list[int]) -> bool:
    """Whether output ``output`` of ``fun`` is independent of the inputs ``wrt`` (structurally)."""
    syms = [ca.SX.sym(f"a{i}", fun.size_in(i)) for i in range(fun.n_in())]
    expr = fun(*syms)
    expr = expr[output] if isinstance(expr, tuple | list) else expr
    return not any(ca.depends_on(expr, syms[i]) for i in wrt)


def bisect_discount(feasible: Callable[[float], bool], floor: float, tol: float, gap: float = 1e-6) -> float | None:
    """Smallest discount mu in ``[floor, 1 - gap]`` for which ``feasible`` holds (monotone).

    Bisects on ``log(1 - mu)`` so that discounts near 1 (slow sampled systems: ``1 - mu`` of
    1e-5) are resolved to a relative tolerance of 1 % in ``1 - mu``, and stops once the bracket
    is narrower than ``tol`` in mu as well. Returns None when ``feasible(1 - gap)`` is False.
    """
    if not feasible(1.0 - gap):
        return None
    hi, lo = np.log(gap), np.log(1.0 - floor)  # log(1 - mu): hi is feasible, lo side infeasible
    if feasible(floor):
        return floor
    while abs(np.exp(hi) - np.exp(lo)) > tol or hi - lo < -0.01:
        mid = 0.5 * (lo + hi)
        if feasible(1.0 - float(np.exp(mid))):
            hi = mid
        else:
            lo = mid
    return 1.0 - float(np.exp(hi))
