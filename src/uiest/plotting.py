"""Figures (matplotlib, non-interactive backend)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

from uiest.errors import DataError
from uiest.results import Trajectory

if TYPE_CHECKING:
    from uiest.estimators.results import EstimationResult


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


def plot_estimates(traj: Trajectory, results: Mapping[str, EstimationResult], *, log_error: bool = True) -> Figure:
    """Per state: the true trajectory and each estimator's estimate, and the estimation errors.

    Parameters
    ----------
    traj : Trajectory
        The simulated truth (x (K+1, nx), w (K, nw)).
    results : mapping from a label to an EstimationResult
        Runs on ``traj.u``, ``traj.y``; each must have ``x_hat`` of shape (K+1, nx).
    log_error : bool
        Plot ``|x - x_hat|`` on a log axis (else the signed error on a linear axis).

    """
    nx, nw = traj.x.shape[1], traj.w.shape[1]
    x_names = traj.names.get("x") or tuple(f"x[{i}]" for i in range(nx))
    w_names = traj.names.get("w") or tuple(f"w[{i}]" for i in range(nw))
    rows = nx + nw
    fig, axes = plt.subplots(rows, 2, figsize=(11, 1.9 * rows + 0.6), sharex=True, squeeze=False)
    for i in range(rows):
        is_x = i < nx
        truth = traj.x[:, i] if is_x else traj.w[:, i - nx]
        name = x_names[i] if is_x else w_names[i - nx]
        t = traj.t[: truth.shape[0]]
        axes[i, 0].plot(t, truth, color="k", lw=1.4, label="true")
        for j, (label, result) in enumerate(results.items()):
            estimate = result.x_hat[:, i] if is_x else result.w_hat[:, i - nx]
            if estimate.shape != truth.shape:
                raise DataError(
                    f"results[{label!r}]: expected {truth.shape[0]} samples of {name}, got {estimate.shape}"
                )
            error = truth - estimate
            axes[i, 0].plot(t, estimate, lw=1.0, ls="--", color=f"C{j}", label=label)
            axes[i, 1].plot(t, np.abs(error) if log_error else error, lw=1.0, color=f"C{j}", label=label)
        axes[i, 0].set_ylabel(name, fontsize=8)
        axes[i, 1].set_ylabel(f"|{name} error|" if log_error else f"{name} error", fontsize=8)
        if log_error:
            axes[i, 1].set_yscale("log")
        for ax in axes[i]:
            ax.tick_params(labelsize=7)
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    for ax in axes[-1]:
        ax.set_xlabel(f"time [{traj.time_unit}]")
    fig.suptitle(f"{traj.system_name}: estimates and errors", fontsize=10)
    fig.tight_layout()
    return fig


def save_figure(fig: Figure, path: Path) -> Path:
    """Write ``fig`` to ``path`` (format from the suffix) and close it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=130)
    plt.close(fig)
    return path
