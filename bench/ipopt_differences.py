"""Where a backend's window optimum differs from IPOPT's: cost excess, distance, and the Hessian along the difference.

Run: ``python bench/ipopt_differences.py [-N 30] [--steps 100] [--solver gn-riccati] [--estimator UISE]``. On the
noisy crop scenario of ``uiest bench`` (seed 1, same estimators and weights), the estimator runs with the backend
in closed loop; every full-length window is re-solved by IPOPT from the same start, as the bench's
``windows_dev_above_1e-6`` does. For each window whose last node differs from IPOPT's by more than 1e-6 (scaled
units, the bench's measure), printed: that distance, the largest distance over the whole window, the cost excess
``cost - cost_ipopt`` (absolute, the issue's "IPOPT's cost + 1e-8", and relative ``/(1 + cost_ipopt)``, the bench's
``windows_cost_above_1e-8``), the difference at the last node as a unit vector, and the Gauss-Newton Hessian
``2 J^T J`` at IPOPT's optimum reduced to the null space of the dynamics' Jacobian: its smallest and largest
eigenvalues, the Rayleigh quotient along the difference (its null-space part) and the cost change that curvature
predicts, ``1/2 d^T H d``. A difference along a direction the cost is flat in has a Rayleigh quotient near the
smallest eigenvalue and a predicted change below the stopping tolerances.
"""

from __future__ import annotations

import argparse
import os

import casadi as ca
import numpy as np

from uiest import simulate
from uiest.experiments.solver_bench import _builders, _record_full_windows
from uiest.models import crop_growth
from uiest.window import IpoptSolver


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("-N", type=int, default=30)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--solver", default="gn-riccati")
    parser.add_argument("--estimator", default="UISE", help="UISE, two-stage UISE or standard MHE")
    args = parser.parse_args()
    system = crop_growth.system()
    scenario = crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, args.steps, w=crop_growth.UnknownInputLaw(), v=scenario.noise(), seed=1)
    build = _builders(system, crop_growth.reduction(), scenario.prior(traj.y[0]))[args.estimator]
    estimator = build(args.solver, args.N)
    recorder = _record_full_windows(estimator, args.N)
    estimator.run(traj.u[: args.steps], traj.y[: args.steps + 1])
    problem = recorder.problem
    jacobians = ca.Function("window_jacobians", [problem.z, problem.p],
                            [ca.densify(ca.jacobian(problem.r, problem.z)),
                             ca.densify(ca.jacobian(problem.g[: problem.n_dyn], problem.z))])  # fmt: skip
    reference = IpoptSolver(problem)
    last = problem.x_index[-1]
    print(f"load {os.getloadavg()[0]:.2f}; {args.estimator}, {args.solver}, N = {args.N}; nx = {problem.model.nx}")
    print(
        " k  last-node dev  window dev  cost excess   relative   unit difference at x_N      "
        "eig min     eig max    Rayleigh   1/2 dHd   off null space"
    )
    counts = {"dev": 0, "abs": 0, "rel": 0, "compared": 0}
    for index, (z0, p, solution) in enumerate(recorder.calls):
        if not solution.success:
            continue
        ipopt = reference.solve(z0, p)
        if not ipopt.success:
            continue
        counts["compared"] += 1
        d = solution.z - ipopt.z
        dev = float(np.abs(d[last]).max())
        excess = solution.cost - ipopt.cost
        counts["abs"] += int(excess > 1e-8)
        counts["rel"] += int(excess / (1.0 + ipopt.cost) > 1e-8)
        if dev <= 1e-6:
            continue
        counts["dev"] += 1
        J, G = (np.asarray(m) for m in jacobians(ipopt.z, p))
        _, sv, vt = np.linalg.svd(G)
        Z = vt[int(np.sum(sv > 1e-12 * sv[0])) :].T  # null space of the dynamics' Jacobian
        reduced = Z.T @ (2.0 * J.T @ J) @ Z
        eig = np.linalg.eigvalsh(reduced)
        c = Z.T @ d
        rayleigh = float(c @ reduced @ c / (c @ c))
        off = float(np.linalg.norm(d - Z @ c) / np.linalg.norm(d))
        unit = d[last] / np.linalg.norm(d[last])
        relative = excess / (1 + ipopt.cost)
        print(f"{index + args.N:3d} {dev:13.2e} {np.abs(d).max():11.2e} {excess:12.2e} {relative:10.2e}  "
              f"{np.array2string(unit, precision=3, suppress_small=True):26s} {eig[0]:10.2e} {eig[-1]:10.2e} "
              f"{rayleigh:10.2e} {0.5 * c @ reduced @ c:9.1e} {off:9.1e}")  # fmt: skip
    print(f"windows compared {counts['compared']}: last node beyond 1e-6 {counts['dev']}, cost above IPOPT's + 1e-8 "
          f"(absolute) {counts['abs']}, relative (/(1 + cost)) above 1e-8 {counts['rel']}")  # fmt: skip


if __name__ == "__main__":
    main()
