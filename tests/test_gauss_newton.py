"""The Gauss-Newton backend against the IPOPT reference, and its fallbacks."""

import dataclasses
import runpy
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

from uiest import UniformNoise, simulate
from uiest.estimators import UISE, MHEWeights, Outcome, StandardMHE, UISEWeights
from uiest.estimators import base as base_module
from uiest.experiments.solver_bench import _record_full_windows, same_window_deviation
from uiest.models import crop_growth, get, load
from uiest.window import gauss_newton
from uiest.window.curvature import BlockCurvature


@pytest.fixture(scope="module")
def crop_run():
    system = crop_growth.system()
    scenario = crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, 50, w=crop_growth.UnknownInputLaw())
    return system, traj, scenario.prior(traj.y[0])


@pytest.mark.parametrize("kind", ["uise", "mhe"])
def test_gauss_newton_reaches_the_ipopt_optimum_on_the_crop_model(crop_run, kind):
    system, traj, prior = crop_run
    runs = {}
    for solver in ("ipopt", "gn"):
        if kind == "uise":
            est = UISE(system, weights=UISEWeights.from_scales(system, 0.48, output=1e6), N=20, x0_prior=prior,
                       solver=solver)  # fmt: skip
        else:
            est = StandardMHE(system, weights=MHEWeights.from_scales(system, 0.48, output=1e6), N=20,
                              x0_prior=prior, solver=solver)  # fmt: skip
        runs[solver] = est.run(traj.u, traj.y)
    gn, ipopt = runs["gn"], runs["ipopt"]
    # "Stalled": no step improved a feasible point further (noise-free windows at rounding level)
    assert gn.failures == 0 and set(gn.solver_status[1:]) <= {"Converged", "Converged (regularised)", "Stalled"}
    assert set(gn.outcome[1:]) == {Outcome.SOLVED} and gn.fallbacks == 0
    deviation = np.abs((gn.x_hat - ipopt.x_hat) / system.x.scale).max()
    assert deviation < 1e-5
    if kind == "uise":  # noise-free: the UISE error of x^{d,1} keeps falling (N = 20: slower than N = 30)
        error = np.abs(gn.error(traj.x))[:, 1]
        assert error[-1] < 1e-6 and error[-1] < 0.02 * error[25]


def test_rti_takes_one_step_per_sample_and_tracks_the_linear_example():
    entry = get("linear-example")
    system, setup = entry.build(), entry.setup()
    traj = simulate(system, setup.x0, 60, w=setup.w)
    weights = UISEWeights.from_scales(system, 0.5, output=1e4)
    rti = UISE(system, weights=weights, N=6, x0_prior=np.zeros(3), solver="rti").run(None, traj.y)
    assert set(rti.iterations[1:]) == {1} and rti.failures == 0
    # linear problem: one Gauss-Newton step from any guess is the optimum
    gn = UISE(system, weights=weights, N=6, x0_prior=np.zeros(3), solver="gn").run(None, traj.y)
    np.testing.assert_allclose(rti.x_hat, gn.x_hat, atol=1e-8)


