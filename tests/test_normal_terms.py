"""The compiled Gauss-Newton terms agree with the same quantities formed as CasADi expressions."""

import copy
import runpy
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from uiest.estimators import UISE, MHEWeights, StandardMHE, TwoStageUISE, TwoStageWeights, UISEWeights
from uiest.models import crop_growth, linear
from uiest.window.normal_terms import NormalTerms
from uiest.window.problem import WindowProblem

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
FLAT, FLOOR = 1e-9, 1e-14


def _expressions(problem: WindowProblem) -> tuple[ca.Function, ca.Sparsity]:
    """The terms as CasADi expressions (NaN handled as the compiled pass does: it propagates)."""
    z, p = problem.z, problem.p
    lam_g = ca.SX.sym("lam_g", problem.n_con)
    J, G = ca.jacobian(problem.r, z), ca.jacobian(problem.g, z)
    H = ca.project(ca.mtimes(J.T, J), ca.mtimes(J.T, J).sparsity() + ca.Sparsity.diag(problem.n_var))
    d = ca.diag(H)
    floor = FLAT * ca.mmax(d)
    H = ca.project(H + ca.diag(ca.if_else(ca.logic_and(d > 0, d < floor), floor - d, 0)), H.sparsity())
    g = problem.g
    lbg, ubg, lbx, ubx = (ca.DM(b) for b in (problem.lbg, problem.ubg, problem.lbx, problem.ubx))
    excess = ca.fmax(lbg - g, 0.0) + ca.fmax(g - ubg, 0.0)
    jtr = ca.densify(ca.mtimes(J.T, problem.r))
    s = jtr + ca.mtimes(G.T, lam_g)
    s = ca.if_else(z >= ubx, ca.fmax(s, 0.0), ca.if_else(z <= lbx, ca.fmin(s, 0.0), s))
    worst = ca.mmax(excess) if g.numel() else ca.SX(0.0)
    tests = [ca.sumsqr(problem.r), ca.sum1(ca.fmax(excess - FLOOR, 0.0)), worst, ca.mmax(ca.fabs(s))]
    outputs = [*(ca.densify(test) for test in tests), jtr, H, ca.densify(g), G]
    return ca.Function("expressions", [z, p, lam_g], outputs), H.sparsity()


def _windows() -> dict[str, WindowProblem]:
    """Window problems of the UISE, standard MHE and two-stage UISE on three models, and problems made from them."""
    system, reduced, scenario = crop_growth.system(), crop_growth.reduction(), crop_growth.DEFAULT_SCENARIO
    prior = scenario.x0
    henon = runpy.run_path(str(EXAMPLES / "chaotic_message.py"))["build"]()
    example = linear.example()
    estimators = {
        "crop UISE": UISE(system, weights=UISEWeights.from_scales(system, 0.48), N=6, x0_prior=prior),
        "crop MHE": StandardMHE(system, weights=MHEWeights.from_scales(system, 0.48), N=6, x0_prior=prior),
        "crop two-stage": TwoStageUISE(
            reduced, weights=TwoStageWeights.from_scales(reduced, 0.48), N=6, x0_prior=prior
        ),
        "Henon UISE": UISE(henon, weights=UISEWeights.from_scales(henon, 0.6), N=4, x0_prior=[0.1, 0.1]),
        "linear MHE": StandardMHE(example, weights=MHEWeights.from_scales(example, 0.5), N=4),
    }
    windows = {name: estimator._cached(estimator.N).problem for name, estimator in estimators.items()}
    crop = windows["crop UISE"]
    fixed = copy.copy(crop)  # two states pinned (lbx == ubx), as a node the data fix
    fixed.lbx, fixed.ubx = np.array(crop.lbx, dtype=float), np.array(crop.ubx, dtype=float)
    fixed.lbx[[0, 1]] = fixed.ubx[[0, 1]] = 0.5 * (fixed.lbx[[0, 1]] + fixed.ubx[[0, 1]])
    windows["crop UISE, fixed variables"] = fixed
    open_rows = copy.copy(windows["crop two-stage"])  # rows bounded on one side only
    open_rows.lbg, open_rows.ubg = np.array(open_rows.lbg, dtype=float), np.array(open_rows.ubg, dtype=float)
    open_rows.lbg[::2], open_rows.ubg[1::3] = -np.inf, np.inf
    windows["crop two-stage, one-sided rows"] = open_rows
    windows["no constraints"] = WindowProblem(example, 0, [0], output_constraints=False)
    assert windows["no constraints"].n_con == 0
    return windows


