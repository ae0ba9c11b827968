"""Where a ``gn-riccati`` sample's kernel CPU goes: QPs per sample, the first QP's guess, interior-point iterations.

Run: ``python bench/riccati_profile.py [-N 30] [--steps 100] [--estimator UISE]``. On the noisy crop scenario
(seed 1, the estimators and weights of ``uiest bench``), each window estimator runs once with the
``gn-riccati`` backend; over the samples with full windows (k >= N), every stage-wise QP
(:meth:`~uiest.window.stage_qp.StageForm.solve`: the scatter, the kernel, the multipliers) is timed
(``time.thread_time``) and its outcome kept.
Printed per estimator: CPU per sample (the whole step) and the kernel's share, Gauss-Newton iterations and QPs
per sample, then for each sample's first QP and for the later ones: CPU per QP, how often the guessed active set
was the optimum, the active-set steps from it, and the interior-point iterations where it was not.
"""

from __future__ import annotations

import argparse
import os
import time
from typing import Any

import numpy as np

from uiest import simulate
from uiest.estimators import UISE, MHEWeights, StandardMHE, TwoStageUISE, TwoStageWeights, UISEWeights
from uiest.models import crop_growth
from uiest.window import riccati_qp, stage_qp


class _KernelTimer:
    """Times :meth:`StageForm.solve` calls (while installed) and an estimator's steps, for samples k >= N."""

    def __init__(self) -> None:
        self.on = False
        self.first = False
        self.qps: list[tuple[bool, float, bool, int, int]] = []  # (first, cpu, from guess, steps, ipm iterations)
        self.steps, self.step_cpu, self.kernel_cpu, self.gn_iterations = 0, 0.0, 0.0, 0
        self._solve = stage_qp.StageForm.solve

    def __enter__(self) -> _KernelTimer:
        solve, timer = self._solve, self

        def timed(form: stage_qp.StageForm, *args: Any, **kwargs: Any) -> Any:
            start = time.thread_time()
            out = solve(form, *args, **kwargs)
            if timer.on:
                cpu = time.thread_time() - start
                timer.kernel_cpu += cpu
                steps, iterations = form.last_counts
                guessed = iterations == 0 and steps > 0 and form.last_status == riccati_qp.QPStatus.SOLVED
                timer.qps.append((timer.first, cpu, guessed, steps, iterations))
                timer.first = False
            return out

        stage_qp.StageForm.solve = timed  # type: ignore[method-assign]
        return self

    def __exit__(self, *exc: object) -> None:
        stage_qp.StageForm.solve = self._solve  # type: ignore[method-assign]

    def wrap(self, estimator: Any, N: int) -> None:
        step = estimator.step

        def timed_step(u_prev: Any, y: Any) -> Any:
            self.on = estimator.k >= N
            self.first = self.on
            start = time.thread_time()
            out = step(u_prev, y)
            if self.on:
                self.steps += 1
                self.step_cpu += time.thread_time() - start
                self.gn_iterations += out.iterations
            self.on = False
            return out

        estimator.step = timed_step


def _summary(label: str, qps: list[tuple[bool, float, bool, int, int]]) -> str:
    if not qps:
        return f"  {label}: none"
    cpu = 1e6 * np.array([q[1] for q in qps])
    guessed = np.array([q[2] for q in qps])
    steps = np.array([q[3] for q in qps])
    ipm = np.array([q[4] for q in qps])
    cold = ipm[~guessed]
    cold_iterations = np.mean(cold) if cold.size else 0.0
    cold_cpu = np.mean(cpu[~guessed]) if cold.size else 0.0
    return (
        f"  {label}: {len(qps)} QPs, {np.mean(cpu):6.1f} us mean ({np.median(cpu):6.1f} median); guess optimal "
        f"{100 * guessed.mean():5.1f} % ({np.mean(steps):.2f} active-set steps); else "
        f"{cold_iterations:.1f} interior-point iterations, {cold_cpu:.1f} us"
    )


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("-N", type=int, default=30, help="window length")
    parser.add_argument("--steps", type=int, default=100, help="samples per record")
    parser.add_argument("--estimator", action="append", help="UISE, two-stage UISE, standard MHE (default all)")
    args = parser.parse_args()
    N, steps = args.N, args.steps
    system, reduced, scenario = crop_growth.system(), crop_growth.reduction(), crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, steps + 1, w=crop_growth.UnknownInputLaw(), v=scenario.noise(), seed=1)
    prior = scenario.prior(traj.y[0])
    builders = {
        "UISE": lambda: UISE(system, weights=UISEWeights.from_scales(system, 0.48, output=1e6), N=N,
                             x0_prior=prior, solver="gn-riccati"),
        "two-stage UISE": lambda: TwoStageUISE(reduced, weights=TwoStageWeights.from_scales(reduced, 0.48, output=1e6),
                                               N=N, x0_prior=prior, solver="gn-riccati"),
        "standard MHE": lambda: StandardMHE(system, weights=MHEWeights.from_scales(system, 0.48, output=1e6), N=N,
                                            x0_prior=prior, solver="gn-riccati"),
    }  # fmt: skip
    chosen = args.estimator or list(builders)
    print(f"load average {os.getloadavg()[0]:.2f}; N = {N}, {steps} samples, CPU of samples k >= N")
    for name in chosen:
        estimator = builders[name]()
        with _KernelTimer() as timer:
            timer.wrap(estimator, N)
            estimator.run(traj.u[:steps], traj.y[: steps + 1])
        per_step = 1e3 * timer.step_cpu / timer.steps
        kernel = 1e3 * timer.kernel_cpu / timer.steps
        print(f"\n{name}: {per_step:.3f} ms per sample ({timer.steps} samples), kernel {kernel:.3f} ms "
              f"({100 * kernel / per_step:.0f} %), {timer.gn_iterations / timer.steps:.2f} GN iterations and "
              f"{len(timer.qps) / timer.steps:.2f} QPs per sample")  # fmt: skip
        print(_summary("first QP", [q for q in timer.qps if q[0]]))
        print(_summary("later QPs", [q for q in timer.qps if not q[0]]))


if __name__ == "__main__":
    main()
