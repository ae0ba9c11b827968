"""The information horizon (:mod:`uiest.estimators.horizon`) against measurements on several models.

Run: ``python bench/information_horizon.py [--steps 150] [--no-runs]``. Per model (the crop model with the bench's
weights at mu = 0.48, output 1e6; a linear system with known zeros, the Henon map and the CSTR of examples/ with
weights from scales) and estimator (UISE, standard MHE), printed:

- the estimate: the horizon, the terms that set it and ``ratio(L)`` (smallest over largest cost term);
- the reduced Gauss-Newton Hessian of the window along the true trajectory (:mod:`uiest.window.resolution`):
  its smallest over largest eigenvalue at several L, the per-node decay rate between them (to compare with the
  discount), and the condition number of its equilibrated matrix (the smallest eigenvalue is resolved while that
  is well below 1/eps);
- unless ``--no-runs``: closed-loop runs of the gn backend at N = the horizon and at twice the horizon with the cap
  removed (the estimator's information horizon replaced by none, for this measurement only), then with the cap:
  failed samples, IPOPT fallbacks, median CPU ms per sample (``time.thread_time``, after the warm-up).

The machine's load average is printed first.
"""

from __future__ import annotations

import argparse
import os
import runpy
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

import uiest.estimators.base as base
from uiest import System, Trajectory, UniformNoise, simulate
from uiest.estimators import UISE, MHEWeights, StandardMHE, UISEWeights
from uiest.estimators.horizon import InformationHorizon
from uiest.models import crop_growth, load
from uiest.models.linear import with_invariant_zeros
from uiest.window.problem import WindowTrajectory
from uiest.window.resolution import curvature_range

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def crop(steps: int) -> tuple[System, Trajectory, np.ndarray, float, float]:
    system, scenario = crop_growth.system(), crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, steps, w=crop_growth.UnknownInputLaw(), v=scenario.noise(), seed=1)
    return system, traj, scenario.prior(traj.y[0]), 0.48, 1e6


def linear(steps: int) -> tuple[System, Trajectory, np.ndarray, float, float]:
    system = with_invariant_zeros([0.5, -0.3], x_bounds=(-10.0, 10.0), v_bounds=(-1e-3, 1e-3))[0]
    w = lambda k, x: np.array([np.sin(0.1 * k) + 0.01 * k])  # noqa: E731
    traj = simulate(system, np.full(system.nx, 0.5), steps, w=w, v=UniformNoise.symmetric(1e-3), seed=0)
    return system, traj, np.zeros(system.nx), 0.6, 1.0


def henon(steps: int) -> tuple[System, Trajectory, np.ndarray, float, float]:
    example = runpy.run_path(str(EXAMPLES / "chaotic_message.py"))
    system = example["build"]()
    traj = simulate(system, [0.1, 0.1], steps, w=example["message"](steps), v=UniformNoise.symmetric(1e-3), seed=0)
    return system, traj, np.zeros(2), 0.6, 1.0


def reactor(steps: int) -> tuple[System, Trajectory, np.ndarray, float, float]:
    entry = load(EXAMPLES / "reactor.py")
    system, setup = entry.build(), entry.simulation()
    traj = simulate(system, setup.x0, steps, u=setup.u, w=setup.w, v=setup.noise, seed=0)
    return system, traj, np.array([0.65, 1.05]), 0.6, 1.0


MODELS: dict[str, Callable[[int], tuple[System, Trajectory, np.ndarray, float, float]]] = {
    "crop": crop,
    "linear": linear,
    "henon": henon,
    "reactor": reactor,
}


def build(kind: str, system: System, mu: float, output: float, N: int, prior: np.ndarray) -> Any:
    if kind == "UISE":
        return UISE(system, weights=UISEWeights.from_scales(system, mu, output=output), N=N, x0_prior=prior)
    weights = MHEWeights.from_scales(system, mu, output=output)
    return StandardMHE(system, weights=weights, N=N, x0_prior=prior)


