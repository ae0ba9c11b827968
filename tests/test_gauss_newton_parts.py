"""The Gauss-Newton solver's parts in isolation: QP, damping, retries, corrections, stopping tests, state."""

import runpy
from pathlib import Path
from typing import NamedTuple

import casadi as ca
import numpy as np
import pytest

from uiest import simulate
from uiest.errors import OptionError
from uiest.estimators import UISE, UISEWeights
from uiest.models import get
from uiest.window import gauss_newton
from uiest.window.gauss_newton import (
    DAMPING_CAP,
    DAMPING_FLOOR,
    REGULARISED_DAMPING,
    SINGULAR_DAMPING,
    Damping,
    GaussNewtonSolver,
    _corrected,
    _Correction,
    _QPForm,
    _retry_damped,
    _solve_qrqp,
    _stop_status,
)
from uiest.window.problem import WindowTrajectory

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


# ------------------------------------------------------------------ the QP
def _two_variable_qp():
    """``min x0^2 + x1^2 / 2 - 2 x0 - 2 x1`` s.t. ``-10 <= x0 - x1 <= 10``, ``-5 <= x <= (5, 0.5)``.

    Unconstrained minimum (1, 2); the bound ``x1 <= 0.5`` is active: ``x = (1, 0.5)``, cost ``-1.875``, its
    multiplier ``2 - 0.5 = 1.5`` (upper: positive), the row's 0.
    """
    form = _QPForm.build(ca.Sparsity.diag(2), ca.Sparsity.dense(1, 2))
    h, q, a = np.array([2.0, 1.0]), np.array([-2.0, -2.0]), np.array([1.0, -1.0])
    bounds = (np.array([-10.0]), np.array([10.0]), np.array([-5.0, -5.0]), np.array([5.0, 0.5]))
    return form, h, q, a, bounds


@pytest.mark.parametrize("scale", [1.0, 1e6])
@pytest.mark.parametrize("start", [None, "active", "wrong"])
def test_qrqp_solves_a_two_variable_qp_with_one_active_bound(scale, start):
    form, h, q, a, bounds = _two_variable_qp()
    guesses = {
        None: None,
        "active": (np.array([0.0, 1e-12]), np.zeros(1)),
        "wrong": (np.array([-1e-12, 0.0]), np.zeros(1)),  # x0 on its lower bound: dropped, x1 taken
    }
    solved = _solve_qrqp(form, h, q, a, bounds, guesses[start], scale, release_tol=1e-9)
    assert solved is not None and not solved.released
    np.testing.assert_allclose(solved.dz, [1.0, 0.5], rtol=0, atol=1e-12)
    assert solved.cost == pytest.approx(-1.875, rel=1e-12)
    np.testing.assert_allclose(solved.lam_x, [0.0, 1.5], rtol=0, atol=1e-12)
    np.testing.assert_allclose(solved.lam_a, [0.0], rtol=0, atol=1e-12)
    # the start is qrqp's first active set: the right one takes one iteration, a wrong one more than none
    assert form.qrqp.stats()["iter_count"] == {None: 2, "active": 1, "wrong": 3}[start]


def test_an_infeasible_qp_is_reported_as_failed():
    form, h, q, a, bounds = _two_variable_qp()  # x0 - x1 >= 20 with x0 <= 5, x1 >= -5
    assert _solve_qrqp(form, h, q, a, (np.array([20.0]), np.array([30.0]), *bounds[2:]), None, 1.0, 1e-9) is None


# ------------------------------------------------------------------ the damping
SCALE = 10.0
FLOOR = DAMPING_FLOOR * SCALE

DAMPING_TABLE = {
    # from the least (0), steps taken in turn -> the damping after each
    "good steps keep it at 0": [("accept", 0.9, 0.0), ("accept", 0.5, 0.0)],
    "a poor step raises it to the floor, a good one returns at once": [
        ("accept", 0.1, FLOOR),
        ("accept", 0.1, 4 * FLOOR),
        ("accept", 0.5, 4 * FLOOR),
        ("accept", 0.9, 0.4 * FLOOR),
        ("accept", 0.9, 0.0),
    ],
    "rejections grow it 4, 8, 16 times": [
        ("reject", None, FLOOR),
        ("reject", None, 8 * FLOOR),
        ("reject", None, 128 * FLOOR),
        ("accept", 0.9, 12.8 * FLOOR),  # distrusted: back by DAMPING_DECAY per good step
        ("reject", None, 51.2 * FLOOR),  # an accepted step restarts the growth at 4
    ],
    "after a rejection it returns gradually, to the least below SINGULAR_DAMPING": [
        ("reject", None, FLOOR),
        *[("accept", 0.9, FLOOR * 10.0**-k) for k in range(1, 6)],
        ("accept", 0.9, 0.0),  # 1e-15 < SINGULAR_DAMPING
        ("accept", 0.9, 0.0),
    ],
}