def test_failed_qp_falls_back_to_cold_start_then_regularised_then_ipopt(crop_run, monkeypatch):
    system, traj, prior = crop_run
    weights = UISEWeights.from_scales(system, 0.48, output=1e6)
    reference = UISE(system, weights=weights, N=5, x0_prior=prior, solver="gn").run(traj.u[:10], traj.y[:11])
    real_qp = gauss_newton.GaussNewtonSolver._qp

    def warm_fails(self, form, h, point, warm, release_tol):
        return None if warm else real_qp(self, form, h, point, warm, release_tol)

    monkeypatch.setattr(gauss_newton.GaussNewtonSolver, "_qp", warm_fails)
    cold = UISE(system, weights=weights, N=5, x0_prior=prior, solver="gn").run(traj.u[:10], traj.y[:11])
    assert set(cold.solver_status[1:]) == {"Converged"}
    np.testing.assert_allclose(cold.x_hat, reference.x_hat, rtol=0, atol=1e-9)

    real_step, real_solve = gauss_newton.GaussNewtonSolver._step, gauss_newton.GaussNewtonSolver.solve
    first = {"step": False}

    def solve(self, *args):
        first["step"] = True
        return real_solve(self, *args)

    def first_qp_fails(self, point, damping, warm):  # every solve's first QP fails undamped
        if first["step"]:
            first["step"] = False
            return None
        return real_step(self, point, damping, warm)

    monkeypatch.setattr(gauss_newton.GaussNewtonSolver, "solve", solve)
    monkeypatch.setattr(gauss_newton.GaussNewtonSolver, "_step", first_qp_fails)
    result = UISE(system, weights=weights, N=5, x0_prior=prior, solver="gn").run(traj.u[:10], traj.y[:11])
    assert set(result.solver_status[1:]) == {"Converged (regularised)"} and result.failures == 0
    np.testing.assert_allclose(result.x_hat, reference.x_hat, rtol=0, atol=1e-7)

    def always_fails(self, point, damping, warm):
        return None

    monkeypatch.setattr(gauss_newton.GaussNewtonSolver, "_step", always_fails)
    result = UISE(system, weights=weights, N=5, x0_prior=prior, solver="gn").run(traj.u[:10], traj.y[:11])
    assert result.fallback[1:].all() and result.fallbacks >= len(result.outcome) - 1
    assert set(result.primary_status[1:]) == {"gn QP_failed"} and set(result.outcome[1:]) == {Outcome.SOLVED}
    assert result.status[1] == f"solved (gn QP_failed -> ipopt {result.solver_status[1]})"
    assert result.failures == 0


@pytest.mark.parametrize("singular_below", [0.0, 1e-12], ids=["undamped", "up-to-1e-14"])
def test_a_singular_qp_keeps_the_smallest_damping_for_later_samples(crop_run, monkeypatch, singular_below):
    """QPs fail undamped (or also at the 1e-14 damping, so that only the 1e-5 one solves): each
    solver tries the undamped QP once, never again in later iterations or samples."""
    system, traj, prior = crop_run
    weights = UISEWeights.from_scales(system, 0.48, output=1e6)
    reference = UISE(system, weights=weights, N=5, x0_prior=prior, solver="gn").run(traj.u[:10], traj.y[:11])
    real_step = gauss_newton.GaussNewtonSolver._step
    dampings: list[float] = []

    def singular_when_undamped(self, point, damping, warm):  # as if J^T J were singular
        relative = damping / np.abs(point.h).max()
        dampings.append(relative)
        return None if relative <= singular_below else real_step(self, point, damping, warm)

    monkeypatch.setattr(gauss_newton.GaussNewtonSolver, "_step", singular_when_undamped)
    estimator = UISE(system, weights=weights, N=5, x0_prior=prior, solver="gn")
    result = estimator.run(traj.u[:10], traj.y[:11])
    assert set(result.solver_status[1:]) == {"Converged (regularised)"} and result.failures == 0
    # each window length's solver (0 .. 5) tried one undamped QP, then 1e-14 (and 1e-9); later solves start damped
    assert dampings.count(0.0) == 6 and min(d for d in dampings if d > 0) == pytest.approx(1e-14)
    if singular_below:  # 1e-14 failed once per solver too: later solves start at 1e-9
        assert sum(0.0 < d < 1e-12 for d in dampings) == 6
    kept = gauss_newton.DAMPING_FLOOR if singular_below else gauss_newton.SINGULAR_DAMPING
    assert estimator._cached(5).warm._kept_damping == kept
    np.testing.assert_allclose(result.x_hat, reference.x_hat, rtol=0, atol=1e-6)


