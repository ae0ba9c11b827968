r"""Gauss-Newton SQP and real-time iteration for window problems (nonlinear least squares).

The window problem is ``min |r(z, p)|^2`` s.t. ``lbg <= g(z, p) <= ubg`` and ``lbx <= z <= ubx``
in scaled variables (see :mod:`uiest.window.problem`). Each Gauss-Newton iteration solves the
convex QP

    min_dz  1/2 dz^T (J^T J + lambda I) dz + (J^T r)^T dz
    s.t.    lbg - g <= G dz <= ubg - g,     lbx - z <= dz <= ubx - z,

with ``J = dr/dz``, ``G = dg/dz`` (one CasADi Function gives r, J, g and G), solved by CasADi's
active-set QP solver ``qrqp`` on the sparse matrices. The step is accepted by a backtracking
line search on the exact penalty merit ``|r|^2 + nu |violation of g|_1`` (``nu`` from the QP
multipliers); ``lambda`` (Levenberg-Marquardt) is 0 and raised only when a QP fails.

Stopping: ``|dz|_inf <= step_tol`` (scaled units) or a predicted cost decrease below
``cost_tol (1 + |r|^2)``, with the constraints satisfied to ``FEASIBILITY_TOL``; or ``max_iter``.
RTI (``max_iter=1``) takes one full step from the warm start per sample: its estimate is not the
optimum but the first Gauss-Newton iterate from the shifted previous solution.

Reliability: a failed QP (or NaN) is retried with ``lambda = 1e-6 |J^T J|``; if that fails too
and ``fallback=True``, the sample is solved by IPOPT and the status says so.
"""

from __future__ import annotations

import time
from typing import Any

import casadi as ca
import numpy as np

from uiest.box import FloatArray
from uiest.window.problem import WindowProblem
from uiest.window.solvers import FEASIBILITY_TOL, IpoptSolver, WindowSolution

QP_OPTIONS: dict[str, Any] = {"print_iter": False, "print_header": False, "print_info": False, "error_on_fail": False}


