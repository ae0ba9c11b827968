"""Shared LMI machinery: batched Jacobians, solver calls with honest statuses, robust rate bisection.

Every certificate is a family of LMIs in a discount rate (mu, eta). A probe at one rate ends
in one of three outcomes, kept apart all the way to the user:

- ``FEASIBLE``: the solver returned a solution and the independent numpy re-check passed at
  every vertex (a solver's "optimal_inaccurate" counts only then);
- ``INFEASIBLE``: the solver solved the margin problem (``max t`` with the LMIs ``>= t I``,
  always feasible) to optimality and ``t* <= 0``;
- ``FAILED``: anything else: the solver raised or returned another status (an "infeasible"
  margin problem is a solver failure), ``0 < t*`` within the floor, or a re-check rejection
  that no cutting plane resolves.

:func:`bisect_rate` finds the smallest feasible rate; a failed probe is retried once nearer the
feasible side and otherwise ends the bisection at the best rate proven so far, never turning a
solver failure into "infeasible".
"""

from __future__ import annotations

import importlib
import itertools
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar

import casadi as ca
import numpy as np

from uiest.box import Box, FloatArray

__all__ = [
    "RATE_FLOOR",
    "RATE_GAP",
    "SOLVED",
    "ActiveSet",
    "Bisection",
    "batched",
    "bisect_rate",
    "cutting_plane_probe",
    "finite_box",
    "grid_points",
    "is_constant",
    "min_eig",
    "solve",
    "symmetric",
]


class _ImportedOnFirstUse:
    """Stands for the module ``name`` and imports it when one of its attributes is first read.

    cvxpy takes about 1.5 s to import (scipy.stats with it); most uses of uiest (estimators, the CLI's
    help, worker processes of a sweep) never solve an LMI. ``importlib.import_module`` holds the import
    lock, so threads that reach for cvxpy at once see it whole (``importlib.util.LazyLoader`` does not
    lock on Python 3.11), and a failed import leaves nothing half-made in ``sys.modules``.
    """

    def __init__(self, name: str) -> None:
        self._name = name

    def __getattr__(self, attribute: str) -> Any:
        return getattr(importlib.import_module(self._name), attribute)


if TYPE_CHECKING:
    import cvxpy as cp
else:
    cp = _ImportedOnFirstUse("cvxpy")

SOLVER = "CLARABEL"
"""cvxpy solver for every LMI (SCS returns 'optimal' for violated LMIs; never trusted here)."""

SOLVED = ("optimal", "optimal_inaccurate")
"""Statuses whose solution is handed to the independent re-check, which alone decides."""

FEASIBLE, INFEASIBLE, FAILED = "feasible", "infeasible", "solver failed"

RATE_FLOOR = 1e-4
"""Lower end of every rate bisection: a rate found at the floor means 'at most 1e-4'."""

RATE_GAP = 1e-6
"""Upper end of every rate bisection is ``1 - RATE_GAP``."""

MAX_ACTIVE = 24
"""Vertices imposed at once; more are added by a cutting plane when the re-check finds them violated."""


def grid_points(box: Box, per_axis: int) -> FloatArray:
    """A tensor grid with ``per_axis`` points per axis, corners included, shape (m, n).

    A degenerate axis (lower == upper) contributes its single value.
    """
    axes = [
        np.array([lo]) if lo == hi else np.linspace(lo, hi, per_axis)
        for lo, hi in zip(box.lower, box.upper, strict=True)
    ]
    if not axes:
        return np.zeros((1, 0))
    return np.array(list(itertools.product(*axes)), dtype=float).reshape(-1, box.size)


def finite_box(box: Box, center: FloatArray, half_width: FloatArray) -> Box:
    """``box`` with infinite sides replaced by ``center -/+ half_width``."""
    lower = np.where(np.isfinite(box.lower), box.lower, center - half_width)
    upper = np.where(np.isfinite(box.upper), box.upper, center + half_width)
    return Box(lower, upper)


