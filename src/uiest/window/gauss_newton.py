r"""Gauss-Newton SQP and real-time iteration for window problems (nonlinear least squares).

The window problem is ``min |r(z, p)|^2`` s.t. ``lbg <= g(z, p) <= ubg`` and ``lbx <= z <= ubx``
in scaled variables (see :mod:`uiest.window.problem`). Each Gauss-Newton iteration solves the
convex QP::

    min_dz  1/2 dz^T (H + lambda I) dz + (J^T r)^T dz
    s.t.    lbg - g <= G dz <= ubg - g,     lbx - z <= dz <= ubx - z,

with ``J = dr/dz``, ``G = dg/dz`` and ``H = J^T J``. After the merit has rejected a step along a curved
valley, or taken one only after poor corrections, the rest of the solve uses ``H = J^T J + S_+``, with
``S_+`` the residuals' and constraints' curvature that Gauss-Newton leaves out, convexified
(:class:`~uiest.window.curvature.BlockCurvature`, built when first needed).

Evaluation: :class:`~uiest.window.normal_terms.NormalTerms` evaluates a point (``|r|^2``, the violation of
``lbg <= g <= ubg``, ``J^T r``, ``J^T J``, ``g``, sparse ``G`` and the KKT stationarity measure; CasADi for the
model's terms through its buffer interface, one compiled pass for the products) into two sets of arrays that
take turns (current and trial point). The QP is solved by CasADi's
active-set solver ``qrqp``, its cost scaled so that its largest curvature is :data:`QP_SCALE`, with
positive curvatures too small for qrqp raised (:data:`FLAT_CURVATURE`). qrqp's active set starts as the
bounds and inequalities the starting point sits on, then as the previous iteration's, without the sides
qrqp holds at a zero multiplier that the cost pulls away from (:func:`_released`); a QP that fails from it
is solved again from an empty active set.

Globalisation: Levenberg-Marquardt damping ``lambda`` with a ratio test on the exact-penalty merit
``|r|^2 + nu |violation of g|_1`` (``nu`` from the QP multipliers, :data:`PENALTY_MARGIN`). A step is
accepted when the actual decrease is at least :data:`ACCEPT_RATIO` times the predicted one; ``lambda``
stays 0 while steps are good, grows after poor or rejected steps (:data:`DAMPING_GROWTH`,
:data:`DAMPING_ACCELERATION`; a rejected step keeps the linearisation) and shrinks back after good ones
(:data:`DAMPING_DECAY`). A full step that the merit rejects because the cost fell while the violation rose
(the Maratos effect) gets second-order corrections, the QP re-solved with the violation left at the trial
point, up to :data:`MAX_CORRECTIONS` times while each lowers the violation by :data:`SOC_CONTRACTION`; a
good correction (:data:`SOC_RATIO`), or else the last one if it passes :data:`LAST_CORRECTION_RATIO`, is
taken. Such a rejection, or a step saved only by poor corrections (:data:`CURVATURE_RATIO`), switches the
solve to ``H = J^T J + S_+`` before any damping. Solves whose steps are all accepted stay plain
Gauss-Newton.

Stopping, with the constraints satisfied to ``FEASIBILITY_TOL``: ``|dz|_inf <= step_tol`` (scaled
units); a predicted change of ``|r|^2`` below ``cost_tol (1 + |r|^2)`` in magnitude (accepted or not); or KKT
stationarity at the new point with the QP's multipliers below ``kkt_tol (1 + |lam_g|_inf)``; otherwise
``max_iter``. The first two count as convergence only for steps damped no more than the solve's least damping
(``min_damping``) or :data:`DAMPING_FLOOR`: a more damped step is small, and predicts little, by its damping. Such
a step below ``step_tol`` ends the solve as :data:`STALLED`, and so does one predicting no decrease at a feasible
point (elsewhere the solve goes on); a stall counts as a solution only where the point is feasible, as IPOPT's
near-success does.
The merit counts no violation below rounding (:data:`VIOLATION_FLOOR` per constraint), and at a point
feasible to that level a step that predicts no decrease of ``|r|^2`` ends the solve, unless it is damped
beyond :data:`DAMPING_FLOOR` or its QP released held sides (:func:`_released`).
RTI (``max_iter=1``) takes one full step from the warm start per sample: its estimate is the first
Gauss-Newton iterate from the shifted previous solution (exact for linear models, whose window problem
is a QP).

Failures: a QP that fails undamped (singular ``J^T J`` on the null space of the active constraints, or
NaN) is retried with the dampings :data:`RETRY_DAMPINGS` (times ``max|J^T J|``); the status then ends in
``"(regularised)"``, and the problem keeps the smallest of the first two dampings above the one that
failed as its least damping until :meth:`GaussNewtonSolver.reset`: the only state carried from one solve to
the next (each solve's own is a :class:`SolveState`). The parts: :class:`Damping`, :func:`_retry_damped`,
:func:`_corrected`, :func:`_stop_status` and :func:`_solve_qrqp`. If the damped QP fails too, or the
iterations do not converge, and ``fallback=True``, the sample is solved by IPOPT and the status says so.
Where the curvature Gauss-Newton leaves out is large and partly negative, ``J^T J + S_+`` (which drops
the negative part) converges only linearly.

The measurements behind each constant and safeguard are in the design notes: Gauss-Newton solver.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import casadi as ca
import numba
import numpy as np
from numpy.typing import NDArray

from uiest.box import FloatArray
from uiest.checks import all_finite, all_true, check_int, check_real
from uiest.errors import OptionError
from uiest.window.buffered import BufferedFunction
from uiest.window.curvature import BlockCurvature, IndexArray
from uiest.window.normal_terms import NormalTerms, Point
from uiest.window.polish import refine
from uiest.window.problem import WindowProblem
from uiest.window.solvers import FEASIBILITY_TOL, IpoptSolver, WindowSolution
from uiest.window.stage_qp import StageForm

__all__ = [
    "DAMPING_FLOOR",
    "QP_OPTIONS",
    "SINGULAR_DAMPING",
    "SOC_RATIO",
    "STALLED",
    "VIOLATION_FLOOR",
    "GaussNewtonSolver",
]

QP_OPTIONS: dict[str, Any] = {
    "print_iter": False,
    "print_header": False,
    "print_info": False,
    "error_on_fail": False,
    "max_iter": 200,
}
"""qrqp options; ``max_iter`` bounds one call (see :data:`QP_CONTINUATIONS`; a failed QP is retried damped, then
by IPOPT)."""

QP_SOLVERS = ("qrqp", "riccati")
"""The QP solvers :class:`GaussNewtonSolver` takes as ``qp``."""

QP_ITERATION_LIMIT = "Maximum number of iterations reached"
"""qrqp's status when ``max_iter`` stopped it."""

