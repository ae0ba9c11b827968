"""CPU per step of the EKF and the UKF on six models.

Run: ``python bench/kalman_step.py [--steps 200] [--rounds 3]``. Models: ``bench/gn_models.py``'s Henon map, CSTR,
Van der Pol oscillator, pendulum and closed-form model, and the noisy crop scenario; each filter (random-walk input,
``w_variance`` 1e-2 w.scale^2, the models' priors, one measurement missing) runs the record ``--rounds`` times;
printed: the median thread CPU per step (``time.thread_time`` over the whole run, ``--steps + 1`` steps) per model
and filter, and the load. From its default ``P0`` (X's width) the UKF on the pendulum loses the angle (its estimate
sits at X's side; a BoundWarning says so): that row times a filter at X's side.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from uiest import simulate
from uiest.estimators import EKF, UKF
from uiest.models import crop_growth

sys.path.insert(0, str(Path(__file__).resolve().parent))
import gn_models  # the models of the Gauss-Newton bench


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    cases = {name: make(args.steps) for name, make in gn_models.MODELS.items()}
    system, scenario = crop_growth.system(), crop_growth.DEFAULT_SCENARIO
    traj = simulate(system, scenario.x0, args.steps, w=crop_growth.UnknownInputLaw(), v=scenario.noise(), seed=1)
    cases["crop"] = (system, traj, scenario.prior(traj.y[0]))
    print(f"load {os.getloadavg()[0]:.2f}; {args.steps + 1} steps, median of {args.rounds} runs")
    for name, (system, traj, prior) in cases.items():
        y = traj.y.copy()
        y[len(y) // 4, 0] = np.nan
        line = f"{name:12s}"
        for cls in (EKF, UKF):
            cpu = []
            for _ in range(args.rounds):
                filt = cls(system, x0_prior=prior, w_variance=1e-2 * system.w.scale**2)
                start = time.thread_time()
                filt.run(traj.u, y)
                cpu.append(time.thread_time() - start)
            line += f"  {cls.__name__} {1e3 * float(np.median(cpu)) / len(y):.3f} ms/step"
        print(line, flush=True)


if __name__ == "__main__":
    main()
