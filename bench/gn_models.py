"""The Gauss-Newton backend against IPOPT beyond the crop model: fallbacks, failures, CPU, agreement.

Run: ``python bench/gn_models.py [-N 10 -N 30] [--steps 200] [--solver gn-riccati]``. For each model x
estimator (UISE, standard MHE; weights from scales at mu = 0.6) x N, the Gauss-Newton backend (``gn``, qrqp's
QPs, by default; ``gn-riccati``, the stage-wise kernel's) and IPOPT run the same noisy record in
closed loop; printed per row: the Gauss-Newton backend's IPOPT fallbacks and failed samples,
IPOPT's failed samples, the median per-sample CPU time (``time.thread_time``, whole steps after N
warm-up samples) of each backend and their ratio, mean Gauss-Newton iterations, and the largest
difference of the two runs' estimates in state scales. The machine's load average is printed first.
With ``--same-window``, IPOPT also re-solves each of the Gauss-Newton backend's full-length windows from the same
start (:func:`uiest.experiments.solver_bench.same_window_deviation`), and the row adds the largest deviation of the
window's last node (state scales), the windows whose Gauss-Newton cost exceeds IPOPT's by more than 1e-8 and the
largest relative cost excess (negative: the Gauss-Newton optimum is the lower): where the two runs' estimates
differ, this says which backend found the lower cost.

Models: a noisy Henon map (x1 measured, the message w in x1), the CSTR of examples/reactor.py
(temperature measured, an actuator fault), a Van der Pol oscillator (position measured, a force
w; continuous time, sampled every 0.1), a damped pendulum (sin(angle) and rate measured, a torque
w; sampled every 0.05) and the closed-form model of :mod:`uiest.models.closed_form` (noise-free).
"""

from __future__ import annotations

import argparse
import os
import runpy
import time
from pathlib import Path
from typing import Any

import numpy as np

from uiest import System, Trajectory, UniformNoise, simulate
from uiest.estimators import UISE, MHEWeights, StandardMHE, UISEWeights
from uiest.experiments.solver_bench import _record_full_windows, same_window_deviation
from uiest.models import get, load

STEPS = 200
EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def henon(steps: int) -> tuple[System, Trajectory, np.ndarray]:
    example = runpy.run_path(str(EXAMPLES / "chaotic_message.py"))  # its build() and message()
    system = example["build"]()
    traj = simulate(system, [0.1, 0.1], steps, w=example["message"](steps), v=UniformNoise.symmetric(1e-3), seed=0)
    return system, traj, np.zeros(2)


def reactor(steps: int) -> tuple[System, Trajectory, np.ndarray]:
    entry = load(EXAMPLES / "reactor.py")
    system, setup = entry.build(), entry.simulation()
    traj = simulate(system, setup.x0, steps, u=setup.u, w=setup.w, v=setup.noise, seed=0)
    return system, traj, np.array([0.65, 1.05])


def van_der_pol(steps: int) -> tuple[System, Trajectory, np.ndarray]:
    system = System.from_ode(
        lambda x, u, w: [x[1], (1.0 - x[0] ** 2) * x[1] - x[0] + w[0]],
        lambda x, v: [x[0] + v[0]],
        nx=2, nw=1, nv=1, dt=0.1, x_bounds=((-4.0, -6.0), (4.0, 6.0)), v_bounds=(-1e-2, 1e-2),
    )  # fmt: skip
    force = lambda k, x: np.array([0.5 * np.sin(0.05 * k)])  # noqa: E731
    traj = simulate(system, [2.0, 0.0], steps, w=force, v=UniformNoise.symmetric(1e-2), seed=0)
    return system, traj, np.array([1.5, 0.5])


def pendulum(steps: int) -> tuple[System, Trajectory, np.ndarray]:
    system = System.from_ode(
        lambda x, u, w: [x[1], -9.81 * np.sin(x[0]) - 0.2 * x[1] + w[0]],
        lambda x, v: [np.sin(x[0]) + v[0], x[1] + v[1]],
        nx=2, nw=1, nv=2, dt=0.05, x_bounds=((-10.0, -20.0), (10.0, 20.0)),
        v_bounds=((-1e-2, -1e-2), (1e-2, 1e-2)),
    )  # fmt: skip
    torque = lambda k, x: np.array([2.0 * np.sign(np.sin(0.03 * k))])  # noqa: E731
    traj = simulate(system, [1.0, 0.0], steps, w=torque, v=UniformNoise.symmetric([1e-2, 1e-2]), seed=0)
    return system, traj, np.array([0.8, 0.2])