QP_CONTINUATIONS = 1
"""Further calls of ``max_iter`` qrqp iterations for a QP that the limit stopped, each from the active set the
last one reached (qrqp changes one bound per iteration; long windows need hundreds)."""

QP_SCALE = 1e6
"""The QP's cost is scaled so that its largest curvature (``max |J^T J|``) is this.

qrqp's tests are absolute: it takes a KKT matrix whose QR factor has a diagonal entry below
:data:`QRQP_SINGULAR` for singular, and holds a bound of such a direction at a zero multiplier."""

QRQP_SINGULAR = 1e-12
"""The smallest diagonal entry of the QR factor of the KKT matrix that qrqp does not take for singular (fixed in
CasADi's ``casadi_qp``)."""

FLAT_CURVATURE = 10.0 * QRQP_SINGULAR / QP_SCALE
"""A variable's own curvature (``J^T J``'s diagonal) that is positive but below this times the largest is raised to it.

Ten times what qrqp tells from zero in the scaled QP, so that qrqp moves such a variable as little as it can
instead of holding it on its box. Long windows have many of them: their weights fall as ``mu^k``. Structural
zeros (the UISE's unpenalised ``w``, fixed by the dynamics) are left alone."""

ACCEPT_RATIO = 1e-4
"""Smallest ratio of actual to predicted merit decrease for which a step is accepted."""

STALLED = "Stalled"
"""The status of a solve whose steps, damped beyond :data:`DAMPING_FLOOR`, became too small to move or to predict a
decrease worth having, with no stopping test passed at the point: no step improves it at the damping it needs.
Like IPOPT's ``Search_Direction_Becomes_Too_Small`` (:data:`~uiest.window.solvers.NEAR_SUCCESS_STATUSES`) it counts
as a solution where the point is feasible to :data:`~uiest.window.solvers.FEASIBILITY_TOL`, under its own name;
elsewhere IPOPT's fallback takes the sample."""

SOC_RATIO = 0.75
"""Ratio of actual to predicted merit decrease at which a second-order correction is taken at once (see
:meth:`GaussNewtonSolver._second_order_correction`); below it the next correction is tried, and the last one is
taken if it passes :data:`LAST_CORRECTION_RATIO`."""

MAX_CORRECTIONS = 4
"""Second-order corrections tried in a row on one step (IPOPT's ``max_soc``)."""

LAST_CORRECTION_RATIO = ACCEPT_RATIO
"""When no correction of a step reaches :data:`SOC_RATIO`, the last one is still taken if its ratio exceeds this
(the plain acceptance test), rather than damping the step."""

CURVATURE_RATIO = SOC_RATIO
"""A step saved by a correction whose ratio is at most this switches the solve to ``J^T J + S_+`` (as a rejected
step does)."""

SOC_CONTRACTION = 0.99
"""A further correction is tried only while each lowers the trial point's violation by this factor (IPOPT's
``kappa_soc``)."""

DAMPING_FLOOR = 1e-9
"""Levenberg-Marquardt damping after a poor or rejected step, relative to ``max |J^T J|`` (see
:data:`DAMPING_DECAY` for its way back)."""

DAMPING_DECAY = 10.0
"""After a rejected step, each good step (ratio above 0.75) divides the damping by this until it falls below
``SINGULAR_DAMPING max |J^T J|``, and then it returns to the solve's minimum (0, or the damping the problem keeps
after failed QPs): about six good steps from ``DAMPING_FLOOR``. Damping that a poor but accepted step left (no
rejection) returns at once from ``DAMPING_FLOOR``."""

DAMPING_GROWTH = 4.0
"""Factor by which a rejected step grows the damping (from at least ``DAMPING_FLOOR``) when it is the first
rejection in a row that damps."""

DAMPING_ACCELERATION = 2.0
"""Each further rejection in a row multiplies the damping's growth by this (Nielsen's rule, Madsen, Nielsen and
Tingleff 2004): from ``DAMPING_FLOOR`` the damping reaches ``max |J^T J|`` after 6 more rejections instead of 15."""

DAMPING_CAP = 1e10
"""Largest damping, relative to ``max |J^T J|``: far beyond any step the solve could still take (steps shrink
below ``step_tol``), and it keeps the damping finite when rejections go on."""

SINGULAR_DAMPING = 1e-14
"""Damping, relative to ``max |J^T J|``, tried first when an undamped QP fails (singular in double precision)."""

REGULARISED_DAMPING = 1e-5
"""Damping, relative to ``max |J^T J|``, tried when ``SINGULAR_DAMPING`` and ``DAMPING_FLOOR`` fail too (never kept)."""

RETRY_DAMPINGS = (SINGULAR_DAMPING, DAMPING_FLOOR, REGULARISED_DAMPING)
"""The dampings a failed QP is retried with, in order; the problem keeps each one but the last as
its least damping once it is tried."""

PENALTY_MARGIN = 2.0
"""The merit's penalty ``nu`` on the violation is this times the largest multiplier of ``|r|^2``
(``2 |lam_g|_inf``): above it, as an exact penalty must be, and in the cost's own units. Where all
multipliers are 0 the merit is the cost alone, and a step may raise the violation; the next step's
linearised constraints remove it."""

VIOLATION_FLOOR = 1e-14
"""Violation of one constraint (scaled units) that the merit counts as none: rounding in evaluating
``g = (f(x_i, ...) - x_{i+1}) / s_x`` (about 45 ulps of an O(1) scaled value)."""

RELEASE_GAIN = 1e-9
"""A side qrqp holds at a zero multiplier is released when leaving it could lower ``|r|^2`` by more than this
times ``1 + |r|^2`` (see :func:`_released`), a tenth of the 1e-8 (relative) to which optima are compared with
IPOPT's."""

ROUNDING = 64.0 * np.finfo(float).eps
"""Rounding of the QP's gradient ``H dz + q + A^T lam_a`` relative to the sum of its terms' magnitudes
(see :func:`_released`)."""

ACTIVE_TOL = 1e-12
"""Distance (scaled units) within which a value counts as sitting on its bound (qrqp warm start)."""


