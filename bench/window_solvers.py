"""Window solver backends on the noisy crop scenario: ms per sample and deviation from IPOPT.

Run: ``python bench/window_solvers.py [--quick] [--json FILE]`` (the same as ``uiest bench``).
For each estimator x backend x horizon N: median, p95 and max solve time per sample after a
warm-up of N samples, the speed-up over the IPOPT backend, mean iterations, and the largest
deviation from the IPOPT backend's solution of the same windows, and of the whole runs, in scaled
units (see :mod:`uiest.experiments.solver_bench`).
"""

from __future__ import annotations

import argparse
import json

from uiest.experiments.solver_bench import bench_window_solvers


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="N = 30 only, 100 samples")
    parser.add_argument("--json", help="write the records to this file")
    args = parser.parse_args()
    header = f"{'estimator':15s} {'solver':6s} {'N':>4s} {'median ms':>10s} {'speedup':>8s} {'p95 ms':>8s}"
    print(f"{header} {'max ms':>8s} {'iter':>5s} {'window dev':>10s} {'cost exc':>9s} {'run dev':>9s} {'failures':>8s}")

    def show(r: dict[str, object]) -> None:
        print(f"{r['estimator']:15s} {r['solver']:6s} {r['N']:4d} {r['median_ms']:10.3f} {r['speedup_vs_ipopt']:8.1f} "
              f"{r['p95_ms']:8.2f} {r['max_ms']:8.2f} {r['iterations']:5.1f} {r['max_dev_vs_ipopt']:10.2e} "
              f"{r['max_cost_excess_vs_ipopt']:9.1e} {r['closed_loop_dev_vs_ipopt']:9.2e} "
              f"{r['failures']:8d}")  # fmt: skip

    records = bench_window_solvers(quick=args.quick, report=show)
    if args.json:
        with open(args.json, "w") as handle:
            json.dump(records, handle, indent=2)


if __name__ == "__main__":
    main()
