"""The Gauss-Newton solver with the stage-wise Riccati interior point (``qp="riccati"``) against IPOPT."""

from __future__ import annotations

import runpy
from pathlib import Path

import numpy as np
import pytest

from uiest import UniformNoise, simulate
from uiest.errors import OptionError
from uiest.estimators import UISE, MHEWeights, StandardMHE, TwoStageUISE, TwoStageWeights, UISEWeights
from uiest.experiments.solver_bench import _record_full_windows, same_window_deviation
from uiest.models import closed_form, crop_growth, get, load
from uiest.window import WindowProblem, make_solver
from uiest.window.gauss_newton import GaussNewtonSolver
from uiest.window.riccati_qp import QPStatus

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _linear_uise():
    entry = get("linear-example")
    system, setup = entry.build(), entry.setup()
    traj = simulate(system, setup.x0, 25, w=setup.w, v=setup.noise, seed=3)
    weights = UISEWeights.from_scales(system, 0.5, output=1e4)
    return UISE(system, weights=weights, N=6, x0_prior=np.zeros(3), solver="gn-riccati"), 6, traj


def _crop(kind):
    system = crop_growth.system()
    scenario = crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, 25, w=crop_growth.UnknownInputLaw(), v=scenario.noise(), seed=1)
    prior = scenario.prior(traj.y[0])
    if kind == "uise":
        weights = UISEWeights.from_scales(system, 0.48, output=1e6)
        return UISE(system, weights=weights, N=10, x0_prior=prior, solver="gn-riccati"), 10, traj
    if kind == "mhe":
        weights = MHEWeights.from_scales(system, 0.48, output=1e6)
        return StandardMHE(system, weights=weights, N=10, x0_prior=prior, solver="gn-riccati"), 10, traj
    reduced = crop_growth.reduction()  # output and node constraints: stage rows C_k
    weights = TwoStageWeights.from_scales(reduced, 0.48, output=1e6)
    return TwoStageUISE(reduced, weights=weights, N=10, x0_prior=prior, solver="gn-riccati"), 10, traj


def _henon_mhe():
    example = runpy.run_path(str(EXAMPLES / "chaotic_message.py"))
    system = example["build"]()
    traj = simulate(system, [0.1, 0.1], 30, w=example["message"](30), v=UniformNoise.symmetric(1e-3), seed=0)
    estimator = StandardMHE(system, weights=MHEWeights.from_scales(system, 0.6), N=15, x0_prior=np.zeros(2),
                            solver="gn-riccati")  # fmt: skip
    return estimator, 15, traj


def _reactor_mhe():
    entry = load(EXAMPLES / "reactor.py")
    system, setup = entry.build(), entry.simulation()
    traj = simulate(system, setup.x0, 25, u=setup.u, w=setup.w, v=setup.noise, seed=0)
    weights = MHEWeights.from_scales(system, 0.6)
    return StandardMHE(system, weights=weights, N=10, x0_prior=np.array([0.65, 1.05]), solver="gn-riccati"), 10, traj


def _closed_form_uise():
    system = closed_form.system()
    entry = get(closed_form.NAME)
    setup = entry.setup()
    traj = simulate(system, setup.x0, 25, u=setup.u, w=setup.w, v=setup.noise, seed=2)
    weights = UISEWeights.from_scales(system, 0.5, output=1e4)
    return UISE(system, weights=weights, N=8, x0_prior=setup.x0, solver="gn-riccati"), 8, traj


