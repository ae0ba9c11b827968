"""Figures (matplotlib, non-interactive backend)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.figure import Figure

from uiest.results import Trajectory


def _label(name: str, unit: str) -> str:
    return f"{name} [{unit}]" if unit else name


def plot_trajectory(traj: Trajectory, units: dict[str, tuple[str, ...]] | None = None) -> Figure:
    """One panel per state, unknown input and output of a trajectory, against time.

    Parameters
    ----------
    traj : Trajectory
    units : mapping from "x", "w", "y" to component units, optional (axis labels).

    """
    units = units or {}
    panels = [("x", i) for i in range(traj.x.shape[1])]
    panels += [("w", i) for i in range(traj.w.shape[1])]
    panels += [("y", i) for i in range(traj.y.shape[1])]
    fig, axes = plt.subplots(len(panels), 1, figsize=(7.5, 1.7 * len(panels) + 0.6), sharex=True, squeeze=False)
    for ax, (kind, i) in zip(axes[:, 0], panels, strict=True):
        data = getattr(traj, kind)[:, i]
        t = traj.t[: data.shape[0]]
        names = traj.names.get(kind) or tuple(f"{kind}[{j}]" for j in range(getattr(traj, kind).shape[1]))
        unit = (units.get(kind) or ("",) * len(names))[i]
        ax.plot(t, data, lw=1.2, color={"x": "C0", "w": "C3", "y": "C2"}[kind])
        ax.set_ylabel(_label(names[i], unit), fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel(f"time [{traj.time_unit}]")
    fig.suptitle(f"{traj.system_name}: states, unknown input, outputs (seed {traj.seed})", fontsize=10)
    fig.tight_layout()
    return fig


def save_figure(fig: Figure, path: Path) -> Path:
    """Write ``fig`` to ``path`` (format from the suffix) and close it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path