@pytest.mark.parametrize("estimator", ["uise", "fie", "mhe"])
def test_gauss_newton_equals_ipopt_on_the_noisy_linear_example(estimator):
    from uiest.estimators import FIE

    entry = get("linear-example")
    system, setup = entry.build(), entry.setup()
    traj = simulate(system, setup.x0, 40, w=setup.w, v=setup.noise, seed=3)
    runs = {}
    for solver in ("ipopt", "gn"):
        if estimator == "mhe":
            weights = MHEWeights.from_scales(system, 0.5, output=1e4)
            est = StandardMHE(system, weights=weights, N=6, x0_prior=np.zeros(3), solver=solver)
        else:
            weights = UISEWeights.from_scales(system, 0.5, output=1e4)
            cls = UISE if estimator == "uise" else FIE
            kwargs = {"N": 6} if estimator == "uise" else {}
            est = cls(system, weights=weights, x0_prior=np.zeros(3), solver=solver, **kwargs)
        runs[solver] = est.run(None, traj.y)
    gn, ipopt = runs["gn"], runs["ipopt"]
    assert gn.failures == 0 and ipopt.failures == 0
    assert np.abs((gn.x_hat - ipopt.x_hat) / system.x.scale).max() < 1e-6


@pytest.mark.parametrize(("kind", "N"), [("two-stage", 10), ("uise", 30)])
@pytest.mark.slow
def test_second_order_corrections_spare_the_fallbacks_on_noisy_crop_windows(kind, N, monkeypatch):
    """Long steps along weakly seen directions leave the dynamics violated: without the correction,
    damped and full steps alternate until the iteration limit and IPOPT takes the sample over."""
    from uiest.estimators import TwoStageUISE, TwoStageWeights

    system, scenario = crop_growth.system(), crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, 300, w=crop_growth.UnknownInputLaw(), v=scenario.noise(), seed=1)
    prior = scenario.prior(traj.y[0])

    def run():
        if kind == "uise":
            weights = UISEWeights.from_scales(system, 0.48, output=1e6)
            estimator = UISE(system, weights=weights, N=N, x0_prior=prior, solver="gn")
        else:
            reduced = crop_growth.reduction()
            weights = TwoStageWeights.from_scales(reduced, 0.48, output=1e6)
            estimator = TwoStageUISE(reduced, weights=weights, N=N, x0_prior=prior, solver="gn")
        result = estimator.run(traj.u, traj.y)
        return result.failures, result.fallbacks

    assert run() == (0, 0)
    monkeypatch.setattr(gauss_newton, "SOC_RATIO", float("inf"))  # no correction is ever good enough
    monkeypatch.setattr(gauss_newton, "LAST_CORRECTION_RATIO", float("inf"))
    failures, fallbacks = run()
    assert failures == 0 and fallbacks > 0


def test_linearly_converging_noisy_windows_finish_within_the_default_iteration_limit():
    """Noisy standard-MHE windows, where the residuals' curvature makes Gauss-Newton contract by
    only about 0.5 per iteration: the default limit lets them converge; 15 iterations, the
    control, hand some samples to IPOPT."""
    system, scenario = crop_growth.system(), crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, 300, w=crop_growth.UnknownInputLaw(), v=scenario.noise(), seed=1)
    weights = MHEWeights.from_scales(system, 0.48, output=1e6)

    def fallbacks(**options):
        estimator = StandardMHE(
            system, weights=weights, N=10, x0_prior=scenario.prior(traj.y[0]), solver="gn", solver_options=options
        )
        result = estimator.run(traj.u, traj.y)
        assert result.failures == 0
        return result.fallbacks

    assert fallbacks() == 0
    assert fallbacks(max_iter=15) > 0


def _gn_mhe_fallbacks(system, traj, weights, N: int, prior) -> int:
    """IPOPT fallbacks of the Gauss-Newton standard MHE on a record (no sample may fail)."""
    result = StandardMHE(system, weights=weights, N=N, x0_prior=prior, solver="gn").run(traj.u, traj.y)
    assert result.failures == 0
    return result.fallbacks


