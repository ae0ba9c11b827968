"""The solver bench's long-horizon protocol (short windows here, so that it runs in seconds)."""

import math

import pytest

from uiest.experiments.solver_bench import SAME_WINDOW_CAP, bench_window_solvers

pytestmark = pytest.mark.slow


def test_long_horizon_protocol_times_ipopt_on_a_capped_set_of_gn_windows():
    records = bench_window_solvers(horizons=(8,), long_horizon=8)
    solvers = ("gn", "rti", "gn-riccati", "ipopt")
    assert [(r["estimator"], r["solver"]) for r in records] == [
        (name, solver) for name in ("UISE", "two-stage UISE", "standard MHE") for solver in solvers
    ]
    for r in records:
        # 300 samples (k = 0 .. 300), 8 of them warm-up: the fast backends are timed in closed loop on 293
        assert math.isnan(r["closed_loop_dev_vs_ipopt"])
        if r["solver"] == "ipopt":
            assert r["protocol"] == f"{SAME_WINDOW_CAP} of gn's windows" and r["samples"] == SAME_WINDOW_CAP
            assert r["cpu_ratio_vs_ipopt"] == 1.0 and r["failures"] == 0
        else:
            assert r["protocol"] == "closed loop" and r["samples"] == 293
            assert r["windows_compared"] == SAME_WINDOW_CAP
            assert r["median_dev_vs_ipopt"] <= r["max_dev_vs_ipopt"]
    gn = [r for r in records if r["solver"] in ("gn", "gn-riccati")]
    assert all(r["failures"] == 0 and r["max_cost_excess_vs_ipopt"] <= 1e-7 for r in gn)
    assert all(r["qp_fallbacks"] == 0 for r in records)