@numba.njit(cache=True)
def _on_bounds(value, lower_edge, upper_edge, ranged):  # pragma: no cover (compiled)
    """Initial multipliers for the first QP: ``+ACTIVE_TOL`` on an upper bound, ``-ACTIVE_TOL`` on a lower one.

    0 elsewhere and where ``ranged`` is False (an equality). ``lower_edge, upper_edge``: ``lower + ACTIVE_TOL``,
    ``upper - ACTIVE_TOL`` (:func:`_edges`).
    """
    marks = np.zeros(value.size)
    for i in range(value.size):
        if ranged[i]:
            if value[i] >= upper_edge[i]:
                marks[i] = ACTIVE_TOL
            elif value[i] <= lower_edge[i]:
                marks[i] = -ACTIVE_TOL
    return marks


@numba.njit(cache=True)
def _trial_point(z, dz, lower, upper, step_tol):  # pragma: no cover (compiled)
    """``(clip(z + dz, lower, upper), |dz|_inf <= step_tol)``; NaN stays NaN and is no small step."""
    trial = np.empty(z.size)
    small = True
    for i in range(z.size):
        t = z[i] + dz[i]
        if t < lower[i]:
            t = lower[i]
        elif t > upper[i]:
            t = upper[i]
        trial[i] = t
        if not abs(dz[i]) <= step_tol:
            small = False
    return trial, small


@numba.njit(cache=True)
def _largest_abs(values):  # pragma: no cover (compiled)
    """``|values|_inf`` (0 for none; NaN if one is, as NumPy's maximum)."""
    largest = 0.0
    for value in values:
        size = abs(value)
        if size > largest:
            largest = size
        elif size != size:
            return math.nan
    return largest