@pytest.mark.parametrize("name", list(DAMPING_TABLE))
def test_the_damping_follows_its_table(name):
    damping = Damping(0.0, SCALE)
    for action, ratio, expected in DAMPING_TABLE[name]:
        damping.accept(ratio) if action == "accept" else damping.reject()
        assert damping.value == pytest.approx(expected, rel=1e-12, abs=1e-300), (action, ratio)


def test_the_damping_stays_at_or_above_its_least_and_below_its_cap():
    damping = Damping(1e-6, SCALE)
    assert damping.value == damping.least == 1e-6 * SCALE
    damping.reject()
    assert damping.value == 4e-6 * SCALE
    for _ in range(8):
        damping.accept(0.9)
    assert damping.value == damping.least and not damping.distrusted
    for _ in range(60):
        damping.reject()
    assert damping.value == DAMPING_CAP * SCALE


# ------------------------------------------------------------------ the regularised retry
def _failing_below(threshold: float, tried: list[float]):
    def solve_qp(damping: float):
        tried.append(damping / SCALE)
        return (np.zeros(1), 1.0) if damping >= threshold * SCALE else None

    return solve_qp


@pytest.mark.parametrize(
    ("threshold", "keep", "tried", "kept", "solved"),
    [
        (SINGULAR_DAMPING, True, [SINGULAR_DAMPING], SINGULAR_DAMPING, True),
        (DAMPING_FLOOR, True, [SINGULAR_DAMPING, DAMPING_FLOOR], DAMPING_FLOOR, True),
        (REGULARISED_DAMPING, True, [SINGULAR_DAMPING, DAMPING_FLOOR, REGULARISED_DAMPING], DAMPING_FLOOR, True),
        (1.0, True, [SINGULAR_DAMPING, DAMPING_FLOOR, REGULARISED_DAMPING], DAMPING_FLOOR, False),
        (DAMPING_FLOOR, False, [SINGULAR_DAMPING, DAMPING_FLOOR], 0.0, True),
    ],
)
def test_a_failed_qp_is_retried_at_growing_dampings_and_the_small_ones_are_kept(threshold, keep, tried, kept, solved):
    damping, calls = Damping(0.0, SCALE), []
    step, kept_damping = _retry_damped(_failing_below(threshold, calls), damping, keep)
    assert calls == pytest.approx(tried, rel=1e-12) and kept_damping == kept and (step is not None) == solved
    assert damping.value == pytest.approx(tried[-1] * SCALE, rel=1e-12)
    assert damping.least == pytest.approx(kept * SCALE, rel=1e-12)


def test_the_retry_starts_above_the_damping_that_failed():
    damping, calls = Damping(DAMPING_FLOOR, SCALE), []
    _retry_damped(_failing_below(1.0, calls), damping, True)
    assert calls == pytest.approx([REGULARISED_DAMPING], rel=1e-12) and damping.least == FLOOR


# ------------------------------------------------------------------ the corrections' sequence
class _Trial(NamedTuple):
    ratio: float
    violation: float


def _corrections(trials):
    """``_corrected`` on corrections whose points carry their ratios; which one it took and how many it tried."""
    queue, calls = list(trials), []

    def correct(dz, trial):
        calls.append(trial)
        point = queue.pop(0)
        return None if point is None else _Correction(dz + 1.0, point, (np.zeros(1), np.zeros(0)))

    taken = _corrected(correct, lambda point: point.ratio, np.zeros(1), _Trial(-1.0, 1.0))
    return (None if taken is None else taken[0].point), len(calls)