CASES = {
    "linear-uise": _linear_uise,
    "crop-uise": lambda: _crop("uise"),
    "crop-mhe": lambda: _crop("mhe"),
    "crop-two-stage": lambda: _crop("two-stage"),
    "henon-mhe": _henon_mhe,
    "reactor-mhe": _reactor_mhe,
    "closed-form-uise": _closed_form_uise,
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_riccati_backend_reaches_ipopts_optimum_on_small_windows(case):
    estimator, N, traj = CASES[case]()
    recorder = _record_full_windows(estimator, N)
    result = estimator.run(traj.u, traj.y)
    assert result.failures == 0 and result.fallbacks == 0
    assert recorder.calls and recorder.solver.qp_fallbacks == 0  # the interior point solved every QP
    agreement = same_window_deviation(recorder)
    assert agreement["windows_compared"] == len(recorder.calls)
    assert agreement["max_cost_excess_vs_ipopt"] <= 1e-8
    assert agreement["max_dev_vs_ipopt"] <= 1e-5


def test_qp_option_is_checked_and_the_backend_is_selectable():
    system = get("linear-example").build()
    problem = WindowProblem(system, 3, [0, 1, 2, 3])
    with pytest.raises(OptionError, match="qp: expected one of"):
        GaussNewtonSolver(problem, qp="hpipm")
    solver = make_solver("gn-riccati", problem)
    assert isinstance(solver, GaussNewtonSolver) and solver.qp == "riccati"
    assert make_solver("gn", problem).qp == "qrqp"
    assert make_solver("gn-riccati", problem, options={"qp": "riccati"}).qp == "riccati"
    with pytest.raises(OptionError, match="solver_options: qp='qrqp' contradicts solver='gn-riccati'"):
        make_solver("gn-riccati", problem, options={"qp": "qrqp"})
    with pytest.raises(OptionError, match="solver_options: max_iter=5 contradicts solver='rti'"):
        make_solver("rti", problem, options={"max_iter": 5})


def _crop_two_stage_form():
    estimator, N, _ = _crop("two-stage")  # output and node constraints: general stage rows
    solver = estimator._cached(N).warm
    return solver.problem, solver._gauss_newton_form.stage


def test_stage_form_guess_is_the_multipliers_signs_above_the_floor():
    from uiest.window.stage_qp import GUESS_FLOOR, _guess_sides

    problem, form = _crop_two_stage_form()
    rows = form._c_rows
    assert rows.size > 0  # the two-stage window has general rows
    rng = np.random.default_rng(0)
    lam_x = rng.standard_normal(problem.n_var) * 10.0 ** rng.integers(-14, 1, problem.n_var)
    lam_a = rng.standard_normal(problem.n_con) * 10.0 ** rng.integers(-14, 1, problem.n_con)
    lam_x[:3] = 0.0
    out = np.empty(problem.n_var + rows.size)
    _guess_sides(lam_x, lam_a, rows, GUESS_FLOOR, out)
    lam = np.concatenate((lam_x, lam_a[rows]))
    expected = np.where(np.abs(lam) > GUESS_FLOOR * np.abs(lam).max(), np.sign(lam), 0.0)
    assert np.array_equal(out, expected) and 0 < np.count_nonzero(out) < out.size


def test_stage_form_refuses_dynamics_rows_that_are_not_equalities():
    problem, form = _crop_two_stage_form()
    solver = GaussNewtonSolver(problem, qp="riccati")
    z = problem.pack(problem.unpack(np.zeros(problem.n_var)))
    point = solver._evaluate(np.clip(z, problem.lbx, problem.ubx), np.zeros(problem.n_par))
    lba, uba = problem.lbg - point.g, problem.ubg - point.g
    bounds = (lba, uba, problem.lbx - point.z, problem.ubx - point.z)
    h = point.h.copy()
    h[solver._gauss_newton_form.diagonal] += 1.0  # positive definite stage blocks
    assert form.solve(h, point.q, point.a, bounds) is not None and form.last_status is QPStatus.SOLVED
    loose = uba.copy()
    loose[problem.n_dyn - 1] += 1e-6  # the last dynamics row becomes an inequality
    assert form.solve(h, point.q, point.a, (lba, loose, *bounds[2:])) is None and form.last_status is None


@pytest.mark.parametrize(("kind", "length"), [("uise", 0), ("two-stage", 10)])
def test_stage_form_takes_the_bounds_relative_to_the_point_it_is_given(kind, length):
    # at=(g, z) shifts the bounds inside the compiled call; a one-node window has no constraint rows (g empty),
    # where the shift was once skipped and the QP solved with X's sides as the step's bounds
    estimator, _, _ = _crop(kind)
    solver = estimator._cached(length).warm
    problem, form = solver.problem, solver._gauss_newton_form.stage
    z = np.clip(problem.pack(problem.unpack(np.zeros(problem.n_var))), problem.lbx, problem.ubx)
    z[0] = problem.ubx[0]  # the start on a side: the step's upper bound there is 0
    point = solver._evaluate(z, np.zeros(problem.n_par))
    h = point.h.copy()
    h[solver._gauss_newton_form.diagonal] += 1.0
    shifted = (problem.lbg - point.g, problem.ubg - point.g, problem.lbx - point.z, problem.ubx - point.z)
    expected = form.solve(h, point.q, point.a, shifted)
    given = form.solve(h, point.q, point.a, (problem.lbg, problem.ubg, problem.lbx, problem.ubx), at=(point.g, point.z))
    assert (problem.n_con == 0) == (length == 0) and expected is not None and given is not None
    np.testing.assert_array_equal(given[0], expected[0])
    assert given[0][0] <= 0.0
