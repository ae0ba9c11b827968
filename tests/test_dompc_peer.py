"""The do-mpc peer poses the same standard-MHE window problem as StandardMHE (optional: needs do-mpc)."""

from __future__ import annotations

import numpy as np
import pytest

from uiest import simulate
from uiest.estimators import MHEWeights, StandardMHE
from uiest.models import crop_growth

pytest.importorskip("do_mpc")

from uiest.experiments.dompc_peer import run_dompc_standard_mhe


def test_dompc_matches_standard_mhe_ipopt() -> None:
    system = crop_growth.system()
    scenario = crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, 40, w=crop_growth.UnknownInputLaw(), v=scenario.noise(), seed=1)
    prior = scenario.prior(traj.y[0])
    weights = MHEWeights.from_scales(system, 0.48, output=1e6)
    N = 10
    ours = StandardMHE(system, weights=weights, N=N, x0_prior=prior, solver="ipopt").run(traj.u, traj.y)
    peer = run_dompc_standard_mhe(system, weights, N, traj.u, traj.y, ours.x_hat)
    assert np.all(np.isfinite(peer.x_hat))
    assert peer.failures == 0
    assert peer.solve_time[N:].min() > 0.0
    # Measured: 7.7e-7 (closed loop over k = 10..40, units of x.scale); both solve the same NLP to
    # IPOPT tol 1e-10, so what remains is the solvers' different variables and scaling. 1e-5 leaves
    # a margin; a formulation difference shows as 1e-3..0.4 (e.g. do-mpc's hard measurement equation
    # with its noise used as our v: 0.42).
    assert peer.max_dev_vs_ipopt < 1e-5