@pytest.mark.parametrize(
    ("trials", "taken", "tried"),
    [
        ([_Trial(0.9, 0.5)], 0, 1),  # good at once
        ([_Trial(0.3, 0.5), _Trial(0.5, 0.2), _Trial(0.6, 0.1), _Trial(0.7, 0.05)], 3, 4),  # the last one
        ([_Trial(0.3, 0.5), _Trial(0.8, 0.2)], 1, 2),
        ([_Trial(0.3, 0.995)], 0, 1),  # no contraction: no further correction, the last is taken
        ([_Trial(1e-5, 0.5), _Trial(1e-5, 0.4), _Trial(1e-5, 0.3), _Trial(1e-5, 0.2)], None, 4),  # none passes
        ([None], None, 1),  # its QP failed
        ([_Trial(0.3, 0.5), None], 0, 2),  # the second's QP failed: the first is the last one
    ],
)
def test_second_order_corrections_are_tried_in_a_row_and_the_right_one_is_taken(trials, taken, tried):
    point, calls = _corrections(trials)
    assert calls == tried
    assert point == (None if taken is None else trials[taken])


# ------------------------------------------------------------------ the stopping tests
@pytest.mark.parametrize(
    ("small_step", "no_decrease", "stationary", "worst", "damped", "status"),
    [
        (False, False, False, 0.0, False, None),
        (True, False, False, 0.0, False, "Converged"),
        (False, True, False, 1e-9, False, "Converged"),
        (False, False, True, 1e-9, True, "Converged"),  # a direct test of the point: any damping
        (False, True, False, 1e-7, False, None),  # infeasible: go on
        (False, False, True, 1e-7, False, None),
        (True, False, False, 1e-7, False, "Infeasible_Stationary_Point"),
        (True, True, False, 1e-7, False, "Infeasible_Stationary_Point"),
        (True, False, False, 0.0, True, "Stalled"),  # small by its damping: not converged
        (False, True, False, 0.0, True, "Stalled"),
        (True, False, False, 1e-7, True, "Stalled"),
        (False, True, False, 1e-7, True, None),
    ],
)
def test_the_stopping_rule(small_step, no_decrease, stationary, worst, damped, status):
    assert _stop_status(small_step, no_decrease, stationary, worst, damped) == status


# ------------------------------------------------------------------ a tiny window with a known optimum
@pytest.fixture(scope="module")
def henon_window():
    """A noise-free Henon map's UISE window (N = 3; quadratic dynamics: curved constraints) and its truth, where
    the cost is 0: a global minimiser, KKT-stationary with zero multipliers."""
    example = runpy.run_path(str(EXAMPLES / "chaotic_message.py"))
    system = example["build"]()
    traj = simulate(system, [0.1, 0.1], 3, w=example["message"](3))
    estimator = UISE(system, weights=UISEWeights.from_scales(system, 0.6), N=3, x0_prior=traj.x[0], solver="gn")
    problem = estimator._cached(3).problem
    p = problem.parameters(traj.x[0], np.zeros((3, system.nu)), traj.y[: problem.n_meas])
    truth = problem.pack(WindowTrajectory(traj.x, traj.w, np.zeros((problem.n_meas, system.nv))))
    return problem, p, truth


def test_the_truth_of_a_noise_free_window_is_a_stationary_point(henon_window):
    problem, p, truth = henon_window
    solver = GaussNewtonSolver(problem)
    point = solver._evaluate(truth, p)
    assert point.cost < 1e-20 and point.worst < 1e-14
    assert solver._stationary(point, np.zeros(problem.n_con))
    off = solver._evaluate(truth + 1e-3, p)
    assert not solver._stationary(off, np.zeros(problem.n_con))
    solution = solver.solve(truth + 1e-2, p)
    assert solution.status == "Converged" and solution.cost < 1e-20
    np.testing.assert_allclose(solution.z, truth, rtol=0, atol=1e-8)


def test_a_rejected_step_ends_the_solve_only_on_a_test_it_passes(henon_window, monkeypatch):
    """Every trial costs more than the point (all steps rejected). An undamped step that predicts no decrease
    worth having ends the solve as converged where it stands; a step that predicts a decrease, damped until it no
    longer moves, ends it as stalled: usable at this feasible point, but not called converged."""
    problem, p, truth = henon_window
    solver = GaussNewtonSolver(problem)
    starts = solver._start(truth, p), solver._start(truth, p)  # the same point, evaluated into buffer 0
    worse = solver._evaluate(truth + 1e-3, p, starts[0].point)
    monkeypatch.setattr(solver, "_evaluate", lambda z, p, keep=None, lam_g=None: worse)

    def step(size: float, predicted: float) -> object:
        return lambda point, damping, warm: (np.full(problem.n_var, size / (1.0 + 1e3 * damping)), predicted)

    monkeypatch.setattr(solver, "_step", step(1e-6, 1e-20))
    state = solver._state = starts[0]
    assert solver._iterate(state) and state.status == "Converged" and state.point is not worse

    monkeypatch.setattr(solver, "_step", step(1e-6, 1e-3))
    state = solver._state = starts[1]
    for state.iterations in range(1, 100):
        if solver._iterate(state):
            break
    assert state.status == gauss_newton.STALLED and state.point is not worse and state.iterations > 2
    solution = solver._finish(state, truth, 0.0)
    assert solution.status == "Stalled" and solution.success and not solution.fallback