def closed_form(steps: int) -> tuple[System, Trajectory, np.ndarray]:
    entry = get("closed-form")
    system, setup = entry.build(), entry.simulation()
    traj = simulate(system, setup.x0, steps, u=setup.u, w=setup.w, seed=0)
    return system, traj, 1.1 * np.asarray(setup.x0, dtype=float)


MODELS = {"henon": henon, "reactor": reactor, "van der pol": van_der_pol, "pendulum": pendulum,
          "closed-form": closed_form}  # fmt: skip


def run(
    system: System, traj: Trajectory, prior: np.ndarray, estimator: str, N: int, solver: str, record: bool = False
) -> dict[str, Any]:
    """One closed-loop run; per-sample CPU of whole steps; ``record``: keep the full-length windows' solves."""
    if estimator == "UISE":
        est: Any = UISE(system, weights=UISEWeights.from_scales(system, 0.6), N=N, x0_prior=prior, solver=solver)
    else:
        est = StandardMHE(system, weights=MHEWeights.from_scales(system, 0.6), N=N, x0_prior=prior, solver=solver)
    recorder = _record_full_windows(est, est.N) if record else None
    step, cpu = est.step, []

    def timed(u_prev: Any, y: Any) -> Any:
        start = time.thread_time()
        out = step(u_prev, y)
        cpu.append(time.thread_time() - start)
        return out

    est.step = timed
    result = est.run(traj.u, traj.y)
    return {
        "result": result,
        "cpu_ms": 1e3 * float(np.median(cpu[N:])),
        "fallbacks": result.fallbacks,
        "recorder": recorder,
    }


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("-N", dest="horizons", type=int, action="append", help="window length (repeat; default 10 30)")
    parser.add_argument("--steps", type=int, default=STEPS, help="samples per record")
    parser.add_argument("--solver", default="gn", help="the Gauss-Newton backend: gn (qrqp) or gn-riccati")
    parser.add_argument("--same-window", action="store_true", help="IPOPT re-solves gn's full windows too")
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}; {args.steps} samples per record")
    print(f"{'model':12s} {'estimator':12s} {'N':>3s} {'gn fallb':>8s} {'gn fail':>7s} {'ipopt fail':>10s} "
          f"{'gn cpu ms':>9s} {'ipopt cpu ms':>12s} {'ratio':>6s} {'gn iter':>7s} {'max est diff':>12s}"
          + (f" {'window dev':>10s} {'cost>+1e-8':>10s} {'cost exc':>9s}" if args.same_window else ""))  # fmt: skip
    for name, make in MODELS.items():
        system, traj, prior = make(args.steps)
        for N in args.horizons or [10, 30]:
            for estimator in ("UISE", "standard MHE"):
                gn = run(system, traj, prior, estimator, N, args.solver, record=args.same_window)
                ipopt = run(system, traj, prior, estimator, N, "ipopt")
                diff = np.nanmax(np.abs(gn["result"].x_hat - ipopt["result"].x_hat) / system.x.scale)
                same = ""
                if args.same_window:
                    agreement = same_window_deviation(gn["recorder"])
                    compared = agreement["windows_compared"]
                    same = (f" {agreement['max_dev_vs_ipopt']:10.1e} "
                            f"{str(agreement['windows_cost_above_ipopt_plus_1e-8']) + '/' + str(compared):>10s} "
                            f"{agreement['max_cost_excess_vs_ipopt']:9.1e}")  # fmt: skip
                print(
                    f"{name:12s} {estimator:12s} {N:3d} {gn['fallbacks']:8d} {gn['result'].failures:7d} "
                    f"{ipopt['result'].failures:10d} {gn['cpu_ms']:9.2f} {ipopt['cpu_ms']:12.2f} "
                    f"{ipopt['cpu_ms'] / gn['cpu_ms']:6.1f} {np.mean(gn['result'].iterations):7.2f} {diff:12.1e}{same}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