WINDOWS = _windows()


@pytest.mark.parametrize("name", list(WINDOWS))
def test_the_compiled_terms_equal_the_expressions(name):
    problem = WINDOWS[name]
    n_par = int(problem.p.numel())
    expressions, h_sparsity = _expressions(problem)
    terms = NormalTerms(problem, flat_curvature=FLAT, violation_floor=FLOOR)
    assert terms.h_sparsity == h_sparsity
    rng = np.random.default_rng(3)
    lower, upper = np.maximum(problem.lbx, -2.0), np.minimum(problem.ubx, 2.0)
    for trial in range(12):
        z = rng.uniform(lower, upper) if trial % 4 else rng.uniform(lower - 1.0, upper + 1.0)  # some outside
        if trial % 2:  # some variables on their bounds: only the outward part of s counts there
            on = rng.integers(0, z.size, z.size // 3)
            z[on] = np.where(rng.random(on.size) < 0.5, lower[on], upper[on])
        p, lam_g = rng.uniform(-1.0, 1.0, n_par), 10.0 * rng.normal(size=problem.n_con)
        expected = [np.asarray(out.nonzeros()) for out in expressions(z, p, lam_g)]
        got = terms(trial % 2, z, p, lam_g)
        for want, have in zip(expected, got[2:], strict=True):  # after z and the slot
            np.testing.assert_allclose(
                np.atleast_1d(have), want, rtol=1e-12, atol=1e-12 * (1 + np.abs(want).max(initial=0.0))
            )


def test_the_two_slots_keep_their_own_arrays():
    problem = WINDOWS["crop UISE"]
    n_par = int(problem.p.numel())
    terms = NormalTerms(problem, flat_curvature=FLAT, violation_floor=FLOOR)
    z = np.clip(np.zeros(problem.n_var), problem.lbx, problem.ubx)
    first = terms(0, z, np.zeros(n_par), np.zeros(problem.n_con))
    kept = [array.copy() for array in (first.q, first.h, first.g, first.a)]
    terms(1, np.clip(z + 0.5, problem.lbx, problem.ubx), np.ones(n_par), np.zeros(problem.n_con))
    for array, before in zip((first.q, first.h, first.g, first.a), kept, strict=True):
        np.testing.assert_array_equal(array, before)


def test_a_point_where_the_model_is_not_finite_has_undefined_tests():
    """A NaN state makes ``|r|^2``, the violations and the KKT measure NaN, so that the merit rejects the point.

    As CasADi expressions, ``fmax`` and ``mmax`` drop NaN: the violation was the other rows' alone.
    """
    problem = WINDOWS["Henon UISE"]
    n_par = int(problem.p.numel())
    terms = NormalTerms(problem, flat_curvature=FLAT, violation_floor=FLOOR)
    z = np.clip(np.full(problem.n_var, 0.1), problem.lbx, problem.ubx)
    z[0] = np.nan
    got = terms(0, z, np.zeros(n_par), np.zeros(problem.n_con))
    assert np.isnan([got.cost, got.violation, got.worst, got.stationarity]).all()
    expressions, _ = _expressions(problem)
    assert np.isfinite(float(expressions(z, np.zeros(n_par), np.zeros(problem.n_con))[1]))