def measured_ratio(estimator: Any, traj: Trajectory, L: int, k: int) -> tuple[float, float]:
    """The reduced Hessian's smallest/largest eigenvalue of the window of L transitions ending at k, at the truth."""
    entry = estimator._cached(L)
    problem, start = entry.problem, k - L
    v = traj.v[problem.measured + start]
    z = problem.pack(WindowTrajectory(traj.x[start : k + 1], traj.w[start:k], v))
    y = traj.y[problem.measured + start]
    p = problem.parameters(traj.x[start], traj.u[start:k], y, v_bar=entry.v_bar, w_bar=entry.w_bar,
                           weights=entry.weights)  # fmt: skip
    found = curvature_range(problem, z, p)
    return found.ratio, found.equilibrated_condition


def run(estimator: Any, traj: Trajectory, steps: int) -> str:
    cpu: list[float] = []
    step = estimator.step

    def timed(u_prev: Any, y: Any) -> Any:
        start = time.thread_time()
        out = step(u_prev, y)
        cpu.append(time.thread_time() - start)
        return out

    estimator.step = timed
    result = estimator.run(traj.u[:steps], traj.y[: steps + 1])
    warm = estimator.N
    return (f"N used {estimator.N:3d}: failures {result.failures:3d}, fallbacks {result.fallbacks:3d}, "
            f"median cpu {1e3 * float(np.median(cpu[warm:])):.2f} ms")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--no-runs", action="store_true")
    parser.add_argument("--model", action="append", choices=list(MODELS))
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}")
    for name in args.model or list(MODELS):
        for kind in ("UISE", "standard MHE"):
            system, traj, prior, mu, output = MODELS[name](max(args.steps, 400))
            est = build(kind, system, mu, output, 1, prior)
            info = est.information_horizon
            assert info is not None and info.horizon is not None
            print(f"\n{name} {kind}: mu {mu}, {info.text()}")
            print(f"  terms: oldest {info.oldest_term} {info.oldest:.3g}, "
                  f"largest {info.largest_term} {info.largest:.3g}")  # fmt: skip
            lengths = sorted({5, 10, 20, info.horizon, min(2 * info.horizon, 60)})
            found = []
            for L in lengths:
                est_L = build(kind, system, mu, output, L, prior)
                if est_L.N != L:  # the measurement reads the window as asked for, past the cap
                    est_L = _uncapped(partial(build, kind, system, mu, output, L, prior))
                ratio, condition = measured_ratio(est_L, traj, L, L + 40)
                found.append((L, ratio))
                print(f"  L {L:3d}: estimate ratio {info.ratio(L):9.3g}, reduced Hessian {ratio:9.3g} "
                      f"(cond(A) {condition:8.2g})")  # fmt: skip
            good = [(L, r) for L, r in found if r > 0.0]
            if len(good) >= 2:
                (L0, r0), (L1, r1) = good[0], good[-1]
                print(f"  measured decay per node {L0}..{L1}: {(r1 / r0) ** (1.0 / (L1 - L0)):.4g} (discount {mu})")
            if args.no_runs:
                continue
            steps = args.steps
            for N in (info.horizon, 2 * info.horizon):
                fresh = _uncapped(partial(build, kind, system, mu, output, N, prior))
                print(f"  N {N:3d} uncapped, {run(fresh, traj, steps)}")
            print(f"  N {2 * info.horizon:3d} capped,   "
                  f"{run(build(kind, system, mu, output, 2 * info.horizon, prior), traj, steps)}")  # fmt: skip


def _uncapped(make: Callable[[], Any]) -> Any:
    """The estimator ``make()`` builds, built with no information horizon (this measurement only)."""
    original = base.information_horizon

    def none(*args: Any, **kwargs: Any) -> InformationHorizon:
        found = original(*args, **kwargs)
        return InformationHorizon(horizon=None, rate=found.rate, oldest=found.oldest, oldest_term=found.oldest_term,
                                  largest=found.largest, largest_term=found.largest_term)  # fmt: skip

    base.information_horizon = none  # type: ignore[assignment]
    try:
        return make()
    finally:
        base.information_horizon = original


if __name__ == "__main__":
    main()