def _reactor_mhe_fallbacks(N: int, steps: int) -> int:
    """IPOPT fallbacks of the Gauss-Newton standard MHE on the CSTR of examples/reactor.py (noisy, N given)."""
    entry = load(Path(__file__).resolve().parents[1] / "examples" / "reactor.py")
    system, setup = entry.build(), entry.simulation()
    traj = simulate(system, setup.x0, steps, u=setup.u, w=setup.w, v=setup.noise, seed=0)
    return _gn_mhe_fallbacks(system, traj, MHEWeights.from_scales(system, 0.6), N, np.array([0.65, 1.05]))


@pytest.mark.slow
def test_the_merit_penalty_is_relative_to_the_multipliers_on_windows_with_a_small_cost(monkeypatch):
    """The CSTR's MHE windows have costs near 1e-5 and multipliers near 1e-3: the absolute margin
    used before, nu = 2 |lam| + 1, rejects every step that leaves a violation of a few 1e-7, and with
    one second-order correction per step samples go to IPOPT (control; repeated corrections rescue
    those steps too)."""
    assert _reactor_mhe_fallbacks(30, 200) == 0
    monkeypatch.setattr(gauss_newton, "MAX_CORRECTIONS", 1)
    assert _reactor_mhe_fallbacks(30, 200) == 0
    monkeypatch.setattr(gauss_newton, "_penalty", lambda lam_max: 2.0 * lam_max + 1.0)
    assert _reactor_mhe_fallbacks(30, 200) > 0


def _crop_mhe_fallbacks(N: int, steps: int) -> int:
    """IPOPT fallbacks of the Gauss-Newton standard MHE on the noisy crop scenario (seed 1)."""
    system, scenario = crop_growth.system(), crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, steps, w=crop_growth.UnknownInputLaw(), v=scenario.noise(), seed=1)
    weights = MHEWeights.from_scales(system, 0.48, output=1e6)
    return _gn_mhe_fallbacks(system, traj, weights, N, scenario.prior(traj.y[0]))


@pytest.mark.slow
def test_the_curvature_and_the_corrections_follow_curved_valleys(monkeypatch):
    """Noisy crop standard MHE, N = 30: in four windows the full step runs 0.5 (state scales) along a
    valley the cost barely sees while the dynamics curve away from it; the merit rejects it, and damped
    steps of 1e-3 crawl to the iteration limit. With the constraints' curvature (BlockCurvature) and a
    second-order correction taken once acceptable, none goes to IPOPT, even with one correction per step
    (its ratio below SOC_RATIO, yet above LAST_CORRECTION_RATIO); with one correction taken only when
    good (control), or without the switch to the curvature (control), some do."""
    assert _crop_mhe_fallbacks(30, 270) == 0
    with monkeypatch.context() as patch:
        patch.setattr(gauss_newton, "MAX_CORRECTIONS", 1)
        assert _crop_mhe_fallbacks(30, 270) == 0
        patch.setattr(gauss_newton, "LAST_CORRECTION_RATIO", gauss_newton.SOC_RATIO)
        assert _crop_mhe_fallbacks(30, 270) > 0
    monkeypatch.setattr(BlockCurvature, "curved", property(lambda self: False))
    assert _crop_mhe_fallbacks(30, 270) > 0


def _closed_form_mhe_fallbacks(N: int, steps: int) -> int:
    """IPOPT fallbacks of the Gauss-Newton standard MHE on the noise-free closed-form model (bench/gn_models.py's)."""
    entry = get("closed-form")
    system, setup = entry.build(), entry.simulation()
    traj = simulate(system, setup.x0, steps, u=setup.u, w=setup.w, seed=0)
    prior = 1.1 * np.asarray(setup.x0, dtype=float)
    return _gn_mhe_fallbacks(system, traj, MHEWeights.from_scales(system, 0.6), N, prior)


