"""Window solver backends on the noisy crop scenario: ms per sample and deviation from IPOPT.

Run: ``python bench/window_solvers.py [--quick]``. For each estimator x backend x horizon N:
median, p95 and max solve time per sample after a warm-up of N samples, mean iterations, and
the largest deviation of the estimate from the IPOPT backend's on the same data, in scaled units
(``|x_hat - x_hat_ipopt| / x.scale``), over the steps where both report success.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from uiest import simulate
from uiest.estimators import UISE, MHEWeights, StandardMHE, UISEWeights
from uiest.models import crop_growth


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="N = 30 only, 100 samples")
    parser.add_argument("--json", help="write the records to this file")
    args = parser.parse_args()
    system = crop_growth.system()
    scenario = crop_growth.DEFAULT_SCENARIO
    steps = 100 if args.quick else 300
    traj = simulate(system, scenario.x0, steps, w=crop_growth.UnknownInputLaw(), v=scenario.noise(), seed=1)
    prior = scenario.prior(traj.y[0])
    horizons = (30,) if args.quick else (10, 30, 100)
    records = []
    print(f"{'estimator':13s} {'solver':6s} {'N':>4s} {'median ms':>10s} {'p95 ms':>8s} {'max ms':>8s} "
          f"{'iter':>5s} {'max dev':>9s} {'failures':>8s}")  # fmt: skip
    for N in horizons:
        for name in ("UISE", "standard MHE"):
            reference = None
            for solver in ("ipopt", "gn", "rti"):
                if name == "UISE":
                    weights = UISEWeights.from_scales(system, 0.48, output=1e6)
                    est = UISE(system, weights=weights, N=N, x0_prior=prior, solver=solver)
                else:
                    weights_mhe = MHEWeights.from_scales(system, 0.48, output=1e6)
                    est = StandardMHE(system, weights=weights_mhe, N=N, x0_prior=prior, solver=solver)
                result = est.run(traj.u, traj.y)
                ms = 1e3 * result.solve_time[N:]
                if reference is None:
                    reference = result
                both = result.success & reference.success
                deviation = float(np.abs((result.x_hat - reference.x_hat)[both] / system.x.scale).max(initial=0.0))
                record = {
                    "estimator": name,
                    "solver": solver,
                    "N": N,
                    "median_ms": float(np.median(ms)),
                    "p95_ms": float(np.percentile(ms, 95)),
                    "max_ms": float(ms.max()),
                    "iterations": float(result.iterations[N:].mean()),
                    "max_dev_vs_ipopt": deviation,
                    "failures": int(result.failures),
                }
                records.append(record)
                timing = f"{record['median_ms']:10.2f} {record['p95_ms']:8.2f} {record['max_ms']:8.2f}"
                print(f"{name:13s} {solver:6s} {N:4d} {timing} {record['iterations']:5.1f} {deviation:9.2e} "
                      f"{result.failures:8d}")  # fmt: skip
    if args.json:
        with open(args.json, "w") as handle:
            json.dump(records, handle, indent=2)


if __name__ == "__main__":
    main()
