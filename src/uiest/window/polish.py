r"""Gauss-Newton refinement ("polish") of a window solution with its active set fixed.

IPOPT solves the multiple-shooting problem through its KKT system, whose multipliers grow with
the output weights; the gradient of the Lagrangian then carries rounding errors near IPOPT's
tolerance (1e-10), and in directions the data barely determine (the crop model's two crop
weights, seen only through slow dynamics) the iterate stops ~1e-6 (scaled) short of the optimum.
Tightening ``tol`` makes IPOPT fail instead (restoration failures). A few Gauss-Newton steps on
the same problem, solved by orthogonal factorisations instead of normal equations, reach the
optimum to about ``eps * cond(J)``::

    min_d |r + J d|^2   s.t.   c_E + G_E d = 0,   d_i = 0 for variables at a bound,

with ``E`` the dynamics and the inequality rows that are active (within ``active_tol`` of a
bound; those are held at the bound; variables are first clipped into their bounds, which IPOPT
relaxes by ~1e-8). The null space of ``G_E`` (SVD) turns this into an
unconstrained linear least-squares problem (``lstsq``). A step is shortened to keep the free
variables in their bounds and accepted only if the inequality constraints still hold (to 1e-9,
scaled), the equality violation does not grow past ``max(old, 1e-9)`` and either the cost does
not increase by more than a relative 1e-6 or the point was infeasible (> 1e-9) and the step
halved its violation; otherwise the previous point is kept (design notes: window solvers).
"""

from __future__ import annotations

import numpy as np

from uiest.box import FloatArray
from uiest.window.buffered import BufferedFunction
from uiest.window.problem import WindowProblem

__all__ = ["refine"]

ACTIVE_TOL = 1e-6
"""Distance (scaled units) below which a bound or an inequality counts as active."""

FEASIBILITY_TOL = 1e-9
"""Largest violation (scaled units) of constraints a refined point may have."""


class _Evaluator:
    """``(r, J, g, G)`` of a problem, dense, through CasADi's buffer interface."""

    def __init__(self, problem: WindowProblem) -> None:
        fun = problem.gauss_newton_function
        self.shapes = [(fun.size1_out(i), fun.size2_out(i)) for i in range(4)]
        self.call = BufferedFunction(fun)

    def __call__(self, z: FloatArray, p: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        r, J, g, G = (
            arr.reshape((rows, cols), order="F").copy()
            for arr, (rows, cols) in zip(self.call(z, p), self.shapes, strict=True)
        )
        return r.ravel(), J, g.ravel(), G


def _evaluator(problem: WindowProblem) -> _Evaluator:
    cached = problem.__dict__.get("_gauss_newton_evaluator")
    if cached is None:
        cached = problem.__dict__["_gauss_newton_evaluator"] = _Evaluator(problem)
    return cached


def _violation(problem: WindowProblem, g: FloatArray) -> tuple[float, float]:
    """Largest violation of the equality rows and of the inequality rows of ``lbg <= g <= ubg``."""
    if not g.size:
        return 0.0, 0.0
    eq = problem.lbg == problem.ubg
    viol = np.maximum(problem.lbg - g, g - problem.ubg)
    return float(np.max(np.abs(viol[eq]), initial=0.0)), float(np.max(viol[~eq], initial=0.0))


def refine(
    problem: WindowProblem, z: FloatArray, p: FloatArray, *, iterations: int = 2, active_tol: float = ACTIVE_TOL
) -> tuple[FloatArray, float, int]:
    """Refine the (scaled) window solution ``z`` by Gauss-Newton steps (see the module docstring).

    Returns
    -------
    z : ndarray
        The refined point (``z`` itself when no step was accepted).
    cost : float
        ``|r|^2`` at the returned point.
    steps : int
        Number of accepted steps.

    """
    fun = _evaluator(problem)
    lbx, ubx, lbg, ubg = problem.lbx, problem.ubx, problem.lbg, problem.ubg
    z = np.clip(np.asarray(z, dtype=float), lbx, ubx)  # IPOPT relaxes bounds by ~1e-8: snap onto them
    r, J, g, G = fun(z, p)
    cost = float(r @ r)
    accepted = 0
    for _ in range(iterations):
        free = (z - lbx > active_tol) & (ubx - z > active_tol)
        low, high = g - lbg < active_tol, ubg - g < active_tol
        rows = (lbg == ubg) | low | high
        target = np.where(low, lbg, ubg)
        Jf, Gf = J[:, free], G[rows][:, free]
        c = g[rows] - target[rows]
        if Gf.shape[0]:
            U, sing, Vt = np.linalg.svd(Gf, full_matrices=True)
            rank = int((sing > 1e-12 * max(sing[0], 1e-300)).sum()) if sing.size else 0
            d_p = Vt[:rank].T @ ((U[:, :rank].T @ -c) / sing[:rank])
            Z = Vt[rank:].T
        else:
            d_p, Z = np.zeros(int(free.sum())), np.eye(int(free.sum()))
        t = np.linalg.lstsq(Jf @ Z, -(r + Jf @ d_p), rcond=None)[0] if Z.size else np.zeros(0)
        d = np.zeros_like(z)
        d[free] = d_p + Z @ t
        if not np.all(np.isfinite(d)) or np.max(np.abs(d), initial=0.0) < 1e-15:
            break
        with np.errstate(divide="ignore", invalid="ignore"):
            room = np.where(d > 0, (ubx - z) / d, np.where(d < 0, (lbx - z) / d, np.inf))
        alpha = min(1.0, float(np.min(room[free], initial=np.inf)))
        z_new = z + alpha * d
        r_n, J_n, g_n, G_n = fun(z_new, p)
        cost_new = float(r_n @ r_n)
        eq_old, _ = _violation(problem, g)
        eq_new, ineq_new = _violation(problem, g_n)
        more_feasible = eq_old > FEASIBILITY_TOL and eq_new < 0.5 * eq_old
        if (
            not np.isfinite(cost_new)
            or ineq_new > FEASIBILITY_TOL
            or eq_new > max(eq_old, FEASIBILITY_TOL)
            or (cost_new > cost * (1.0 + 1e-6) + 1e-300 and not more_feasible)
        ):
            break
        z, r, J, g, G, cost = z_new, r_n, J_n, g_n, G_n, cost_new
        accepted += 1
    return z, cost, accepted
