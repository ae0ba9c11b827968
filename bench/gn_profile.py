"""Where a Gauss-Newton sample's CPU goes: the QP, the CasADi evaluations, and the Python around them.

Run: ``python bench/gn_profile.py [-N 30] [--steps 300] [--solver gn-riccati] [--estimator UISE]``. On the
noisy crop scenario (seed 1, the estimators and weights of ``uiest bench``), each window estimator runs the
record once untimed (numba's cache, the problems' construction), then once timed with the chosen Gauss-Newton
backend (``gn``: qrqp; ``gn-riccati``: the stage-wise kernel). Over the samples with full windows (k >= N),
``time.thread_time`` times every call of a CasADi Function through :class:`~uiest.window.buffered.BufferedFunction`
by the Function's name (``gn_qp`` is qrqp, ``gn_model_terms`` the point's ``r, J, g, G``; the buffer's Python
copies included), every call of the compiled pass that forms ``J^T J``, ``J^T r`` and the tests from them
(``normal terms``), every call of the compiled QP (``riccati kernel``: the scatter, guess, kernel and multipliers in
one compiled call), the Python of :meth:`~uiest.window.stage_qp.StageForm.solve` around it (``QP wrapper``), and
the whole step. Printed per estimator: CPU per sample and its share of the step for
each, calls per sample, CPU per call; the QP's iterations (qrqp's active-set changes, or the kernel's active-set
steps and interior-point iterations) per QP and in each solve's first QP; and the rest of the step (``Python,
rest``: the estimator's step, the window shift, the parameters, the Gauss-Newton loop, the result's bookkeeping)
against issue 38's :data:`PYTHON_TARGET`. The timers' own bookkeeping is timed and taken out of the step.
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
from uiest.window import buffered, normal_terms, stage_qp

PYTHON_TARGET = 0.1
"""Issue 38's target for the Python outside the QP and CasADi, ms per full-window sample at N = 30."""

KERNEL = "riccati kernel"
"""The name the compiled stage-wise QP's calls (scatter, guess, kernel, multipliers) are reported under."""

TERMS = "normal terms"
"""The name the compiled pass of :mod:`uiest.window.normal_terms` is reported under."""

WRAPPER = "QP wrapper"
"""The Python of :meth:`~uiest.window.stage_qp.StageForm.solve` around the compiled QP."""


class _Timer:
    """Times BufferedFunction and kernel calls (while installed) and an estimator's steps; only samples k >= N."""

    def __init__(self) -> None:
        self.on = False
        self.cpu: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self.qp_iterations: list[tuple[int, int]] = []  # (active-set steps or qrqp's changes, interior-point its)
        self.first_qp_iterations: list[tuple[int, int]] = []
        self.steps, self.step_cpu, self.overhead = 0, 0.0, 0.0
        self._first = False
        self._call = buffered.BufferedFunction.__call__
        self._kernel = stage_qp._solve_form
        self._stage_solve = stage_qp.StageForm.solve
        self._terms = normal_terms._terms

    def _record(self, name: str, start: float, end: float, iterations: tuple[int, int] | None) -> None:
        self.cpu[name] += end - start
        self.calls[name] += 1
        if iterations is not None:
            self.qp_iterations.append(iterations)
            if self._first:
                self.first_qp_iterations.append(iterations)
                self._first = False

    def __enter__(self) -> _Timer:
        call, kernel, stage_solve, terms, timer = self._call, self._kernel, self._stage_solve, self._terms, self

        def timed(function: buffered.BufferedFunction, *args: Any) -> list[np.ndarray]:
            start = time.thread_time()
            out = call(function, *args)
            if timer.on:
                end = time.thread_time()
                name = function.function.name()
                changes = (int(function.stats().get("iter_count", 0)), 0) if name == "gn_qp" else None
                timer._record(name, start, end, changes)
                timer.overhead += time.thread_time() - end  # the bookkeeping, taken out of the step's CPU
            return out

        def timed_kernel(*args: Any) -> int:
            start = time.thread_time()
            code: int = kernel(*args)
            if timer.on:
                end = time.thread_time()
                info = args[-1]  # cost, interior-point iterations, residual, exact, active-set steps
                timer._record(KERNEL, start, end, (int(info[4]), int(info[1])))
                timer.overhead += time.thread_time() - end
            return code

        def timed_terms(*args: Any) -> None:
            start = time.thread_time()
            terms(*args)
            if timer.on:
                end = time.thread_time()
                timer._record(TERMS, start, end, None)
                timer.overhead += time.thread_time() - end

        def timed_stage_solve(form: stage_qp.StageForm, *args: Any, **kwargs: Any) -> Any:
            start, kernel_before = time.thread_time(), timer.cpu[KERNEL]
            out = stage_solve(form, *args, **kwargs)
            if timer.on:
                end = time.thread_time()
                timer.cpu[WRAPPER] += end - start - (timer.cpu[KERNEL] - kernel_before)
                timer.calls[WRAPPER] += 1
                timer.overhead += time.thread_time() - end
            return out

        buffered.BufferedFunction.__call__ = timed  # type: ignore[method-assign]
        stage_qp._solve_form = timed_kernel
        stage_qp.StageForm.solve = timed_stage_solve  # type: ignore[method-assign]
        normal_terms._terms = timed_terms
        return self

    def __exit__(self, *exc: object) -> None:
        buffered.BufferedFunction.__call__ = self._call  # type: ignore[method-assign]
        stage_qp._solve_form = self._kernel
        stage_qp.StageForm.solve = self._stage_solve  # type: ignore[method-assign]
        normal_terms._terms = self._terms

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