@pytest.mark.slow
def test_a_step_saved_by_poor_corrections_switches_to_the_curvature(monkeypatch):
    """Closed-form standard MHE, N = 10: along its barely observable x2 the dynamics curve away from the step;
    four corrections bring the violation back with a merit ratio near 0.36, and the step is taken. Switched to
    J^T J + S_+ from there, the solve converges in a few iterations; staying with J^T J (control), it crawls
    to the iteration limit and hands the sample to IPOPT."""
    switched = _closed_form_mhe_fallbacks(10, 200)
    monkeypatch.setattr(gauss_newton, "CURVATURE_RATIO", 0.0)
    assert 2 * switched < _closed_form_mhe_fallbacks(10, 200)


def test_the_block_curvature_is_the_lagrangian_curvature_without_its_negative_part():
    """``J^T J + S_+`` on a crop window with random multipliers: ``S_+`` and ``S_+ - S`` are positive
    semidefinite (S the residuals' and constraints' curvature, from CasADi's Hessian of the Lagrangian),
    and nonzero; they match where S is, block by block, already positive semidefinite."""
    import casadi as ca

    system, scenario = crop_growth.system(), crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, 6, w=crop_growth.UnknownInputLaw(), v=scenario.noise(), seed=1)
    estimator = StandardMHE(system, weights=MHEWeights.from_scales(system, 0.48, output=1e6), N=5,
                            x0_prior=scenario.prior(traj.y[0]), solver="gn")  # fmt: skip
    recorder = _record_full_windows(estimator, 5)
    estimator.run(traj.u, traj.y)
    z, p = recorder.calls[-1][2].z, recorder.calls[-1][1]
    problem = recorder.problem
    solver = gauss_newton.GaussNewtonSolver(problem)
    curvature = BlockCurvature(problem, solver._h_sparsity)
    lam_g = np.random.default_rng(0).normal(scale=100.0, size=problem.n_con)
    gn = solver._evaluate(z, p).h.copy()
    dense = lambda sparsity, nonzeros: np.array(ca.DM(ca.Sparsity(sparsity), nonzeros))  # noqa: E731
    gauss_newton_matrix = dense(solver._h_sparsity, gn)
    s_plus = dense(curvature.sparsity, curvature(z, p, lam_g, gn)) - gauss_newton_matrix
    lagrangian = 0.5 * ca.sumsqr(problem.r) + ca.dot(lam_g, problem.g)
    exact = ca.Function("hessian", [problem.z, problem.p], [ca.hessian(lagrangian, problem.z)[0]])
    s = np.array(exact(z, p)) - gauss_newton_matrix
    scale = np.abs(s).max()
    assert scale > 0.0 and np.abs(s_plus).max() > 0.1 * scale
    assert np.linalg.eigvalsh(s_plus).min() >= -1e-10 * scale
    assert np.linalg.eigvalsh(s_plus - s).min() >= -1e-10 * scale
    # the negative part removed is exactly the negative eigenvalues of S's blocks
    assert np.trace(s_plus - s) == pytest.approx(-np.linalg.eigvalsh(s).clip(max=0.0).sum(), rel=1e-8)


def test_a_linear_model_has_no_curvature_to_switch_to():
    """A linear model's residuals and dynamics have no curvature: BlockCurvature says so, and a rejected step
    damps at once instead of re-solving the same QP."""
    system = get("linear-example").build()
    problem = StandardMHE(system, weights=MHEWeights.from_scales(system, 0.6), N=5)._cached(5).problem
    solver = gauss_newton.GaussNewtonSolver(problem)
    assert not solver._curve() and not solver._curved
    assert not BlockCurvature(problem, solver._h_sparsity).curved


def _crop_uise_agreement(steps: int) -> dict[str, float]:
    """gn's noisy crop UISE windows (N = 30, seed 1) against IPOPT's solves of the same windows."""
    system, scenario = crop_growth.system(), crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, steps, w=crop_growth.UnknownInputLaw(), v=scenario.noise(), seed=1)
    weights = UISEWeights.from_scales(system, 0.48, output=1e6)
    estimator = UISE(system, weights=weights, N=30, x0_prior=scenario.prior(traj.y[0]), solver="gn")
    recorder = _record_full_windows(estimator, 30)
    estimator.run(traj.u, traj.y)
    return same_window_deviation(recorder)