class GaussNewtonSolver:
    """Gauss-Newton SQP on a window problem, built once (see the module docstring).

    Parameters
    ----------
    problem : WindowProblem
    max_iter : int
        Iterations per solve (1: real-time iteration).
    step_tol : float
        Convergence tolerance on ``|dz|_inf`` in scaled units.
    cost_tol : float
        Also converged when the Gauss-Newton model predicts a decrease of ``|r|^2`` below
        ``cost_tol (1 + |r|^2)`` (flat, weakly observable directions move without changing the cost).
    fallback : bool
        Solve with IPOPT when both the plain and the regularised QP fail.

    """

    def __init__(
        self,
        problem: WindowProblem,
        *,
        max_iter: int = 30,
        step_tol: float = 1e-10,
        cost_tol: float = 1e-14,
        fallback: bool = True,
    ) -> None:
        self.problem = problem
        self.max_iter = int(max_iter)
        self.step_tol = float(step_tol)
        self.cost_tol = float(cost_tol)
        self.fallback = fallback
        z = ca.SX.sym("z", problem.n_var)
        p = ca.SX.sym("p", problem.n_par)
        r = problem.residual_function(z, p)
        g = problem.constraint_function(z, p)
        J = ca.jacobian(r, z)
        G = ca.jacobian(g, z)
        H = ca.mtimes(J.T, J)
        self._linearisation = ca.Function("gn_linearisation", [z, p], [r, ca.mtimes(J.T, r), H, g, G])
        self._merit_parts = ca.Function("gn_merit", [z, p], [r, g])
        self._qp = ca.conic("gn_qp", "qrqp", {"h": H.sparsity(), "a": G.sparsity()}, dict(QP_OPTIONS))
        self._ipopt: IpoptSolver | None = None
        self._lam_x = np.zeros(problem.n_var)
        self._lam_a = np.zeros(problem.n_con)
        self._at_z: tuple[FloatArray, FloatArray] = (np.zeros(0), np.zeros(0))

    def _merit(self, z: FloatArray, p: FloatArray, nu: float) -> float:
        r, g = (np.asarray(v, dtype=float).reshape(-1) for v in self._merit_parts(z, p))
        return self._merit_value(r, g, nu)

    def _merit_value(self, r: FloatArray, g: FloatArray, nu: float) -> float:
        """``|r|^2 + nu |violation of lbg <= g <= ubg|_1``."""
        prob = self.problem
        violation = np.maximum(prob.lbg - g, 0.0).sum() + np.maximum(g - prob.ubg, 0.0).sum() if g.size else 0.0
        return float(r @ r + nu * violation)

    def _violation(self, z: FloatArray, p: FloatArray) -> float:
        prob = self.problem
        worst = float(np.max(np.maximum(prob.lbx - z, z - prob.ubx), initial=0.0))
        if prob.n_con:
            g = np.asarray(self._merit_parts(z, p)[1], dtype=float).reshape(-1)
            worst = max(worst, float(np.max(np.maximum(prob.lbg - g, g - prob.ubg), initial=0.0)))
        return worst

    def _step(
        self, z: FloatArray, p: FloatArray, regularise: float
    ) -> tuple[FloatArray | None, FloatArray, float, float]:
        """One QP: returns (dz or None, lam_g, cost |r|^2, predicted decrease of |r|^2).

        Keeps ``(r, g)`` at ``z`` in ``self._at_z`` so that the line search need not evaluate them again.
        """
        prob = self.problem
        r, grad, H, g, G = self._linearisation(z, p)
        r_arr = np.asarray(r, dtype=float).reshape(-1)
        g_arr = np.asarray(g, dtype=float).reshape(-1)
        self._at_z = (r_arr, g_arr)
        if regularise:
            H = H + regularise * ca.DM.eye(prob.n_var)
        out = self._qp(
            h=H,
            g=grad,
            a=G,
            lba=prob.lbg - g_arr,
            uba=prob.ubg - g_arr,
            lbx=prob.lbx - z,
            ubx=prob.ubx - z,
            lam_x0=self._lam_x,
            lam_a0=self._lam_a,
        )
        dz = np.asarray(out["x"], dtype=float).reshape(-1)
        ok = bool(self._qp.stats().get("success", False)) and np.all(np.isfinite(dz))
        lam_g = np.asarray(out["lam_a"], dtype=float).reshape(-1)
        if ok:  # the active set of this QP starts the next one (qrqp is an active-set method)
            self._lam_x = np.asarray(out["lam_x"], dtype=float).reshape(-1)
            self._lam_a = lam_g
        # predicted decrease of |r|^2 by the Gauss-Newton model: -2 (grad^T dz + dz^T H dz / 2)
        predicted = -2.0 * float(out["cost"]) if ok else float("nan")
        return (dz if ok else None), lam_g, float(r_arr @ r_arr), predicted

    def solve(
        self,
        z0: FloatArray,
        p: FloatArray,
        lam_x0: FloatArray | None = None,
        lam_g0: FloatArray | None = None,
    ) -> WindowSolution:
        """Gauss-Newton iterations from ``z0`` (clipped into the bounds)."""
        prob = self.problem
        start = time.perf_counter()
        z = np.clip(np.asarray(z0, dtype=float), prob.lbx, prob.ubx)
        lam_g = np.zeros(prob.n_con)
        # qrqp starts cold at the first iteration (the shifted multipliers of the previous window
        # made a few QPs take 10x longer: UISE p95 20 ms against 4.6 ms) and from the previous
        # iteration's active set afterwards
        self._lam_x = np.zeros(prob.n_var)
        self._lam_a = np.zeros(prob.n_con)
        status, converged, iterations, regularised = "Maximum_Iterations_Exceeded", False, 0, False
        for iterations in range(1, self.max_iter + 1):  # noqa: B007 (iterations is reported)
            dz, lam_g, cost, predicted = self._step(z, p, 0.0)
            if dz is None:
                scale = float(np.abs(np.asarray(self._linearisation(z, p)[2].nonzeros())).max(initial=1.0))
                dz, lam_g, cost, predicted = self._step(z, p, 1e-6 * scale)
                regularised = True
            if dz is None:
                status = "QP_failed"
                break
            nu = 2.0 * float(np.abs(lam_g).max(initial=0.0)) + 1.0
            merit0 = self._merit_value(*self._at_z, nu)
            alpha = 1.0
            if self.max_iter > 1:
                while alpha > 1e-4 and self._merit(z + alpha * dz, p, nu) > merit0 * (1.0 + 1e-12) + 1e-300:
                    alpha *= 0.5
            z = np.clip(z + alpha * dz, prob.lbx, prob.ubx)
            small_step = alpha * np.abs(dz).max(initial=0.0) <= self.step_tol
            no_progress = predicted <= self.cost_tol * (1.0 + cost)
            if small_step or no_progress:
                feasible = self._violation(z, p) <= FEASIBILITY_TOL
                if feasible:
                    status, converged = "Converged", True
                    break
                if small_step:
                    status = "Infeasible_Stationary_Point"
                    break
        if self.max_iter == 1 and status != "QP_failed":
            # one step of the linearised problem: not feasible to FEASIBILITY_TOL by design
            status, converged = "RTI_Step", bool(np.all(np.isfinite(z)))
        if regularised and converged:
            status += " (regularised)"
        elapsed = time.perf_counter() - start
        if status == "QP_failed" and self.fallback:
            if self._ipopt is None:
                self._ipopt = IpoptSolver(prob)
            fallback = self._ipopt.solve(z0, p)
            return WindowSolution(
                fallback.z,
                fallback.lam_x,
                fallback.lam_g,
                fallback.cost,
                f"gn QP failed -> ipopt {fallback.status}",
                fallback.success,
                iterations + fallback.iterations,
                elapsed + fallback.solve_time,
            )
        r = np.asarray(self._merit_parts(z, p)[0], dtype=float).reshape(-1)
        return WindowSolution(
            z=z,
            lam_x=self._lam_x.copy(),
            lam_g=self._lam_a.copy(),
            cost=float(r @ r),
            status=status,
            success=bool(converged and np.all(np.isfinite(z))),
            iterations=iterations,
            solve_time=elapsed,
        )