def batched(fun: ca.Function, columns: list[FloatArray]) -> list[FloatArray]:
    """Evaluate a CasADi Function on m points at once.

    ``columns[i]`` has shape (m, n_i); returns one array of shape (m, rows, cols) per output.
    """
    m = columns[0].shape[0]
    mapped = fun.map(m, "serial")(*[c.T for c in columns])
    outs = mapped if isinstance(mapped, tuple | list) else [mapped]
    result = []
    for i, out in enumerate(outs):
        rows, cols = fun.size_out(i)
        arr = np.asarray(out, dtype=float).reshape(rows, m, cols)  # map() stacks [M_1, ..., M_m] horizontally
        result.append(np.transpose(arr, (1, 0, 2)))
    return result


def is_constant(fun: ca.Function, output: int, wrt: list[int]) -> bool:
    """Whether output ``output`` of ``fun`` is independent of the inputs ``wrt`` (structurally)."""
    syms = [ca.SX.sym(f"a{i}", fun.size_in(i)) for i in range(fun.n_in())]
    expr = fun(*syms)
    expr = expr[output] if isinstance(expr, tuple | list) else expr
    return not any(ca.depends_on(expr, syms[i]) for i in wrt)


def min_eig(matrices: FloatArray) -> FloatArray:
    """Smallest eigenvalue of each symmetric matrix in a batch (m, k, k) -> (m,)."""
    sym = 0.5 * (matrices + np.swapaxes(matrices, -1, -2))
    return np.asarray(np.linalg.eigvalsh(sym)[..., 0], dtype=np.float64)


def symmetric(expr: cp.Expression) -> cp.Expression:
    """``(M + M^T) / 2`` so that cvxpy accepts ``>> 0`` on block matrices."""
    return 0.5 * (expr + expr.T)


def solve(problem: cp.Problem) -> str:
    """Solve with the default LMI solver; return the status.

    ``'nonfinite_data'`` where cvxpy refuses the problem's data as NaN or infinite (a Jacobian that overflows at a
    point of the domain, or products of huge ones), ``'solver_error'`` where the solver raised.
    """
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # 'inaccurate' shows up in the status instead
            problem.solve(solver=SOLVER)
    except cp.error.SolverError:
        return "solver_error"
    except ValueError as exc:  # cvxpy's check of the data it hands the solver
        if "NaN or Inf" not in str(exc):
            raise
        return "nonfinite_data"
    except BaseException as exc:  # a Rust panic in Clarabel: pyo3's PanicException derives from BaseException only
        if type(exc).__name__ != "PanicException":
            raise
        return "solver_error"
    return str(problem.status)


@dataclass(frozen=True, kw_only=True)
class Bisection:
    """Outcome of :func:`bisect_rate`.

    Attributes
    ----------
    rate : float or None
        Smallest rate proven feasible (None when none was).
    outcome : str
        ``FEASIBLE``, ``INFEASIBLE`` (the largest rate is infeasible) or ``FAILED`` (no rate
        could be decided because the solver failed).
    failed_at : tuple of float
        Rates whose probe failed (the bisection stopped early when this is not empty).
    probes : int
        Probes made.

    """

    rate: float | None
    outcome: str
    failed_at: tuple[float, ...]
    probes: int

    @property
    def note(self) -> str:
        """What the failures cost, or ''."""
        if not self.failed_at:
            return ""
        rates = ", ".join(f"{r:.6g}" for r in self.failed_at)
        if self.rate is None:  # no rate was proved: there is no smallest one to qualify
            return f"the solver failed at rate(s) {rates}"
        return f"the solver failed at rate(s) {rates}, so the smallest rate is an upper estimate"