@pytest.mark.slow
def test_a_step_that_restores_feasibility_at_a_higher_cost_does_not_end_the_solve(monkeypatch):
    """Noisy crop UISE windows (N = 30) where a long first step leaves the dynamics violated and the
    next one restores them at a higher cost: gn's optimum is IPOPT's. Control: read as "no decrease
    left", that negative prediction stopped a window 1e-5 (relative) above IPOPT's cost."""
    assert _crop_uise_agreement(90)["max_cost_excess_vs_ipopt"] <= 1e-8
    monkeypatch.setattr(gauss_newton, "_no_decrease_left", lambda predicted, cost, tol: predicted <= tol * (1 + cost))
    assert _crop_uise_agreement(90)["max_cost_excess_vs_ipopt"] > 1e-6


@pytest.mark.slow
def test_sides_held_at_a_zero_multiplier_are_released_for_the_next_qp(monkeypatch):
    """The oldest noise estimates of noisy crop UISE windows (weights 0.48^29) parked on the noise box's
    sides with qrqp's zero-multiplier marks: released, every window's cost is within 1e-8 of IPOPT's.
    Control: kept in the warm start, windows end 1e-8 .. 4e-8 (relative) above it."""
    agreement = _crop_uise_agreement(70)
    assert agreement["windows_compared"] >= 30 and agreement["windows_cost_above_1e-8"] == 0
    monkeypatch.setattr(gauss_newton, "_released", lambda held, *_: np.zeros_like(held))
    assert _crop_uise_agreement(70)["windows_cost_above_1e-8"] > 0


def test_a_held_side_is_released_only_where_leaving_it_could_lower_the_cost():
    """Sides 0-1 held at an upper bound, 2-3 at a lower one; the QP's gradient at its solution pulls
    sides 0 and 2 inwards by a relevant amount, side 1 inwards above its rounding but by less than the
    gain worth a release, side 3 outwards (its zero multiplier is right); side 4 is not held. Then
    side 0's gradient is below its rounding."""
    held = np.array([True, True, True, True, False])
    lam = np.array([1e-308, 1e-308, -1e-308, -1e-308, 0.0])
    gradient = np.array([1e-9, 1e-14, -1e-9, 1e-9, 1.0])
    width = np.array([1.0, 1.0, 2.0, np.inf, 1.0])
    rounding = np.full(5, 1e-16)
    released = gauss_newton._released(held, lam, gradient, rounding, width, tol=1e-12)
    assert released.tolist() == [True, False, True, False, False]
    rounding[0] = 1e-8  # side 0's gradient is now below its rounding
    assert gauss_newton._released(held, lam, gradient, rounding, width, tol=1e-12).tolist()[0] is False


def _noisy_crop_mhe(steps: int):
    """The crop model's noisy record (seed 1) and a builder of its Gauss-Newton standard MHE (N = 10)."""
    system, scenario = crop_growth.system(), crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, steps, w=crop_growth.UnknownInputLaw(), v=scenario.noise(), seed=1)
    weights = MHEWeights.from_scales(system, 0.48, output=1e6)

    def build() -> StandardMHE:
        return StandardMHE(system, weights=weights, N=10, x0_prior=scenario.prior(traj.y[0]), solver="gn")

    return system, traj, build


