"""Where a Gauss-Newton sample's CPU goes: qrqp, the fused evaluation, the other CasADi calls, and Python.

Run: ``python bench/gn_profile.py [-N 30] [--steps 300]``. On the noisy crop scenario (seed 1, the
estimators and weights of ``uiest bench``), each window estimator runs once with the ``gn`` backend;
over the samples with full windows (k >= N), every call of a CasADi Function through
:class:`~uiest.window.buffered.BufferedFunction` is timed (``time.thread_time``) by the Function's
name, beside the whole step. Printed per estimator: CPU per sample and its share of the step for each
Function (``gn_qp`` is qrqp, ``gn_evaluation`` the fused point evaluation), calls per sample, CPU per
call, qrqp's active-set changes per QP and in each solve's first QP, and the rest of the step (Python:
the estimator's step and the Gauss-Newton loop). The wrappers' bookkeeping is timed and taken out of the step.
"""

from __future__ import annotations

import argparse
import os
import time
from collections import defaultdict
from typing import Any

import numpy as np

from uiest import simulate
from uiest.estimators import UISE, MHEWeights, StandardMHE, TwoStageUISE, TwoStageWeights, UISEWeights
from uiest.models import crop_growth
from uiest.window import buffered


class _Timer:
    """Times BufferedFunction calls (while installed) and an estimator's steps; counts only samples k >= N."""

    def __init__(self) -> None:
        self.on = False
        self.cpu: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self.qp_iterations: list[int] = []
        self.first_qp_iterations: list[int] = []
        self.steps, self.step_cpu, self.overhead = 0, 0.0, 0.0
        self._first = False
        self._call = buffered.BufferedFunction.__call__

    def __enter__(self) -> _Timer:
        call, timer = self._call, self

        def timed(function: buffered.BufferedFunction, *args: Any) -> list[np.ndarray]:
            start = time.thread_time()
            out = call(function, *args)
            if timer.on:
                end = time.thread_time()
                name = function.function.name()
                timer.cpu[name] += end - start
                timer.calls[name] += 1
                if name == "gn_qp":
                    iterations = int(function.stats().get("iter_count", 0))
                    timer.qp_iterations.append(iterations)
                    if timer._first:
                        timer.first_qp_iterations.append(iterations)
                        timer._first = False
                timer.overhead += time.thread_time() - end  # the bookkeeping, taken out of the step's CPU
            return out

        buffered.BufferedFunction.__call__ = timed  # type: ignore[method-assign]
        return self

    def __exit__(self, *exc: object) -> None:
        buffered.BufferedFunction.__call__ = self._call  # type: ignore[method-assign]

    def wrap(self, estimator: Any, N: int) -> None:
        step = estimator.step

        def timed_step(u_prev: Any, y: Any) -> Any:
            self.on = estimator.k >= N
            self._first = self.on
            start = time.thread_time()
            out = step(u_prev, y)
            if self.on:
                self.steps += 1
                self.step_cpu += time.thread_time() - start
            self.on = False
            return out

        estimator.step = timed_step


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("-N", type=int, default=30, help="window length")
    parser.add_argument("--steps", type=int, default=300, help="samples per record")
    args = parser.parse_args()
    N, steps = args.N, args.steps
    system, reduced, scenario = crop_growth.system(), crop_growth.reduction(), crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, steps, w=crop_growth.UnknownInputLaw(), v=scenario.noise(), seed=1)
    prior = scenario.prior(traj.y[0])
    builders = {
        "UISE": lambda: UISE(system, weights=UISEWeights.from_scales(system, 0.48, output=1e6), N=N,
                             x0_prior=prior, solver="gn"),
        "two-stage UISE": lambda: TwoStageUISE(reduced, weights=TwoStageWeights.from_scales(reduced, 0.48, output=1e6),
                                               N=N, x0_prior=prior, solver="gn"),
        "standard MHE": lambda: StandardMHE(system, weights=MHEWeights.from_scales(system, 0.48, output=1e6), N=N,
                                            x0_prior=prior, solver="gn"),
    }  # fmt: skip
    print(f"load average {os.getloadavg()[0]:.2f}; N = {N}, {steps} samples, CPU of samples k >= N")
    for name, build in builders.items():
        estimator = build()
        with _Timer() as timer:
            timer.wrap(estimator, N)
            estimator.run(traj.u, traj.y)
        per_step = 1e3 * (timer.step_cpu - timer.overhead) / timer.steps
        print(f"\n{name}: {per_step:.3f} ms per sample, mean of {timer.steps} samples (timing's bookkeeping taken out)")
        for function in sorted(timer.cpu, key=timer.cpu.get, reverse=True):  # type: ignore[arg-type]
            ms = 1e3 * timer.cpu[function] / timer.steps
            calls = timer.calls[function] / timer.steps
            print(f"  {function:16s} {ms:7.3f} ms {100 * ms / per_step:5.1f} %  {calls:5.2f} calls  "
                  f"{1e3 * ms / calls:7.1f} us/call")  # fmt: skip
        rest = per_step - 1e3 * sum(timer.cpu.values()) / timer.steps
        print(f"  {'Python, rest':16s} {rest:7.3f} ms {100 * rest / per_step:5.1f} %")
        print(f"  qrqp active-set changes: {np.mean(timer.qp_iterations):.1f} per QP, "
              f"{np.mean(timer.first_qp_iterations):.1f} in a solve's first QP")  # fmt: skip


if __name__ == "__main__":
    main()
