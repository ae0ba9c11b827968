"""The Gauss-Newton backend against the IPOPT reference, and its fallbacks."""

import numpy as np
import pytest

from uiest import simulate
from uiest.estimators import UISE, MHEWeights, StandardMHE, UISEWeights
from uiest.models import crop_growth, get
from uiest.window import gauss_newton


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
    assert gn.failures == 0 and set(gn.status[1:]) <= {"Converged", "Converged (regularised)"}
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


def test_failed_qp_falls_back_to_regularised_then_ipopt(crop_run, monkeypatch):
    system, traj, prior = crop_run
    calls = {"n": 0}
    real_step = gauss_newton.GaussNewtonSolver._step

    def failing(self, z, p, regularise):
        calls["n"] += 1
        if regularise == 0.0 or calls["n"] % 2 == 0:
            return None, np.zeros(self.problem.n_con), 0.0, float("nan")
        return real_step(self, z, p, regularise)

    monkeypatch.setattr(gauss_newton.GaussNewtonSolver, "_step", failing)
    weights = UISEWeights.from_scales(system, 0.48, output=1e6)
    result = UISE(system, weights=weights, N=5, x0_prior=prior, solver="gn").run(traj.u[:10], traj.y[:11])
    statuses = set(result.status[1:])
    assert any("regularised" in s for s in statuses) or any("ipopt" in s for s in statuses)

    def always_failing(self, z, p, regularise):
        return None, np.zeros(self.problem.n_con), 0.0, float("nan")

    monkeypatch.setattr(gauss_newton.GaussNewtonSolver, "_step", always_failing)
    result = UISE(system, weights=weights, N=5, x0_prior=prior, solver="gn").run(traj.u[:10], traj.y[:11])
    assert all(s.startswith("gn QP failed -> ipopt") for s in result.status[1:])
    assert result.failures == 0