def test_the_merit_counts_no_violation_below_rounding(monkeypatch):
    """At the solutions of noisy crop windows the dynamics hold up to rounding: the merit's violation is
    0 there, while the largest entry (the feasibility test's) is not. Control: with no floor, the merit
    counts the rounding."""
    _, traj, build = _noisy_crop_mhe(30)
    estimator = build()
    recorder = _record_full_windows(estimator, 10)
    estimator.run(traj.u, traj.y)
    windows = [(p, solution.z) for _, p, solution in recorder.calls if solution.success]
    assert len(windows) >= 15

    def violations():
        solver = gauss_newton.GaussNewtonSolver(recorder.problem)
        points = [solver._evaluate(z, p) for p, z in windows]
        return np.array([point.violation for point in points]), np.array([point.worst for point in points])

    merit, worst = violations()
    assert np.all(merit == 0.0) and np.all(worst <= gauss_newton.VIOLATION_FLOOR) and np.any(worst > 0.0)
    monkeypatch.setattr(gauss_newton, "VIOLATION_FLOOR", 0.0)
    merit, _ = violations()
    assert np.any(merit > 0.0)


def test_a_step_that_would_only_restore_rounding_ends_the_solve(monkeypatch):
    """Noisy crop standard MHE (N = 10): at a point feasible to rounding, a step that predicts no decrease
    of the cost ends the solve there, with the same estimates (to 1e-6) in fewer iterations than
    taking it (control)."""
    system, traj, build = _noisy_crop_mhe(120)
    stopping = build().run(traj.u, traj.y)
    monkeypatch.setattr(gauss_newton, "_only_restores_rounding", lambda predicted, point: False)
    taking = build().run(traj.u, traj.y)
    assert stopping.failures == taking.failures == 0
    assert np.abs((stopping.x_hat - taking.x_hat) / system.x.scale).max() < 1e-6
    assert stopping.iterations.sum() < taking.iterations.sum()


@pytest.mark.slow
def test_a_qp_stopped_by_the_iteration_limit_goes_on_from_where_it_stopped(monkeypatch):
    """Noisy crop UISE windows (N = 30), whose first QPs need up to tens of active-set changes, with qrqp
    limited to 8 iterations per call: continued from the active set it reached, no QP has to be
    damped. Control: with no continuation, solves fall back on damped QPs ("(regularised)")."""
    system, scenario = crop_growth.system(), crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, 60, w=crop_growth.UnknownInputLaw(), v=scenario.noise(), seed=1)
    weights = UISEWeights.from_scales(system, 0.48, output=1e6)
    monkeypatch.setitem(gauss_newton.QP_OPTIONS, "max_iter", 8)

    def damped_samples():
        estimator = UISE(system, weights=weights, N=30, x0_prior=scenario.prior(traj.y[0]), solver="gn")
        result = estimator.run(traj.u, traj.y)
        assert result.failures == 0
        return int(np.count_nonzero((result.solver_status == "Converged (regularised)") | result.fallback))

    monkeypatch.setattr(gauss_newton, "QP_CONTINUATIONS", 8)
    assert damped_samples() == 0
    monkeypatch.setattr(gauss_newton, "QP_CONTINUATIONS", 0)
    assert damped_samples() > 0


@contextmanager
def _uncapped() -> Iterator[None]:
    """Estimators built inside run the N asked for, past their information horizon.

    The solver tests below need windows whose oldest terms fall below double precision, which the estimators cap.
    """
    real = base_module.information_horizon

    def none(*args, **kwargs):
        return dataclasses.replace(real(*args, **kwargs), horizon=None)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(base_module, "information_horizon", none)
        yield


@pytest.fixture(scope="module")
def henon_mhe_windows():
    """The full windows (N = 100, weights down to 0.6^99 ~ 1e-22) of a noisy Henon map's standard MHE, recorded."""
    example = runpy.run_path(str(Path(__file__).resolve().parents[1] / "examples" / "chaotic_message.py"))
    system = example["build"]()
    traj = simulate(system, [0.1, 0.1], 106, w=example["message"](106), v=UniformNoise.symmetric(1e-3), seed=0)
    with _uncapped():  # its information horizon is 70
        estimator = StandardMHE(system, weights=MHEWeights.from_scales(system, 0.6), N=100, x0_prior=np.zeros(2),
                                solver="gn")  # fmt: skip
    recorder = _record_full_windows(estimator, 100)
    assert estimator.run(traj.u, traj.y).failures == 0
    return recorder