def _edges(lower: FloatArray, upper: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``(lower + ACTIVE_TOL, upper - ACTIVE_TOL)``: within them a value is on its bound (:func:`_on_bounds`)."""
    return lower + ACTIVE_TOL, upper - ACTIVE_TOL


class _QPForm(NamedTuple):
    """A QP's Hessian sparsity: qrqp, the QP's gradient at a solution with its rounding, the diagonal's positions.

    ``stage``: the QP in stage form for the Riccati interior point (``qp="riccati"``), else None. ``zeros``:
    qrqp's start when none is given (the primal point, the multipliers of the bounds and of the rows); ``unused``:
    its inputs ``q`` and ``p``.
    """

    qrqp: BufferedFunction
    gradient: BufferedFunction
    diagonal: IndexArray
    stage: StageForm | None
    zeros: tuple[FloatArray, FloatArray, FloatArray]
    unused: tuple[FloatArray, FloatArray]

    @classmethod
    def build(cls, h_sparsity: ca.Sparsity, a_sparsity: ca.Sparsity, staged: WindowProblem | None = None) -> _QPForm:
        """Qrqp, ``H dz + q + A^T lam_a`` with its rounding (:func:`_released`), ``staged``'s stage form if given."""
        qrqp = BufferedFunction(ca.conic("gn_qp", "qrqp", {"h": h_sparsity, "a": a_sparsity}, dict(QP_OPTIONS)))
        h, a = ca.SX.sym("h", h_sparsity), ca.SX.sym("a", a_sparsity)
        q, dz, lam = (
            ca.SX.sym("q", h_sparsity.size1()),
            ca.SX.sym("dz", h_sparsity.size1()),
            ca.SX.sym("lam", a_sparsity.size1()),
        )
        gradient = ca.mtimes(h, dz) + q + ca.mtimes(a.T, lam)
        magnitude = ca.mtimes(ca.fabs(h), ca.fabs(dz)) + ca.fabs(q) + ca.mtimes(ca.fabs(a).T, ca.fabs(lam))
        function = ca.Function("gn_qp_gradient", [h, q, a, dz, lam], [gradient, ROUNDING * magnitude])
        rows, cols = (np.asarray(index) for index in h_sparsity.get_triplet())
        stage = None if staged is None else StageForm(staged, h_sparsity, a_sparsity)
        n_var, n_con = h_sparsity.size1(), a_sparsity.size1()
        zeros = np.zeros(n_var), np.zeros(n_var), np.zeros(n_con)
        unused = np.zeros(0), np.zeros(0)
        return cls(qrqp, BufferedFunction(function), np.flatnonzero(rows == cols), stage, zeros, unused)


class _QPSolution(NamedTuple):
    """A QP's minimiser ``dz``, its cost and multipliers (``|r|^2 / 2`` units), and whether held sides were released."""

    dz: FloatArray
    cost: float
    lam_x: FloatArray
    lam_a: FloatArray
    released: bool


def _solve_qrqp(
    form: _QPForm,
    h: FloatArray,
    q: FloatArray,
    a: FloatArray,
    bounds: tuple[FloatArray, ...],
    start: tuple[FloatArray, FloatArray] | None,
    scale: float,
    release_tol: float,
) -> _QPSolution | None:
    """``min 1/2 dz^T H dz + q^T dz`` s.t. ``lba <= A dz <= uba``, ``lbx <= dz <= ubx`` by qrqp; None if it fails.

    Parameters
    ----------
    form : _QPForm
    h, a : ndarray
        The nonzeros of ``H`` and ``A`` in their sparsities' order; ``q`` (n_var,).
    bounds : (lba, uba, lbx, ubx)
    start : (lam_x, lam_a), optional
        Multipliers whose signs are the active set qrqp starts from (else none active).
    scale : float
        The cost is scaled by this for qrqp (:data:`QP_SCALE`); the results are in the unscaled QP's units.
    release_tol : float
        Sides qrqp holds at a zero multiplier are released (multiplier 0) where :func:`_released` says so.

    """
    c, qrqp = scale, form.qrqp
    x0, unused = form.zeros[0], form.unused
    lam_x0, lam_a0 = (c * start[0], c * start[1]) if start is not None else form.zeros[1:]
    # inputs h, g, a, lba, uba, lbx, ubx, x0, lam_x0, lam_a0, q, p; outputs x, cost, lam_a, lam_x
    x, cost, lam_a, lam_x = qrqp(c * h, c * q, a, *bounds, x0, lam_x0, lam_a0, *unused)
    stats = qrqp.stats()
    for _ in range(QP_CONTINUATIONS):
        if stats.get("return_status") != QP_ITERATION_LIMIT:
            break
        active_set = lam_x.copy(), lam_a.copy()  # on from the active set the limit stopped it at
        x, cost, lam_a, lam_x = qrqp(c * h, c * q, a, *bounds, x0, *active_set, *unused)
        stats = qrqp.stats()
    if not (stats.get("success", False) and np.all(np.isfinite(x))):
        return None
    lam_x, lam_a = lam_x / c, lam_a / c
    held = (np.abs(lam_x) * c <= np.finfo(float).tiny) & (lam_x != 0.0)  # qrqp's marks, +-DBL_MIN
    released = False
    if held.any():
        # the QP's gradient at its solution is -(the bounds' exact multipliers)
        gradient, rounding = form.gradient(h, q, a, x, lam_a)
        release = _released(held, lam_x, gradient, rounding, bounds[3] - bounds[2], release_tol)
        lam_x = np.where(release, 0.0, lam_x)
        released = bool(release.any())
    return _QPSolution(x.copy(), float(cost[0]) / c, lam_x, lam_a, released)


_Step = tuple[FloatArray, float]
"""A QP step ``dz`` and the decrease of ``|r|^2`` it predicts."""


def _released(
    held: NDArray[np.bool_], lam: FloatArray, gradient: FloatArray, rounding: FloatArray, width: FloatArray, tol: float
) -> NDArray[np.bool_]:
    """Which of the sides qrqp holds at a zero multiplier (``held``; ``lam`` > 0 upper, < 0 lower) to release.

    Those whose exact multiplier (``-gradient``, the QP's gradient at its solution) has the wrong
    sign (qrqp holds such sides while the error is within its dual tolerance) by more than its own
    rounding (``rounding``, see :data:`ROUNDING`),
    where leaving the side across the box (``width``) could lower ``|r|^2`` by more than ``tol``
    (``2 |gradient| width``: the QP is in ``|r|^2 / 2`` units). Only bounds: the marks of inequality
    rows (the two-stage UISE's output and node constraints) stay in the warm start.

    Kept in the next QP's warm start, such a side would hold its variable although the cost pulls it
    inwards; the rounding and size tests keep qrqp from releasing and re-taking flat sides one per
    iteration (design notes: Gauss-Newton solver).
    """
    wrong_sign = np.sign(lam) * gradient > 0.0
    relevant = (np.abs(gradient) > rounding) & (2.0 * np.abs(gradient) * np.minimum(width, 1e300) > tol)
    return held & wrong_sign & relevant


def _penalty(lam_max: float) -> float:
    """The merit's penalty on the violation, given the largest QP constraint multiplier (see :data:`PENALTY_MARGIN`)."""
    return PENALTY_MARGIN * 2.0 * lam_max  # |r|^2's multipliers are twice those of the QP's |r|^2 / 2


def _no_decrease_left(predicted: float, cost: float, cost_tol: float) -> bool:
    """The model's predicted change of ``|r|^2`` is below ``cost_tol (1 + cost)`` in magnitude.

    A negative prediction (a step that restores feasibility at a higher cost) is no sign of an optimum.
    """
    return abs(predicted) <= cost_tol * (1.0 + cost)


def _only_restores_rounding(predicted: float, point: Point) -> bool:
    """The step predicts no decrease of ``|r|^2`` from a point feasible to rounding (see :data:`VIOLATION_FLOOR`).

    All it would do is remove the rounding from the constraints, at the cost's expense: nothing is left to gain.
    The solve applies it to steps at its least damping only: a heavily damped step shrinks the descent
    part of the step but not the restoring part, and could predict no decrease short of an optimum.
    """
    return predicted <= 0.0 and point.violation == 0.0


def _ratio(point: Point, trial: Point, predicted: float, nu: float) -> float:
    """Actual over predicted decrease of the merit ``|r|^2 + nu |violation|_1`` from ``point`` to ``trial``.

    The QP step satisfies the linearised constraints: the model predicts the violation gone.
    """
    predicted_merit = predicted + nu * point.violation
    actual_merit = point.cost + nu * point.violation - trial.cost - nu * trial.violation
    return actual_merit / predicted_merit if predicted_merit > 0.0 else (1.0 if actual_merit >= 0 else -1.0)


class Damping:
    """The Levenberg-Marquardt damping of one solve and its update (see the module docstring).

    In absolute units: the relative constants (:data:`DAMPING_FLOOR`, ...) times ``scale``.

    Parameters
    ----------
    least : float
        The solve's least damping, relative to ``scale`` (``min_damping``, or the damping failed QPs left).
    scale : float
        ``max(max |J^T J|, 1)`` at the solve's starting point.

    Attributes
    ----------
    value : float
        The damping the next QP adds to its Hessian's diagonal (starts at the least).
    least : float
        The least damping (absolute); a regularised retry may raise it (:func:`_retry_damped`).
    growth : float
        The factor of the next rejection.
    distrusted : bool
        A step was rejected since ``value`` was last at ``least``.

    """

    def __init__(self, least: float, scale: float) -> None:
        self.scale = scale
        self.least = least * scale
        self.value = self.least
        self.growth = DAMPING_GROWTH
        self.distrusted = False

    @property
    def floor(self) -> float:
        """:data:`DAMPING_FLOOR` in absolute units: the least damping after a poor or rejected step."""
        return DAMPING_FLOOR * self.scale

    def accept(self, ratio: float) -> None:
        """Update after an accepted step whose actual decrease is ``ratio`` times the predicted one.

        Above 0.75 the damping falls (by :data:`DAMPING_DECAY` per step while distrusted, else at once from
        the floor or by 10); below 0.25 it grows fourfold (at least to the floor); in between it stays.
        """
        self.growth = DAMPING_GROWTH
        if ratio > 0.75:
            if self.distrusted:  # back to the least gradually (see DAMPING_DECAY)
                decayed = self.value / DAMPING_DECAY
                self.value = max(decayed, self.least) if decayed >= SINGULAR_DAMPING * self.scale else self.least
            else:
                self.value = self.least if self.value <= self.floor else max(self.value / 10.0, self.least)
            self.distrusted = self.distrusted and self.value > self.least
        elif ratio < 0.25:
            self.value = max(4.0 * self.value, self.floor)

    def reject(self) -> None:
        """Update after a rejected step: times ``growth`` (at least the floor, at most :data:`DAMPING_CAP`)."""
        self.value = min(max(self.growth * self.value, self.floor), DAMPING_CAP * self.scale)
        self.distrusted = True
        self.growth *= DAMPING_ACCELERATION


def _retry_damped(
    solve_qp: Callable[[float], _Step | None], damping: Damping, keep: bool
) -> tuple[_Step | None, float]:
    """A QP that failed solved again with the dampings :data:`RETRY_DAMPINGS` above ``damping.value``.

    Parameters
    ----------
    solve_qp : callable
        ``solve_qp(damping)``: the step with that (absolute) damping, None if its QP fails.
    damping : Damping
        Its value becomes the last damping tried; with ``keep``, its least rises to each one tried
        below :data:`REGULARISED_DAMPING`.
    keep : bool
        Whether the dampings tried are to be kept (False once the solve's QPs hold ``S_+``).

    Returns
    -------
    (step or None, kept)
        The first step whose QP solved, and the largest relative damping kept (0 if none).

    """
    kept = 0.0
    for relative in RETRY_DAMPINGS:
        if relative * damping.scale > damping.value:
            if keep and relative < REGULARISED_DAMPING:  # later ones start this damped
                kept = relative
                damping.least = max(damping.least, relative * damping.scale)
            damping.value = relative * damping.scale
            step = solve_qp(damping.value)
            if step is not None:
                return step, kept
    return None, kept


class _Correction(NamedTuple):
    """A second-order correction: its step, its evaluated point and its QP's multipliers ``(lam_x, lam_a)``."""

    dz: FloatArray
    point: Point
    multipliers: tuple[FloatArray, FloatArray]


def _corrected(
    correct: Callable[[FloatArray, Point], _Correction | None],
    ratio_of: Callable[[Point], float],
    dz: FloatArray,
    trial: Point,
) -> tuple[_Correction, float] | None:
    """The second-order correction to take for a rejected step ``dz`` (trial point ``trial``), with its ratio.

    Corrections are tried in a row, each of the last (``correct(dz, trial)``, None if its QP fails), up to
    :data:`MAX_CORRECTIONS` while none has a ratio (``ratio_of(point)``) above :data:`SOC_RATIO` and each lowers
    the violation by :data:`SOC_CONTRACTION`. The last one tried is taken if its ratio exceeds
    :data:`LAST_CORRECTION_RATIO`; None otherwise.
    """
    last = None
    for _ in range(MAX_CORRECTIONS):
        correction = correct(dz, trial)
        if correction is None:  # a failed QP evaluates nothing: the last correction's arrays stand
            break
        last = correction, ratio_of(correction.point)
        if last[1] > SOC_RATIO or correction.point.violation > SOC_CONTRACTION * trial.violation:
            break
        dz, trial = correction.dz, correction.point
    return last if last is not None and last[1] > LAST_CORRECTION_RATIO else None


def _stop_status(small_step: bool, no_decrease: bool, stationary: bool, worst: float, damped: bool) -> str | None:
    """The status that ends the solve after a step, or None to go on.

    Parameters
    ----------
    small_step : bool
        ``|dz|_inf <= step_tol``.
    no_decrease : bool
        The step predicts no decrease of ``|r|^2`` worth having (:func:`_no_decrease_left`).
    stationary : bool
        The point the solve now stands at is KKT-stationary (False after a rejected step).
    worst : float
        The largest violation of ``lbg <= g <= ubg`` where the solve stands.
    damped : bool
        The step was damped beyond the solve's least damping and :data:`DAMPING_FLOOR`: its size and predicted
        decrease are then the damping's, and prove nothing about the point.

    Returns
    -------
    str or None
        ``"Converged"`` (stationary, or an undamped step small or predicting no decrease, at a point feasible to
        :data:`~uiest.window.solvers.FEASIBILITY_TOL`), ``"Infeasible_Stationary_Point"`` (a small undamped step at
        an infeasible point), :data:`STALLED` (a damped step small, or predicting no decrease at a feasible point),
        or None.

    """
    feasible = worst <= FEASIBILITY_TOL
    if stationary and feasible:
        return "Converged"
    if not (small_step or no_decrease):
        return None
    if damped:
        return STALLED if small_step or feasible else None
    if feasible:
        return "Converged"
    return "Infeasible_Stationary_Point" if small_step else None


@dataclass
class SolveState:
    """The state of one :meth:`GaussNewtonSolver.solve`, built at its start and dropped at its end.

    Attributes
    ----------
    p : ndarray (n_par,)
        The window's parameters.
    point : Point
        The current iterate, evaluated.
    damping : Damping
    qp_scale : float
        The QP's cost scale (:data:`QP_SCALE` over ``max |J^T J|`` at the start).
    lam_x, lam_a : ndarray (n_var,), (n_con,)
        The last QP's multipliers (``|r|^2 / 2`` units); before the first QP, marks (``+-ACTIVE_TOL``) of the
        sides its active set starts with.
    warm : bool
        The next QP starts from ``lam_x, lam_a``.
    curved : bool
        The QPs hold the curvature ``S_+`` (since a rejected or poorly corrected step).
    hessian : (z, H) or None
        ``J^T J + S_+`` at ``z``, once computed there.
    released : bool
        The last QP released held sides (see :func:`_released`).
    regularised : bool
        A QP of this solve (or of an earlier one, see ``GaussNewtonSolver``) needed damping.
    iterations : int
    status : str

    """

    p: FloatArray
    point: Point
    damping: Damping
    qp_scale: float
    lam_x: FloatArray
    lam_a: FloatArray
    regularised: bool
    warm: bool = True
    curved: bool = False
    hessian: tuple[FloatArray, FloatArray] | None = None
    released: bool = False
    iterations: int = 0
    status: str = "Maximum_Iterations_Exceeded"


class GaussNewtonSolver:
    """Gauss-Newton SQP on a window problem, built once (see the module docstring).

    Parameters
    ----------
    problem : WindowProblem
        The window problem (scaled variables ``z``, parameters ``p``), built once.
    max_iter : int
        Iterations per solve (1: real-time iteration). Where the residuals' curvature is large
        (noisy windows), Gauss-Newton converges linearly.
    step_tol : float
        Convergence tolerance on ``|dz|_inf`` in scaled units, for a step damped no more than the solve's least
        damping or :data:`DAMPING_FLOOR`.
    cost_tol : float
        Also converged when the step (damped no more than for ``step_tol``) predicts a change of ``|r|^2`` below
        ``cost_tol (1 + |r|^2)`` in magnitude (flat, weakly observable directions move without changing the cost).
        A more damped step predicting that little ends the solve as :data:`STALLED` at a feasible point.
    fallback : bool
        Solve the sample with IPOPT (from the same starting point) when Gauss-Newton does not
        converge: both the plain and the damped QP fail, ``max_iter`` is reached, the iterate
        is an infeasible stationary point, or the solve stalls at an infeasible point. The solution then has
        ``fallback=True``, IPOPT's status and ``primary_status = "gn <why>"``.
    min_damping : float
        Levenberg-Marquardt damping kept at every step, relative to ``max |J^T J|`` (default 0:
        exact Gauss-Newton steps; > 0 keeps the QP strictly convex when inputs are unpenalised,
        at the price of slow progress in directions flatter than the damping).
    kkt_tol : float
        Also converged when the KKT stationarity test of :meth:`_stationary` holds (and the
        constraints hold to ``FEASIBILITY_TOL``).
    polish : bool
        Refine every converged solution with :func:`uiest.window.polish.refine` (orthogonal
        factorisations of ``J`` instead of the normal equations ``J^T J``, whose condition
        number is ``cond(J)^2``): in directions the data barely determine, Gauss-Newton stops
        where the cost no longer changes at double precision.
    qp : {"qrqp", "riccati"}
        The QP solver: CasADi's active-set ``qrqp``, or the stage-wise interior point of
        :mod:`uiest.window.riccati_qp` (:class:`~uiest.window.stage_qp.StageForm`), with qrqp for any QP it
        does not solve (counted in :attr:`qp_fallbacks`).

    Attributes
    ----------
    qp_fallbacks : int
        QPs the Riccati interior point did not solve and qrqp was given, since construction or :meth:`reset`.

    Notes
    -----
    Each solve builds its own :class:`SolveState`. Between solves the solver keeps only the least damping that
    failed QPs left (``_kept_damping``, relative to ``max |J^T J|``; forgotten by :meth:`reset`), so that later
    samples do not fail the same singular QP again. The measurements behind the defaults are in the design
    notes: Gauss-Newton solver.

    """

    def __init__(
        self,
        problem: WindowProblem,
        *,
        max_iter: int = 30,
        step_tol: float = 1e-10,
        cost_tol: float = 1e-12,
        fallback: bool = True,
        min_damping: float = 0.0,
        kkt_tol: float = 1e-10,
        polish: bool = False,
        qp: str = "qrqp",
    ) -> None:
        self.problem = problem
        if qp not in QP_SOLVERS:
            raise OptionError(f"solver_options: qp: expected one of {list(QP_SOLVERS)}, got {qp!r}")
        self.qp = qp
        self.qp_fallbacks = 0
        self.max_iter = check_int(max_iter, "solver_options: max_iter", low=1)
        tolerances = {"step_tol": step_tol, "cost_tol": cost_tol, "min_damping": min_damping, "kkt_tol": kkt_tol}
        for name, value in tolerances.items():
            number = check_real(value, f"solver_options: {name}", "a finite number >= 0")
            if not (math.isfinite(number) and number >= 0.0):
                raise OptionError(f"solver_options: {name}: expected a finite number >= 0, got {value!r}")
        self.step_tol, self.cost_tol, self.min_damping, self.kkt_tol = (float(v) for v in tolerances.values())
        for name, value in (("fallback", fallback), ("polish", polish)):
            if not isinstance(value, bool | np.bool_):
                raise OptionError(f"solver_options: {name}: expected True or False, got {value!r}")
        self.fallback = bool(fallback)
        self.polish = bool(polish)
        self._terms = NormalTerms(problem, flat_curvature=FLAT_CURVATURE, violation_floor=VIOLATION_FLOOR)
        self._h_sparsity, self._a_sparsity = self._terms.h_sparsity, self._terms.a_sparsity
        self._a_rows, self._a_cols = (np.asarray(index, dtype=np.int64) for index in self._a_sparsity.get_triplet())
        self._no_multipliers = np.zeros(problem.n_con)
        # the first QP's active set: the bounds and the inequalities (not the equalities) the start sits on
        self._x_edges = (*_edges(problem.lbx, problem.ubx), np.ones(problem.n_var, dtype=np.bool_))
        self._g_edges = (*_edges(problem.lbg, problem.ubg), problem.lbg < problem.ubg)
        self._staged = problem if qp == "riccati" else None
        self._gauss_newton_form = _QPForm.build(self._h_sparsity, self._a_sparsity, self._staged)
        # the curvature Gauss-Newton leaves out and the QP form that holds it, built when first needed
        self._curvature: tuple[BlockCurvature, _QPForm] | None = None
        self._ipopt: IpoptSolver | None = None
        self._kept_damping = 0.0  # least damping (relative) after failed QPs, carried from solve to solve
        self._state: SolveState | None = None  # the running (or last) solve's state

    def reset(self) -> None:
        """Forget the least damping that failed QPs left (kept from solve to solve, see the module docstring)."""
        self._kept_damping = 0.0
        self.qp_fallbacks = 0

    @property
    def _curved(self) -> bool:
        """The running solve's QPs hold the curvature ``S_+``."""
        return self._state is not None and self._state.curved

    # ------------------------------------------------------------------ evaluations
    def _evaluate(
        self, z: FloatArray, p: FloatArray, keep: Point | None = None, lam_g: FloatArray | None = None
    ) -> Point:
        """The point ``z``, with the stationarity measure for the constraint multipliers ``lam_g`` (default 0).

        Evaluated into the buffer that ``keep`` (a point still in use) does not occupy; the
        arrays of the returned point are overwritten by the evaluation after next.
        """
        slot = 1 - keep.slot if keep is not None else 0
        lam = self._no_multipliers if lam_g is None else lam_g
        return self._terms(slot, z, p, lam)

    def _stationary(self, point: Point, lam_a: FloatArray, largest: float | None = None) -> bool:
        """KKT stationarity at ``point`` with the constraint multipliers ``lam_a`` it was evaluated with.

        ``s = J^T r + G^T lam_g`` must vanish at free variables and point outwards at active
        bounds (where the bound's multiplier takes it); the test is
        ``|s|_inf <= kkt_tol (1 + |lam_g|_inf)``. After a full Gauss-Newton step the multipliers
        of the QP are those of the window problem to second order, so this stops without
        solving one more QP to see a zero step. ``largest``: ``|lam_a|_inf`` if the caller has it.
        """
        if largest is None:
            largest = _largest_abs(lam_a)
        return point.stationarity <= self.kkt_tol * (1.0 + largest)

    # ------------------------------------------------------------------ QP
    def _qp(
        self, form: _QPForm, h: FloatArray, point: Point, warm: bool, release_tol: float
    ) -> tuple[FloatArray, float, FloatArray, FloatArray] | None:
        """``(dz, QP cost, lam_x, lam_a)`` of the QP at ``point`` with Hessian ``h`` (cost of ``|r|^2`` units), or None.

        By the form's stage-wise interior point if it has one, else (or if that fails) by qrqp
        (:func:`_solve_qrqp`). ``warm``: start from the running solve's multipliers.
        """
        state, prob = self._state, self.problem
        assert state is not None
        c, start = state.qp_scale, (state.lam_x, state.lam_a) if warm else None
        q, a, g, z = point.q, point.a, point.g, point.z
        if form.stage is not None:
            staged = form.stage.solve(h, q, a, (prob.lbg, prob.ubg, prob.lbx, prob.ubx), start, scale=c, at=(g, z))
            if staged is not None:
                state.released = False
                return staged
            self.qp_fallbacks += 1
        bounds = (prob.lbg - g, prob.ubg - g, prob.lbx - z, prob.ubx - z)
        solved = _solve_qrqp(form, h, q, a, bounds, start, c, release_tol)
        if solved is None:
            return None
        state.released = solved.released
        return solved.dz, solved.cost, solved.lam_x, solved.lam_a

    def _model(self, point: Point) -> tuple[_QPForm, FloatArray]:
        """The QP's form and Hessian at ``point``: ``J^T J``, or once the solve is curved ``J^T J + S_+``.

        ``S_+`` takes the multipliers at hand when the first curved QP at the point is set up (those of the
        step the merit rejected there, or of the QP whose step led to the point), so the corrections and damped
        retries that follow solve QPs with the same Hessian.
        """
        state = self._state
        assert state is not None
        if not state.curved:
            return self._gauss_newton_form, point.h
        assert self._curvature is not None
        curvature, form = self._curvature
        if state.hessian is None or state.hessian[0] is not point.z:
            state.hessian = point.z, curvature(point.z, state.p, state.lam_a, point.h)
        return form, state.hessian[1]

    def _curve(self) -> bool:
        """Switch the running solve to QPs with the curvature Gauss-Newton leaves out; False if the model has none."""
        if self._curvature is None:
            curvature = BlockCurvature(self.problem, self._h_sparsity)
            form = _QPForm.build(curvature.sparsity, self._a_sparsity, self._staged)
            self._curvature = curvature, form
        curved = self._curvature[0].curved
        if self._state is not None:
            self._state.curved = curved
        return curved

    def _step(self, point: Point, damping: float, warm: bool) -> _Step | None:
        """The QP step ``dz`` with ``damping`` added to the model's Hessian, and the decrease of ``|r|^2`` it predicts.

        ``warm``: the QP starts from the running solve's multipliers, and from scratch if that fails; they
        become the QP's. None if the QP fails.
        """
        state = self._state
        assert state is not None
        form, h = self._model(point)
        if damping:
            h = h.copy()
            h[form.diagonal] += damping
        release_tol = RELEASE_GAIN * (1.0 + point.cost)
        solved = (warm and self._qp(form, h, point, True, release_tol)) or self._qp(form, h, point, False, release_tol)
        if not solved:
            return None
        dz, model, state.lam_x, state.lam_a = solved
        # decrease of |r|^2 predicted by the undamped model (H = J^T J, or J^T J + S_+), -2 (q^T dz + dz^T H dz / 2),
        # from the QP's cost q^T dz + dz^T (H + damping I) dz / 2 (Python floats overflow to inf without a warning)
        if damping:
            with np.errstate(over="ignore", invalid="ignore"):
                predicted = -2.0 * (model - 0.5 * damping * float(dz @ dz))
        else:
            predicted = -2.0 * model
        # a step whose square overflows has no model decrease: treated as a failed QP (damped retries follow)
        return (dz, predicted) if math.isfinite(predicted) else None

    def _second_order_correction(
        self, point: Point, trial: Point, dz: FloatArray, damping: float, p: FloatArray
    ) -> _Correction | None:
        """The step re-solved with the constraints' curvature seen at the rejected trial point.

        A full step along a direction the cost barely sees can be long, and the constraints'
        curvature then leaves the trial point infeasible, so the merit rejects it (Maratos
        effect): damped steps follow, then the full step again, and the iteration crawls. The
        correction solves the same QP (same Hessian and damping) with ``G dz' = -(g(z + dz) - G dz)``,
        i.e. the linearised constraints shifted by what the step left violated. None if that QP fails.
        """
        state = self._state
        assert state is not None
        g_dz = np.bincount(self._a_rows, weights=point.a * dz[self._a_cols], minlength=self.problem.n_con)
        step = self._step(point._replace(g=trial.g - g_dz), damping, warm=True)
        if step is None:
            return None
        corrected = step[0]
        z = (point.z + corrected).clip(self.problem.lbx, self.problem.ubx)
        return _Correction(corrected, self._evaluate(z, p, point, state.lam_a), (state.lam_x, state.lam_a))

    # ------------------------------------------------------------------ the solve
    def solve(
        self,
        z0: FloatArray,
        p: FloatArray,
        lam_x0: FloatArray | None = None,
        lam_g0: FloatArray | None = None,
    ) -> WindowSolution:
        """Gauss-Newton iterations from ``z0`` (clipped into the bounds).

        Parameters
        ----------
        z0 : numpy.ndarray
            Starting point, shape (n_var,), scaled variables.
        p : numpy.ndarray
            The window's parameters (data, prior, weights), shape (n_par,).
        lam_x0, lam_g0 : None
            Not taken (:class:`~uiest.errors.OptionError` otherwise): the first QP starts from the sides ``z0``
            is on (see :data:`~uiest.window.backends.MULTIPLIER_BACKENDS`).

        Returns
        -------
        WindowSolution
            The solution, its status, iterations and solve time; ``fallback=True`` when IPOPT solved it.

        """
        start = time.perf_counter()
        for name, multipliers in (("lam_x0", lam_x0), ("lam_g0", lam_g0)):
            if multipliers is not None:
                raise OptionError(
                    f"{name}: expected None; the Gauss-Newton backend takes no multipliers (its first QP starts "
                    "from the sides z0 is on)"
                )
        state = self._state = self._start(z0, p)
        for state.iterations in range(1, self.max_iter + 1):
            if self._iterate(state):
                break
        return self._finish(state, z0, start)

    def _start(self, z0: FloatArray, p: FloatArray) -> SolveState:
        """A solve's state at ``z0`` (clipped into the bounds): the first QP's active set is the sides ``z0`` is on."""
        prob = self.problem
        p = np.asarray(p, dtype=float)
        point = self._evaluate(np.asarray(z0, dtype=float).clip(prob.lbx, prob.ubx), p)
        largest = _largest_abs(point.h)
        damping = Damping(max(self.min_damping, self._kept_damping), max(largest, 1.0))
        lam_x = _on_bounds(point.z, *self._x_edges)
        lam_a = _on_bounds(point.g, *self._g_edges)
        return SolveState(p, point, damping, QP_SCALE / (largest or 1.0), lam_x, lam_a, self._kept_damping > 0.0)

    def _iterate(self, state: SolveState) -> bool:
        """One Gauss-Newton iteration: a QP step, its corrections, acceptance and the damping; True to stop."""
        point, damping = state.point, state.damping
        step = self._step(point, damping.value, state.warm)
        if step is None and damping.value <= damping.least:  # a singular or failed QP: Levenberg-Marquardt steps
            step = self._regularised_step(state)
        if step is None:
            state.status = "QP_failed"
            return True
        dz, predicted = step
        state.warm = True
        # damped beyond the solve's least damping (min_damping, kept after failed QPs) and the floor, a step is small
        # by its damping (see _stop_status)
        undamped = damping.value <= max(damping.floor, damping.least)
        at_least_damping = undamped and not state.released and self.max_iter > 1
        if at_least_damping and _only_restores_rounding(predicted, point):
            state.status = "Converged"
            return True
        lam_a, largest = state.lam_a, _largest_abs(state.lam_a)
        nu = _penalty(largest)
        z_trial, small_step = _trial_point(point.z, dz, self.problem.lbx, self.problem.ubx, self.step_tol)
        trial = self._evaluate(z_trial, state.p, point, state.lam_a)
        ratio = _ratio(point, trial, predicted, nu)
        maratos = trial.cost < point.cost and trial.violation > point.violation  # the cost fell, the violation rose
        if ratio <= ACCEPT_RATIO and maratos and self.max_iter > 1:
            dz, trial, ratio = self._correct(state, dz, trial, predicted, nu)
            small_step = all_true(np.abs(dz) <= self.step_tol)
        no_decrease = _no_decrease_left(predicted, point.cost, self.cost_tol)
        if ratio > ACCEPT_RATIO or self.max_iter == 1:
            state.point = trial
            damping.accept(ratio)
            stationary = self._stationary(trial, state.lam_a, largest if state.lam_a is lam_a else None)
            status = _stop_status(small_step, no_decrease, stationary, trial.worst, damped=not undamped)
        else:  # rejected: the curvature, then damp more; same linearisation
            # the model predicts no decrease of |r|^2 worth having: stop as when accepted (the merit may still have
            # failed to remove a violation; _stop_status then asks feasibility to FEASIBILITY_TOL)
            no_decrease = no_decrease and not state.released
            status = _stop_status(small_step, no_decrease, False, point.worst, damped=not undamped)
            if status is None and (state.curved or not (maratos and self._curve())):
                damping.reject()
        if status is None:
            return False
        state.status = status
        return True

    def _regularised_step(self, state: SolveState) -> _Step | None:
        """The step of a QP that failed undamped, retried damped (:func:`_retry_damped`).

        The dampings below :data:`REGULARISED_DAMPING` tried are kept for later solves unless the QPs hold ``S_+``.
        """
        tried = state.damping.value
        step, kept = _retry_damped(lambda damping: self._step(state.point, damping, False), state.damping,
                                   not state.curved)  # fmt: skip
        state.regularised = state.regularised or state.damping.value != tried
        self._kept_damping = max(self._kept_damping, kept)
        return step

    def _correct(
        self, state: SolveState, dz: FloatArray, trial: Point, predicted: float, nu: float
    ) -> tuple[FloatArray, Point, float]:
        """A rejected step's second-order correction if one is taken (:func:`_corrected`), else the step itself.

        Returns the step, its point and its ratio; a taken correction's multipliers become the solve's, and one
        that was not good (:data:`CURVATURE_RATIO`) switches the solve to ``S_+``.
        """
        point, damping = state.point, state.damping.value
        multipliers, released = (state.lam_x, state.lam_a), state.released  # the step's, unless a correction is taken
        taken = _corrected(
            lambda step, at: self._second_order_correction(point, at, step, damping, state.p),
            lambda corrected: _ratio(point, corrected, predicted, nu),
            dz,
            trial,
        )
        if taken is None:
            (state.lam_x, state.lam_a), state.released = multipliers, released
            return dz, trial, _ratio(point, trial, predicted, nu)
        correction, ratio = taken
        state.lam_x, state.lam_a = correction.multipliers
        if ratio <= CURVATURE_RATIO:  # the model misses the constraints' curvature
            self._curve()
        return correction.dz, correction.point, ratio

    def _finish(self, state: SolveState, z0: FloatArray, start: float) -> WindowSolution:
        """The solution at the solve's last point: RTI's status, polishing, IPOPT's fallback if not converged."""
        status, point = state.status, state.point
        # a stall at a feasible point is usable, as IPOPT's Search_Direction_Becomes_Too_Small is (its status says so)
        converged = status == "Converged" or (status == STALLED and point.worst <= FEASIBILITY_TOL)
        if self.max_iter == 1 and status != "QP_failed":
            # one step of the linearised problem: not feasible to FEASIBILITY_TOL by design
            status, converged = "RTI_Step", bool(np.isfinite(point.z).all())
        if state.regularised and converged:
            status += " (regularised)"
        z, cost = point.z, point.cost
        if converged and self.polish and self.max_iter > 1:
            z, cost, _ = refine(self.problem, z, state.p)
        elapsed = time.perf_counter() - start
        if not converged and self.fallback:
            return self._fallback(z0, state.p, f"gn {status}", state.iterations, elapsed)
        return WindowSolution(
            z=z,
            lam_x=state.lam_x.copy(),
            lam_g=state.lam_a.copy(),
            cost=cost,
            status=status,
            success=bool(converged and all_finite(z)),
            iterations=state.iterations,
            solve_time=elapsed,
        )

    def _fallback(self, z0: FloatArray, p: FloatArray, why: str, iterations: int, elapsed: float) -> WindowSolution:
        """IPOPT's solution from ``z0``, with the Gauss-Newton iterations and time before it and ``why``."""
        if self._ipopt is None:
            self._ipopt = IpoptSolver(self.problem, polish=self.polish)
        fallback = self._ipopt.solve(z0, p)
        return WindowSolution(
            fallback.z,
            fallback.lam_x,
            fallback.lam_g,
            fallback.cost,
            fallback.status,
            fallback.success,
            iterations + fallback.iterations,
            elapsed + fallback.solve_time,
            fallback=True,
            primary_status=why,
        )
