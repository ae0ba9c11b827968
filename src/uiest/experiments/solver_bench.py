"""Window solver backends compared on the noisy crop scenario (``uiest bench``, ``bench/window_solvers.py``).

Two deviations from the IPOPT backend are reported, both in the window problem's scaled units
(state scales; for the two-stage UISE the reduced state's scales), at the window's last node:

- ``max_dev_vs_ipopt``: the same window problem (same data, prior and starting point) solved
  by IPOPT from the backend's starting point, compared with the backend's solution, over the
  full-length windows where both report success: how far the backend's optimum is from IPOPT's;
  ``max_cost_excess_vs_ipopt`` is the largest ``(cost - cost_ipopt) / (1 + cost_ipopt)`` there
  (at most about 0: the backend's optimum is as good as IPOPT's; a deviation with no cost
  excess lies along a direction in which the cost is flat to IPOPT's tolerance);
- ``closed_loop_dev_vs_ipopt``: ``|x_hat - x_hat_ipopt| / x.scale`` of two whole runs, where
  each estimator's priors come from its own earlier estimates, so differences carry over.

When the optional peer do-mpc imports (``pip install uiest[peers]``), the standard MHE gets one
more record per N, solver ``"do-mpc"``: the same window problem posed in do-mpc's MHE
(:mod:`uiest.experiments.dompc_peer`), run from k = N on with our IPOPT run's estimates for
k < N. Its ``max_dev_vs_ipopt`` and ``max_cost_excess_vs_ipopt`` are NaN (do-mpc's windows are
not re-solved by our IPOPT backend); ``closed_loop_dev_vs_ipopt`` is its closed-loop deviation
over k >= N; ``iterations`` is the mean IPOPT iteration count.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from uiest import simulate
from uiest.box import FloatArray
from uiest.estimators import UISE, MHEWeights, StandardMHE, TwoStageUISE, TwoStageWeights, UISEWeights
from uiest.models import crop_growth
from uiest.window import IpoptSolver, WindowSolution, WindowSolver

SOLVERS = ("ipopt", "gn", "rti")


class _Recorder:
    """A backend that keeps every ``(z0, p, solution)`` it is asked for."""

    def __init__(self, solver: WindowSolver) -> None:
        self.solver = solver
        self.problem = solver.problem
        self.calls: list[tuple[FloatArray, FloatArray, WindowSolution]] = []

    def solve(
        self, z0: FloatArray, p: FloatArray, lam_x0: FloatArray | None = None, lam_g0: FloatArray | None = None
    ) -> WindowSolution:
        solution = self.solver.solve(z0, p, lam_x0, lam_g0)
        self.calls.append((np.array(z0, dtype=float), np.array(p, dtype=float), solution))
        return solution


def _record_full_windows(estimator: Any, N: int) -> _Recorder:
    """Wrap the estimator's solvers of its full-length window in one recorder."""
    entry = estimator._cached(N)
    recorder = _Recorder(entry.warm)
    if entry.cold is entry.warm:
        entry.cold = recorder
    entry.warm = recorder
    return recorder


def same_window_deviation(recorder: _Recorder) -> tuple[float, float]:
    """IPOPT on the recorded windows: largest last-node deviation and largest relative cost excess.

    Over the windows where both succeed: ``max |z_last - z_last_ipopt|_inf`` and
    ``max (cost - cost_ipopt) / (1 + cost_ipopt)`` (negative: the backend's optimum is lower).
    """
    problem = recorder.problem
    reference = IpoptSolver(problem)
    last = problem.x_index[-1]
    deviation, excess = 0.0, -np.inf
    for z0, p, solution in recorder.calls:
        if not solution.success:
            continue
        ipopt = reference.solve(z0, p)
        if ipopt.success:
            deviation = max(deviation, float(np.abs(solution.z[last] - ipopt.z[last]).max()))
            excess = max(excess, (solution.cost - ipopt.cost) / (1.0 + ipopt.cost))
    return deviation, float(excess) if np.isfinite(excess) else 0.0


def _dompc_available() -> bool:
    """Whether the optional peer do-mpc imports (``pip install uiest[peers]``)."""
    try:
        import do_mpc  # noqa: F401
    except ImportError:
        return False
    return True