def _qrqp_iterations(monkeypatch) -> list[int]:
    """qrqp's iterations of every QP solved from now on (the list fills as QPs are solved)."""
    counts: list[int] = []
    real_qp = gauss_newton.GaussNewtonSolver._qp

    def counting(self, form, *args):
        solved = real_qp(self, form, *args)
        counts.append(form.qrqp.stats()["iter_count"])
        return solved

    monkeypatch.setattr(gauss_newton.GaussNewtonSolver, "_qp", counting)
    return counts


def _henon_qrqp_iterations(windows, counts: list[int]) -> int:
    """qrqp's iterations over the recorded windows, each solved by one fresh solver (to the recorded cost)."""
    counts.clear()
    solver = gauss_newton.GaussNewtonSolver(windows.problem)
    for z0, p, recorded in windows.calls:
        solution = solver.solve(z0, p)
        assert solution.status == "Converged"
        assert abs(solution.cost - recorded.cost) <= 1e-10 * (1.0 + recorded.cost)
    return sum(counts)


@pytest.mark.slow
def test_the_qp_is_scaled_so_that_qrqp_tells_small_curvature_from_none(henon_mhe_windows, monkeypatch):
    """qrqp takes a KKT matrix whose QR factor has a diagonal entry below 1e-12 (absolute) for singular. The Henon
    windows' largest curvature is 2: unscaled, qrqp holds their weakly weighted variables on their boxes one
    iteration at a time, QP after QP. Both without raised curvature; control: the scale of those windows' own cost
    (QP_SCALE = 2)."""
    counts = _qrqp_iterations(monkeypatch)
    monkeypatch.setattr(gauss_newton, "FLAT_CURVATURE", 0.0)
    scaled = _henon_qrqp_iterations(henon_mhe_windows, counts)
    monkeypatch.setattr(gauss_newton, "QP_SCALE", 2.0)
    assert 2 * scaled < _henon_qrqp_iterations(henon_mhe_windows, counts)


@pytest.mark.slow
def test_curvature_too_small_for_qrqp_is_raised(henon_mhe_windows, monkeypatch):
    """The oldest nodes' curvature (weights 0.6^99) is below what qrqp tells from zero even in the scaled QP: raised,
    qrqp moves those variables by the least it can instead of holding them on their boxes and releasing them later.
    Control: FLAT_CURVATURE = 0 (solvers built after the patch)."""
    counts = _qrqp_iterations(monkeypatch)
    raised = _henon_qrqp_iterations(henon_mhe_windows, counts)
    monkeypatch.setattr(gauss_newton, "FLAT_CURVATURE", 0.0)
    assert 2 * raised < _henon_qrqp_iterations(henon_mhe_windows, counts)


@pytest.mark.slow
def test_damping_returns_to_zero_gradually_after_good_steps(monkeypatch):
    """The crop UISE with N = 50, whose oldest states are free to rounding: returning to undamped steps at once,
    the undamped step runs far along them and is rejected, a damped one is accepted, and so on to the iteration
    limit. Control: DAMPING_DECAY = inf (the damping back to 0 after one good step)."""
    system, scenario = crop_growth.system(), crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, 100, w=crop_growth.UnknownInputLaw(), v=scenario.noise(), seed=1)
    weights = UISEWeights.from_scales(system, 0.48, output=1e6)

    def fallbacks() -> int:
        with _uncapped():  # its information horizon is 30
            estimator = UISE(system, weights=weights, N=50, x0_prior=scenario.prior(traj.y[0]), solver="gn")
        return estimator.run(traj.u, traj.y).fallbacks

    gradual = fallbacks()
    monkeypatch.setattr(gauss_newton, "DAMPING_DECAY", float("inf"))
    assert gradual < fallbacks() - 5
