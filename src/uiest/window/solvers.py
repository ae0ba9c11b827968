"""Backends that solve a :class:`~uiest.window.problem.WindowProblem`.

``"ipopt"`` (the reference, :class:`IpoptSolver`), ``"gn"`` (Gauss-Newton SQP) and ``"rti"``
(one Gauss-Newton step per sample; both :class:`~uiest.window.gauss_newton.GaussNewtonSolver`).
A backend is built once per window problem and called at every step with a guess and the
window's parameters; it returns a :class:`WindowSolution`.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import casadi as ca
import numpy as np

from uiest.box import FloatArray
from uiest.errors import OptionError
from uiest.window.polish import refine
from uiest.window.problem import WindowProblem

__all__ = [
    "FEASIBILITY_TOL",
    "IPOPT_DEFAULTS",
    "IPOPT_WARM_START",
    "IpoptSolver",
    "WindowSolution",
    "WindowSolver",
]

SUCCESS_STATUSES = frozenset({"Solve_Succeeded", "Solved_To_Acceptable_Level"})
"""IPOPT return statuses counted as a usable solution."""

NEAR_SUCCESS_STATUSES = frozenset({"Search_Direction_Becomes_Too_Small"})
"""Statuses counted as solved when the final iterate is feasible: IPOPT stops because no step can
improve the point further at the given numerical precision."""

POLISH_BELOW = 1e-3
"""A solution of a window whose cost IPOPT saw scaled by less than this (weights above 1e9, see
:meth:`WindowProblem.objective_scale`) is refined (:func:`uiest.window.polish.refine`): IPOPT's
stopping test is ``1/c`` times looser in the original units."""

FEASIBILITY_TOL = 1e-8
"""Largest violation of the (scaled) constraints and bounds accepted for a near-success status."""

IPOPT_DEFAULTS: dict[str, Any] = {
    "print_level": 0,
    "sb": "yes",
    "tol": 1e-10,
    "acceptable_tol": 1e-8,
    "acceptable_iter": 10,
    "max_iter": 300,
    "nlp_scaling_method": "none",
    "mu_strategy": "adaptive",
}
"""IPOPT options used unless overridden.

