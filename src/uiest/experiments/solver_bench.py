"""Window solver backends compared on the noisy crop scenario (``uiest bench``, ``bench/window_solvers.py``)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from uiest import simulate
from uiest.estimators import UISE, MHEWeights, StandardMHE, TwoStageUISE, TwoStageWeights, UISEWeights
from uiest.models import crop_growth

SOLVERS = ("ipopt", "gn", "rti")


def bench_window_solvers(
    *, quick: bool = False, report: Callable[[dict[str, object]], None] | None = None
) -> list[dict[str, object]]:
    """One record per estimator x backend x N on the noisy crop scenario (seed 1).

    Keys: estimator, solver, N, median_ms, p95_ms, max_ms (solve time per sample after a warm-up
    of N samples), iterations (mean), max_dev_vs_ipopt (largest ``|x_hat - x_hat_ipopt| / x.scale``
    over the steps where both report success), failures. ``quick``: N = 30 only, 100 samples
    (else N in {10, 30, 100}, 300 samples). ``report(record)`` is called as records appear.
    """
    system = crop_growth.system()
    reduced = crop_growth.reduction()
    scenario = crop_growth.DEFAULT_SCENARIO
    steps = 100 if quick else 300
    traj = simulate(system, scenario.x0, steps, w=crop_growth.UnknownInputLaw(), v=scenario.noise(), seed=1)
    prior = scenario.prior(traj.y[0])
    records: list[dict[str, object]] = []
    for N in (30,) if quick else (10, 30, 100):

        def uise(solver: str, N: int = N) -> UISE:
            weights = UISEWeights.from_scales(system, 0.48, output=1e6)
            return UISE(system, weights=weights, N=N, x0_prior=prior, solver=solver)

        def two_stage(solver: str, N: int = N) -> TwoStageUISE:
            weights = TwoStageWeights.from_scales(reduced, 0.48, output=1e6)
            return TwoStageUISE(reduced, weights=weights, N=N, x0_prior=prior, solver=solver)

        def standard(solver: str, N: int = N) -> StandardMHE:
            weights = MHEWeights.from_scales(system, 0.48, output=1e6)
            return StandardMHE(system, weights=weights, N=N, x0_prior=prior, solver=solver)

        builders: dict[str, Callable[[str], object]] = {
            "UISE": uise,
            "two-stage UISE": two_stage,
            "standard MHE": standard,
        }
        for name, build in builders.items():
            reference = None
            for solver in SOLVERS:
                result = build(solver).run(traj.u, traj.y)  # type: ignore[attr-defined]
                ms = 1e3 * result.solve_time[N:]
                if reference is None:
                    reference = result
                both = result.success & reference.success
                deviation = float(np.abs((result.x_hat - reference.x_hat)[both] / system.x.scale).max(initial=0.0))
                record: dict[str, object] = {
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
                if report is not None:
                    report(record)
    return records