def test_a_constant_damping_the_user_asked_for_still_converges():
    """``min_damping`` damps every step by the same amount: a small step at that damping is the solve's
    least-damped step, and ends it as converged, not stalled (noisy linear windows, whose KKT test rounding fails)."""
    entry = get("linear-example")
    system, setup = entry.build(), entry.setup()
    traj = simulate(system, setup.x0, 20, w=setup.w, v=setup.noise, seed=3)
    weights = UISEWeights.from_scales(system, 0.5, output=1e4)
    for solver in ("gn", "gn-riccati"):
        result = UISE(system, weights=weights, N=6, x0_prior=np.zeros(3), solver=solver,
                      solver_options={"min_damping": 1e-8}).run(None, traj.y)  # fmt: skip
        assert set(result.solver_status[1:]) == {"Converged"} and result.fallbacks == 0


def test_a_second_order_correction_removes_the_violation_a_curved_constraint_leaves(henon_window):
    """From a point off the truth the full step satisfies the linearised dynamics only: the quadratic term
    leaves the trial point infeasible. The correction, the QP with the violation seen at the trial point,
    leaves a violation of higher order."""
    problem, p, truth = henon_window
    solver = GaussNewtonSolver(problem)
    z = np.clip(truth + 0.05 * np.cos(np.arange(problem.n_var)), problem.lbx, problem.ubx)
    state = solver._state = solver._start(z, p)
    step = solver._step(state.point, 0.0, True)
    assert step is not None
    dz = step[0]
    trial = solver._evaluate(np.clip(z + dz, problem.lbx, problem.ubx), p, state.point, state.lam_a)
    trial_worst = trial.worst
    assert trial_worst > 1e-4
    correction = solver._second_order_correction(state.point, trial, dz, 0.0, p)
    assert correction is not None
    assert correction.point.worst < 0.01 * trial_worst


def test_each_solve_starts_from_its_own_state(henon_window):
    """A solve of another window in between leaves nothing behind: the same window from the same start gives the
    same iterates (only the damping failed QPs leave is carried, until reset())."""
    problem, p, truth = henon_window
    solver = GaussNewtonSolver(problem)
    start = np.clip(truth + 0.05 * np.sin(np.arange(problem.n_var)), problem.lbx, problem.ubx)
    first = solver.solve(start, p)
    solver.solve(np.clip(truth - 0.1, problem.lbx, problem.ubx), p * 1.01)
    again = solver.solve(start, p)
    assert first.iterations == again.iterations and first.status == again.status
    np.testing.assert_array_equal(first.z, again.z)
    np.testing.assert_array_equal(first.lam_g, again.lam_g)


def test_a_solve_refuses_multipliers(henon_window):
    problem, p, truth = henon_window
    solver = GaussNewtonSolver(problem)
    with pytest.raises(OptionError, match="lam_x0"):
        solver.solve(truth, p, np.zeros(problem.n_var), None)
    with pytest.raises(OptionError, match="lam_g0"):
        solver.solve(truth, p, None, np.zeros(problem.n_con))


def test_the_estimators_pass_multipliers_only_to_backends_that_take_them(henon_window, monkeypatch):
    example = runpy.run_path(str(EXAMPLES / "chaotic_message.py"))
    system = example["build"]()
    traj = simulate(system, [0.1, 0.1], 12, w=example["message"](12))
    weights = UISEWeights.from_scales(system, 0.6)
    given = []
    real_solve = gauss_newton.GaussNewtonSolver.solve

    def solve(self, z0, p, lam_x0=None, lam_g0=None):
        given.append((lam_x0, lam_g0))
        return real_solve(self, z0, p, lam_x0, lam_g0)

    monkeypatch.setattr(gauss_newton.GaussNewtonSolver, "solve", solve)
    for backend in ("gn", "rti", "gn-riccati"):
        estimator = UISE(system, weights=weights, N=3, x0_prior=traj.x[0], solver=backend, warm_start=True)
        assert estimator.run(traj.u, traj.y).failures == 0
    assert len(given) > 30 and all(pair == (None, None) for pair in given)