def bisect_rate(
    probe: Callable[[float], str], *, floor: float = RATE_FLOOR, tol: float = 1e-4, gap: float = RATE_GAP
) -> Bisection:
    """Smallest rate in ``[floor, 1 - gap]`` for which ``probe`` returns ``FEASIBLE`` (monotone).

    Bisects on ``log(1 - rate)``, so rates near one (slow sampled systems: ``1 - rate`` of
    1e-5) are resolved to 1 % of ``1 - rate``, and stops once the bracket is narrower than
    ``tol`` in the rate as well. A ``FAILED`` probe is retried once halfway towards the
    feasible end of the bracket; a second failure ends the bisection (recorded in ``failed_at``).
    """
    failed: list[float] = []
    probes = 0

    def run(rate: float) -> str:
        nonlocal probes
        probes += 1
        outcome = probe(rate)
        if outcome == FAILED:
            failed.append(rate)
        return outcome

    top = 1.0 - gap
    first = run(top)
    if first == FAILED:
        top = 1.0 - 10.0 * gap
        first = run(top)
        if first == INFEASIBLE:  # infeasible below the rate whose probe failed: nothing is decided at 1 - gap
            first = FAILED
    if first != FEASIBLE:
        return Bisection(rate=None, outcome=first, failed_at=tuple(failed), probes=probes)
    if run(floor) == FEASIBLE:
        return Bisection(rate=floor, outcome=FEASIBLE, failed_at=tuple(failed), probes=probes)
    hi, lo = np.log(1.0 - top), np.log(1.0 - floor)  # log(1 - rate): hi feasible, lo not
    while abs(np.exp(hi) - np.exp(lo)) > tol or hi - lo < -0.01:
        mid = 0.5 * (lo + hi)
        outcome = run(1.0 - float(np.exp(mid)))
        if outcome == FAILED:
            mid = 0.5 * (mid + hi)
            outcome = run(1.0 - float(np.exp(mid)))
            if outcome == FAILED:
                break
        if outcome == FEASIBLE:
            hi = mid
        else:
            lo = mid
    return Bisection(rate=1.0 - float(np.exp(hi)), outcome=FEASIBLE, failed_at=tuple(failed), probes=probes)


Solution = TypeVar("Solution")


def cutting_plane_probe(
    solve: Callable[[], tuple[str, Solution | None, float]],
    recheck: Callable[[Solution], FloatArray],
    active: ActiveSet,
    floor: float,
) -> tuple[str, Solution | None]:
    """One rate probe: solve the margin problem on the active vertices, re-check all, grow, repeat.

    ``solve()`` returns (solver status, solution or None, margin t) for the active vertices;
    ``recheck(solution)`` the re-check margin of every vertex (>= 0 passes). Returns the outcome
    and the solution (None unless ``FEASIBLE``).
    """
    for _ in range(len(active.all) + 1):
        status, solution, t = solve()
        if solution is None or status not in SOLVED:
            return FAILED, None
        if t <= 0.0:
            return (INFEASIBLE if status == "optimal" else FAILED), None
        if t <= floor:
            return FAILED, None  # a margin within the solver's tolerance decides nothing
        margins = recheck(solution)
        if margins.min() >= 0.0:
            return FEASIBLE, solution
        if not active.add_worst(margins):
            return FAILED, None  # an imposed vertex fails the re-check: solver inaccuracy
    return FAILED, None


class ActiveSet:
    """The vertices imposed in an LMI: a spread-out subset of at most ``size``, grown by cutting planes.

    After each solve the re-check runs on every vertex; :meth:`add_worst` adds the most violated
    ones that are not imposed yet (never a duplicate), and the LMI is solved again.
    """

    def __init__(self, vertices: FloatArray, size: int = MAX_ACTIVE) -> None:
        self.all = vertices
        m = len(vertices)
        if m <= size:
            self.index = list(range(m))
        else:  # farthest-point selection: a spread-out subset
            flat = vertices.reshape(m, -1)
            chosen = [int(np.argmax(np.linalg.norm(flat - flat.mean(axis=0), axis=1)))]
            dist = np.linalg.norm(flat - flat[chosen[0]], axis=1)
            while len(chosen) < size:
                nxt = int(np.argmax(dist))
                chosen.append(nxt)
                dist = np.minimum(dist, np.linalg.norm(flat - flat[nxt], axis=1))
            self.index = chosen

    @property
    def vertices(self) -> FloatArray:
        """The imposed vertices."""
        return self.all[self.index]

    def add_worst(self, margins: FloatArray, count: int = 4) -> bool:
        """Add up to ``count`` violated vertices not yet active; False when there are none."""
        order = [i for i in np.argsort(margins) if margins[i] < 0 and i not in self.index][:count]
        self.index.extend(int(i) for i in order)
        return bool(order)
