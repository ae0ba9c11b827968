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

from uiest.experiments.solver_bench import TABLE_HEADER, bench_window_solvers, table_row


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="N = 30 only, 100 samples")
    parser.add_argument("--json", help="write the records to this file")
    args = parser.parse_args()
    print(TABLE_HEADER, flush=True)
    records = bench_window_solvers(quick=args.quick, report=lambda r: print(table_row(r), flush=True))
    if args.json:
        with open(args.json, "w") as handle:
            json.dump(records, handle, indent=2)


if __name__ == "__main__":
    main()