The window problem is already scaled (variables by the signals' scales, residuals by the
weights), so IPOPT's own gradient-based scaling is off: it would scale the objective down by the
initial gradient (large when the prior is far off) and then stop short of the optimum in the
weakly observable directions. The barrier update is adaptive. Design notes: window solvers.
"""

IPOPT_WARM_START: dict[str, Any] = {
    "warm_start_init_point": "yes",
    "mu_init": 1e-6,
    "warm_start_bound_push": 1e-9,
    "warm_start_bound_frac": 1e-9,
    "warm_start_slack_bound_push": 1e-9,
    "warm_start_slack_bound_frac": 1e-9,
    "warm_start_mult_bound_push": 1e-9,
}
"""Options added for primal-dual warm starts (shifted previous solution and multipliers)."""


@dataclass(frozen=True)
class WindowSolution:
    """What a backend returns for one window solve.

    Attributes
    ----------
    z : ndarray (n_var,)
        Scaled decision vector at the solver's last iterate.
    lam_x, lam_g : ndarray
        Multipliers of the simple bounds and of g: IPOPT's for the cost ``|r|^2`` (those of its scaled cost
        divided by the scale; an IPOPT warm start takes them back), the Gauss-Newton backends' for ``|r|^2 / 2``
        (the Lagrangian their stationarity test uses).
    cost : float
        ``|r|^2`` at ``z``.
    status : str
        The return status of the solver that produced ``z`` (after a fallback, IPOPT's).
    success : bool
        Whether the status counts as solved.
    iterations : int
    solve_time : float
        Wall-clock seconds of the call.
    fallback : bool
        The Gauss-Newton backend did not converge and handed the window to IPOPT.
    primary_status : str
        After a fallback, why Gauss-Newton handed over (``"gn QP_failed"``, ``"gn Stalled"``,
        ``"gn Maximum_Iterations_Exceeded"``, ...); else ``""``.

    """

    z: FloatArray
    lam_x: FloatArray
    lam_g: FloatArray
    cost: float
    status: str
    success: bool
    iterations: int
    solve_time: float
    fallback: bool = False
    primary_status: str = ""


class WindowSolver(Protocol):
    """A backend: ``solve(z0, p, lam_x0, lam_g0) -> WindowSolution``."""

    problem: WindowProblem

    def solve(
        self,
        z0: FloatArray,
        p: FloatArray,
        lam_x0: FloatArray | None = None,
        lam_g0: FloatArray | None = None,
    ) -> WindowSolution:
        """Solve the window problem from the guess ``z0`` with parameters ``p``."""
        ...

    def reset(self) -> None:
        """Forget what earlier solves left behind (called when the estimator starts over)."""
        ...


@contextlib.contextmanager
def interruptible() -> Iterator[None]:
    """Ctrl-C (SIGINT) during a CasADi solver call takes effect when the call returns.

    CasADi turns the KeyboardInterrupt raised inside IPOPT into a warning and goes on, so a run of IPOPT solves
    ignored Ctrl-C. Inside, a SIGINT is recorded instead; when the call returns it goes to the handler that was
    installed before (the default one raises KeyboardInterrupt). Outside the main thread (where signals are not
    handled) nothing changes.
    """
    previous = signal.getsignal(signal.SIGINT)
    if threading.current_thread() is not threading.main_thread() or previous is None:  # None: not set from Python
        yield
        return
    caught: list[Any] = []
    signal.signal(signal.SIGINT, lambda signum, frame: caught.append(frame))
    try:
        yield
    finally:  # also where the call raised: the interrupt is not lost
        signal.signal(signal.SIGINT, previous)
        if caught and callable(previous):
            previous(signal.SIGINT, caught[0])
        elif caught and previous == signal.SIG_DFL:
            signal.raise_signal(signal.SIGINT)  # what the default would have done


class IpoptSolver:
    """CasADi ``nlpsol("ipopt")`` on a window problem, built once.

    Parameters
    ----------
    problem : WindowProblem
    warm_start : bool
        Build with IPOPT's primal-dual warm-start options (:data:`IPOPT_WARM_START`); the
        multipliers passed to :meth:`solve` are then used.
    options : mapping, optional
        IPOPT options overriding :data:`IPOPT_DEFAULTS` (and the warm-start ones).
    polish : bool
        Refine every successful solution by Gauss-Newton steps with the active set fixed
        (:func:`uiest.window.polish.refine`): IPOPT's iterate stops short of the optimum in
        weakly determined directions; the time is included in ``solve_time``.

    """

    def __init__(
        self,
        problem: WindowProblem,
        *,
        warm_start: bool = False,
        options: Mapping[str, Any] | None = None,
        polish: bool = False,
    ):
        self.problem = problem
        self.warm_start = warm_start
        self.polish = bool(polish)
        ipopt = dict(IPOPT_DEFAULTS)
        if warm_start:
            ipopt.update(IPOPT_WARM_START)
        ipopt.update(options or {})
        try:
            self._solver = ca.nlpsol(
                f"window_{problem.length}",
                "ipopt",
                problem.nlp(),
                # IPOPT backtracks from a trial point where the model is not finite (outside its domain); CasADi
                # would print a warning for every such evaluation (thousands in a study); the status says how it ended
                {"ipopt": ipopt, "print_time": False, "error_on_fail": False, "show_eval_warnings": False},
            )
        except RuntimeError as exc:
            raise OptionError(f"solver_options: IPOPT rejected the options {ipopt}: {exc}") from exc

    def reset(self) -> None:
        """Nothing to forget: every IPOPT solve starts from its own arguments."""

    def solve(
        self,
        z0: FloatArray,
        p: FloatArray,
        lam_x0: FloatArray | None = None,
        lam_g0: FloatArray | None = None,
    ) -> WindowSolution:
        """Solve from the guess ``z0`` (clipped into the bounds) with parameters ``p``."""
        prob = self.problem
        args: dict[str, Any] = {
            "x0": np.clip(z0, prob.lbx, prob.ubx),
            "p": p,
            "lbx": prob.lbx,
            "ubx": prob.ubx,
            "lbg": prob.lbg,
            "ubg": prob.ubg,
        }
        c = prob.objective_scale(p)  # IPOPT sees c |r|^2: its multipliers are c times those of |r|^2
        if self.warm_start and lam_x0 is not None and lam_g0 is not None:
            args["lam_x0"] = c * np.asarray(lam_x0)
            args["lam_g0"] = c * np.asarray(lam_g0)
        start = time.perf_counter()
        try:
            with interruptible():
                out = self._solver(**args)
            stats = self._solver.stats()
            status = str(stats.get("return_status", "unknown"))
        except RuntimeError as exc:  # evaluation errors (NaN/inf in f or h) and the like
            elapsed = time.perf_counter() - start
            nan = np.full(prob.n_var, np.nan)
            return WindowSolution(
                z=nan,
                lam_x=np.zeros(prob.n_var),
                lam_g=np.zeros(prob.n_con),
                cost=float("nan"),
                status=f"error: {exc}".splitlines()[0][:200],
                success=False,
                iterations=0,
                solve_time=elapsed,
            )
        z = np.asarray(out["x"], dtype=float).reshape(-1)
        success = bool(np.all(np.isfinite(z))) and (
            status in SUCCESS_STATUSES or (status in NEAR_SUCCESS_STATUSES and self.violation(z, p) <= FEASIBILITY_TOL)
        )
        cost = float(out["f"]) / c
        if success and (self.polish or c < POLISH_BELOW):
            z, cost, _ = refine(prob, z, p)
        elapsed = time.perf_counter() - start
        return WindowSolution(
            z=z,
            lam_x=np.asarray(out["lam_x"], dtype=float).reshape(-1) / c,
            lam_g=np.asarray(out["lam_g"], dtype=float).reshape(-1) / c,
            cost=cost,
            status=status,
            success=success,
            iterations=int(stats.get("iter_count", 0)),
            solve_time=elapsed,
        )

    def violation(self, z: FloatArray, p: FloatArray) -> float:
        """Largest violation of ``lbg <= g(z, p) <= ubg`` and ``lbx <= z <= ubx`` (scaled units)."""
        prob = self.problem
        g = np.asarray(prob.constraint_function(z, p), dtype=float).reshape(-1) if prob.n_con else np.zeros(0)
        return largest_violation(prob, z, g)


def largest_violation(problem: WindowProblem, z: FloatArray, g: FloatArray) -> float:
    """Largest violation of ``lbx <= z <= ubx`` and ``lbg <= g <= ubg`` (scaled units), ``g`` given."""
    worst = float(np.max(np.maximum(problem.lbx - z, z - problem.ubx), initial=0.0))
    if g.size:
        worst = max(worst, float(np.max(np.maximum(problem.lbg - g, g - problem.ubg), initial=0.0)))
    return worst