def _report(name: str, timer: _Timer, solver: str) -> None:
    per_step = 1e3 * (timer.step_cpu - timer.overhead) / timer.steps
    print(f"\n{name}: {per_step:.3f} ms per sample, mean of {timer.steps} samples (timing's bookkeeping taken out)")
    for function in sorted(timer.cpu, key=timer.cpu.get, reverse=True):  # type: ignore[arg-type]
        ms = 1e3 * timer.cpu[function] / timer.steps
        calls = timer.calls[function] / timer.steps
        print(f"  {function:16s} {ms:7.3f} ms {100 * ms / per_step:5.1f} %  {calls:5.2f} calls  "
              f"{1e3 * ms / calls:7.1f} us/call")  # fmt: skip
    rest = per_step - 1e3 * sum(timer.cpu.values()) / timer.steps
    verdict = "within" if rest <= PYTHON_TARGET else "above"
    print(f"  {'Python, rest':16s} {rest:7.3f} ms {100 * rest / per_step:5.1f} %  "
          f"({verdict} the target of {PYTHON_TARGET} ms)")  # fmt: skip
    if WRAPPER in timer.cpu:
        outside = rest + 1e3 * timer.cpu[WRAPPER] / timer.steps
        print(f"  Python outside the kernel and CasADi (rest + QP wrapper): {outside:.3f} ms")
    if not timer.qp_iterations:
        return
    steps, interior = np.mean(timer.qp_iterations, axis=0)
    first_steps, first_interior = np.mean(timer.first_qp_iterations, axis=0)
    if solver == "gn":
        print(f"  qrqp active-set changes: {steps:.1f} per QP, {first_steps:.1f} in a solve's first QP")
    else:
        print(f"  kernel: {steps:.1f} active-set steps and {interior:.1f} interior-point iterations per QP, "
              f"{first_steps:.1f} and {first_interior:.1f} in a solve's first QP")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("-N", type=int, default=30, help="window length")
    parser.add_argument("--steps", type=int, default=300, help="samples per record")
    parser.add_argument("--solver", choices=("gn-riccati", "gn"), default="gn-riccati", help="Gauss-Newton backend")
    parser.add_argument("--estimator", action="append", choices=("UISE", "two-stage UISE", "standard MHE"),
                        help="estimators to profile (repeatable; default all)")  # fmt: skip
    args = parser.parse_args()
    N, steps, solver = args.N, args.steps, args.solver
    system, reduced, scenario = crop_growth.system(), crop_growth.reduction(), crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, steps, w=crop_growth.UnknownInputLaw(), v=scenario.noise(), seed=1)
    prior = scenario.prior(traj.y[0])
    builders = {
        "UISE": lambda: UISE(system, weights=UISEWeights.from_scales(system, 0.48, output=1e6), N=N,
                             x0_prior=prior, solver=solver),
        "two-stage UISE": lambda: TwoStageUISE(reduced, weights=TwoStageWeights.from_scales(reduced, 0.48, output=1e6),
                                               N=N, x0_prior=prior, solver=solver),
        "standard MHE": lambda: StandardMHE(system, weights=MHEWeights.from_scales(system, 0.48, output=1e6), N=N,
                                            x0_prior=prior, solver=solver),
    }  # fmt: skip
    chosen = args.estimator or list(builders)
    print(f"load average {os.getloadavg()[0]:.2f}; {solver}, N = {N}, {steps} samples, CPU of samples k >= N")
    for name in chosen:
        estimator = builders[name]()
        estimator.run(traj.u, traj.y)  # untimed: builds the problems, loads the kernel
        with _Timer() as timer:
            timer.wrap(estimator, N)
            estimator.run(traj.u, traj.y)
        _report(name, timer, solver)


if __name__ == "__main__":
    main()
