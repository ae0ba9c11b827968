"""Figures (matplotlib, non-interactive backend; matplotlib is imported by the first figure, not by this module)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from uiest.atomic import write_file
from uiest.checks import check_flag, shown
from uiest.errors import DataError, OptionError
from uiest.paths import writable_file
from uiest.results import EstimationResult, Trajectory
from uiest.system import System

if TYPE_CHECKING:
    from types import ModuleType

    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = ["plot_estimates", "plot_record", "plot_trajectory", "pyplot", "robust_limits", "save_figure"]


def pyplot() -> ModuleType:
    """``matplotlib.pyplot`` with the non-interactive backend (imported here: matplotlib is heavy and optional)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _check_trajectory(traj: object) -> None:
    if not isinstance(traj, Trajectory):
        raise DataError(f"traj: expected a uiest.Trajectory (the simulated truth), got {shown(traj)}")


def _label(name: str, unit: str) -> str:
    return f"{name} [{unit}]" if unit else name


def plot_trajectory(traj: Trajectory, units: dict[str, tuple[str, ...]] | None = None) -> Figure:
    """One panel per state, unknown input and output of a trajectory, against time.

    Parameters
    ----------
    traj : Trajectory
    units : mapping from "x", "w", "y" (also "u", "v") to component units, optional (axis labels).

    """
    _check_trajectory(traj)
    if units is not None and not isinstance(units, Mapping):
        raise DataError(f"units: expected a mapping from 'x', 'w', 'y' to unit strings, got {shown(units)}")
    units = dict(units or {})
    for kind, given in units.items():
        n = getattr(traj, kind).shape[1] if kind in ("x", "u", "w", "v", "y") else None
        if n is None or isinstance(given, str) or not isinstance(given, Sequence) or len(given) != n:
            expected = f"{n} unit strings" if n is not None else 'one of the keys "x", "u", "w", "v", "y"'
            raise DataError(f"units[{kind!r}]: expected {expected}, got {given!r}")
    panels = [("x", i) for i in range(traj.x.shape[1])]
    panels += [("w", i) for i in range(traj.w.shape[1])]
    panels += [("y", i) for i in range(traj.y.shape[1])]
    fig, axes = pyplot().subplots(len(panels), 1, figsize=(7.5, 1.7 * len(panels) + 0.6), sharex=True, squeeze=False)
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
    _check_trajectory(traj)
    log_error = check_flag(log_error, "log_error")
    if not isinstance(results, Mapping) or not all(isinstance(r, EstimationResult) for r in results.values()):
        raise DataError(f"results: expected a mapping from a label to an EstimationResult, got {shown(results)}")
    for label, result in results.items():
        for name, got, truth in (("x_hat", result.x_hat, traj.x), ("w_hat", result.w_hat, traj.w)):
            if got.shape != truth.shape:
                raise DataError(
                    f"results[{label!r}].{name}: expected the shape of the truth's {name[0]}, {truth.shape}, "
                    f"got {got.shape} (a run of another system or record?)"
                )
    nx, nw = traj.x.shape[1], traj.w.shape[1]
    x_names = traj.names.get("x") or tuple(f"x[{i}]" for i in range(nx))
    w_names = traj.names.get("w") or tuple(f"w[{i}]" for i in range(nw))
    rows = nx + nw
    fig, axes = pyplot().subplots(rows, 2, figsize=(11, 1.9 * rows + 0.6), sharex=True, squeeze=False)
    for i in range(rows):
        is_x = i < nx
        truth = traj.x[:, i] if is_x else traj.w[:, i - nx]
        name = x_names[i] if is_x else w_names[i - nx]
        t = traj.t[: truth.shape[0]]
        axes[i, 0].plot(t, truth, color="k", lw=1.4, label="true")
        for j, (label, result) in enumerate(results.items()):
            estimate = result.x_hat[:, i] if is_x else result.w_hat[:, i - nx]
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


def robust_limits(ax: Axes, values: np.ndarray) -> bool:
    """Y limits from the 1st-99th percentiles widened by 20 % (a start-up transient does not set the scale).

    Returns whether some of ``values`` fall outside the limits (clipped from view).
    """
    finite = values[np.isfinite(values)]
    if finite.size < 10:
        return False
    lo, hi = np.percentile(finite, [1, 99])
    pad = 0.2 * (hi - lo) if hi > lo else max(abs(hi), 1.0) * 0.1
    ax.set_ylim(lo - pad, hi + pad)
    return bool(np.any((finite < lo - pad) | (finite > hi + pad)))


def plot_record(system: Any, record: Trajectory, results: Mapping[str, EstimationResult]) -> Figure:
    """Measured outputs beside each estimator's predicted output, then the state and unknown-input estimates.

    No truth is needed: the true states and unknown inputs are drawn where ``record`` has them.
    Axis limits are robust (1st-99th percentiles of what is drawn), so a start-up transient does
    not flatten the rest; axes carry the signals' units.
    """
    if not isinstance(system, System):
        raise DataError(f"system: expected a uiest.System, got {shown(system)}")
    _check_trajectory(record)
    units = {sig.kind: sig.units for sig in system.signals}
    panels = [("y", i) for i in range(system.ny)] + [("x", i) for i in range(system.nx)]
    panels += [("w", i) for i in range(system.nw)]
    fig, axes = pyplot().subplots(len(panels), 1, figsize=(7.5, 1.6 * len(panels) + 0.6), sharex=True, squeeze=False)
    for ax, (kind, i) in zip(axes[:, 0], panels, strict=True):
        drawn = []
        if kind == "y":
            ax.plot(record.t, record.y[:, i], ".", ms=2.5, color="0.4", label="measured")
            drawn.append(record.y[:, i])
        elif record.has_states:
            truth = getattr(record, kind)[:, i]
            ax.plot(record.t[: len(truth)], truth, color="k", lw=1.3, label="true")
            drawn.append(truth)
        for j, (label, result) in enumerate(results.items()):
            if kind == "y":
                values = system.output(result.x_hat, np.zeros(system.nv))[:, i]
            else:
                values = (result.x_hat if kind == "x" else result.w_hat)[:, i]
            ax.plot(record.t[: len(values)], values, lw=1.0, color=f"C{j}", label=label)
            drawn.append(values)
        robust_limits(ax, np.concatenate(drawn))
        ax.set_ylabel(_label(getattr(system, kind).names[i], units[kind][i]), fontsize=8)
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, ncol=min(len(results) + 1, 4))
    axes[-1, 0].set_xlabel(f"time [{record.time_unit}]")
    fig.tight_layout()
    return fig


def save_figure(fig: Figure, path: Path | str) -> Path:
    """Write ``fig`` to ``path`` (a Path or str; format from the suffix) whole or not at all, and close it."""
    from matplotlib.figure import Figure

    if not isinstance(fig, Figure):
        raise DataError(f"fig: expected a matplotlib Figure, got {shown(fig)}")
    path = Path(path)
    formats = sorted(fig.canvas.get_supported_filetypes())
    if path.suffix.lstrip(".").lower() not in formats:
        raise OptionError(f"path: expected a file name ending in one of {formats}, got {str(path)!r}")
    writable_file(path, "path")
    try:
        write_file(path, lambda tmp: fig.savefig(tmp, dpi=130, format=path.suffix.lstrip(".").lower()))
    finally:
        pyplot().close(fig)
    return path