def _dompc_record(system: Any, N: int, traj: Any, steps: int, reference: Any, reference_ms: float) -> dict[str, object]:
    """The do-mpc peer's record for the standard MHE (see :mod:`uiest.experiments.dompc_peer`)."""
    from uiest.experiments.dompc_peer import run_dompc_standard_mhe

    weights = MHEWeights.from_scales(system, 0.48, output=1e6)
    peer = run_dompc_standard_mhe(system, weights, N, traj.u[:steps], traj.y[: steps + 1], reference.x_hat)
    return {
        "estimator": "standard MHE",
        "solver": "do-mpc",
        "N": N,
        "median_ms": peer.median_ms,
        "speedup_vs_ipopt": reference_ms / peer.median_ms,
        "p95_ms": peer.p95_ms,
        "max_ms": peer.max_ms,
        "iterations": float(peer.iterations[N:].mean()),
        "max_dev_vs_ipopt": float("nan"),
        "max_cost_excess_vs_ipopt": float("nan"),
        "closed_loop_dev_vs_ipopt": peer.max_dev_vs_ipopt,
        "failures": peer.failures,
    }


def bench_window_solvers(
    *, quick: bool = False, report: Callable[[dict[str, object]], None] | None = None
) -> list[dict[str, object]]:
    """One record per estimator x backend x N on the noisy crop scenario (seed 1).

    Keys: estimator, solver, N, median_ms, speedup_vs_ipopt (the IPOPT backend's median over
    this one), p95_ms, max_ms (solve time per sample after a warm-up of N samples), iterations
    (mean), max_dev_vs_ipopt, max_cost_excess_vs_ipopt and closed_loop_dev_vs_ipopt (see the
    module docstring), failures. ``quick``: N = 30 only, 100 samples (else N in {10, 30, 100},
    300 samples, 150 for N = 100). ``report(record)`` is called as records appear.
    """
    system = crop_growth.system()
    reduced = crop_growth.reduction()
    scenario = crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, 300, w=crop_growth.UnknownInputLaw(), v=scenario.noise(), seed=1)
    prior = scenario.prior(traj.y[0])
    records: list[dict[str, object]] = []
    for N in (30,) if quick else (10, 30, 100):
        steps = 100 if quick else (300 if N <= 30 else 150)

        def uise(solver: str, N: int = N) -> UISE:
            weights = UISEWeights.from_scales(system, 0.48, output=1e6)
            return UISE(system, weights=weights, N=N, x0_prior=prior, solver=solver)

        def two_stage(solver: str, N: int = N) -> TwoStageUISE:
            weights = TwoStageWeights.from_scales(reduced, 0.48, output=1e6)
            return TwoStageUISE(reduced, weights=weights, N=N, x0_prior=prior, solver=solver)

        def standard(solver: str, N: int = N) -> StandardMHE:
            weights = MHEWeights.from_scales(system, 0.48, output=1e6)
            return StandardMHE(system, weights=weights, N=N, x0_prior=prior, solver=solver)

        builders: dict[str, Callable[[str], Any]] = {
            "UISE": uise,
            "two-stage UISE": two_stage,
            "standard MHE": standard,
        }
        for name, build in builders.items():
            reference, reference_ms = None, 0.0
            if name == "standard MHE" and _dompc_available():
                solvers: tuple[str, ...] = (*SOLVERS, "do-mpc")
            else:
                solvers = SOLVERS
            for solver in solvers:
                if solver == "do-mpc":
                    assert reference is not None
                    record = _dompc_record(system, N, traj, steps, reference, reference_ms)
                    records.append(record)
                    if report is not None:
                        report(record)
                    continue
                estimator = build(solver)
                recorder = _record_full_windows(estimator, N) if solver != "ipopt" else None
                result = estimator.run(traj.u[:steps], traj.y[: steps + 1])
                deviation, excess = (0.0, 0.0) if recorder is None else same_window_deviation(recorder)
                ms = 1e3 * result.solve_time[N:]
                if reference is None:
                    reference, reference_ms = result, float(np.median(ms))
                both = result.success & reference.success
                closed_loop = float(np.abs((result.x_hat - reference.x_hat)[both] / system.x.scale).max(initial=0.0))
                record: dict[str, object] = {
                    "estimator": name,
                    "solver": solver,
                    "N": N,
                    "median_ms": float(np.median(ms)),
                    "speedup_vs_ipopt": reference_ms / float(np.median(ms)),
                    "p95_ms": float(np.percentile(ms, 95)),
                    "max_ms": float(ms.max()),
                    "iterations": float(result.iterations[N:].mean()),
                    "max_dev_vs_ipopt": deviation,
                    "max_cost_excess_vs_ipopt": excess,
                    "closed_loop_dev_vs_ipopt": closed_loop,
                    "failures": int(result.failures),
                }
                records.append(record)
                if report is not None:
                    report(record)
    return records
