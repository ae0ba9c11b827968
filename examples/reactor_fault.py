"""A continuous-time reactor with a drifting actuator fault: the designed UISE beside a tuned EKF.

The model is ``examples/reactor.py`` (a CSTR, only the temperature measured, the coolant fault
as the unknown input). The UISE's weights come from its strong-detectability certificate
(``UISE.design``); the EKF treats the fault as a random walk whose variance is tuned on a
separate simulation. Both see the same record; the fault here drifts smoothly, the EKF's case.
Run ``python examples/reactor_fault.py`` to write ``examples/figures/reactor_fault.png``.
"""

from pathlib import Path

import numpy as np

from uiest import simulate
from uiest.estimators import EKF, UISE
from uiest.models import load
from uiest.plotting import save_figure

HERE = Path(__file__).resolve().parent


def run(out: Path, steps: int = 400, seed: int = 7) -> dict[str, float]:
    """Simulate the reactor, estimate with both, write ``reactor_fault.png``; return the RMS errors."""
    import matplotlib.pyplot as plt

    entry = load(HERE / "reactor.py")
    system, config = entry.build(), entry.simulation()
    record = simulate(system, config.x0, steps, u=config.u, w=config.w, v=config.noise, seed=seed)
    training = simulate(system, config.x0, steps, u=config.u, w=config.w, v=config.noise, seed=seed + 1000)
    u = record.u
    uise = UISE.design(system, x0_prior=config.x0, trials=1, steps=60)
    ekf = EKF.tuned(system, training, x0_prior=config.x0)
    results = {"UISE (designed)": uise.run(u, record.y), "EKF (tuned)": ekf.run(u, record.y)}
    t = record.t
    fig, axes = plt.subplots(3, 1, figsize=(7.5, 5.6), sharex=True)
    axes[0].plot(t, record.y[:, 0], ".", ms=2, color="0.4", label="measured T")
    axes[1].plot(t, record.x[:, 0], color="k", lw=1.3, label="true c_A")
    axes[2].plot(t[:-1], record.w[:, 0], color="k", lw=1.3, label="true fault")
    for j, (label, result) in enumerate(results.items()):
        axes[1].plot(t, result.x_hat[:, 0], color=f"C{j}", lw=1.0, ls="--", label=label)
        axes[2].plot(t[:-1], result.w_hat[:, 0], color=f"C{j}", lw=0.8, alpha=0.8, label=label)
    axes[2].set_ylim(-0.45, 0.2)
    for ax, name in zip(axes, ("temperature [-]", "concentration c_A [-]", "actuator fault [-]"), strict=True):
        ax.set_ylabel(name, fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=3, loc="lower left")
    axes[-1].set_xlabel("time [-]")
    fig.tight_layout()
    save_figure(fig, Path(out) / "reactor_fault.png")
    settled = slice(40, steps)
    metrics = {}
    for label, result in results.items():
        key = label.split()[0].lower()
        metrics[f"{key}_x_rmse"] = float(np.sqrt(np.mean(result.error(record.x)[settled] ** 2)))
        metrics[f"{key}_w_rmse"] = float(np.sqrt(np.nanmean((result.w_hat - record.w)[settled] ** 2)))
    return metrics


if __name__ == "__main__":
    print(run(HERE / "figures"))
