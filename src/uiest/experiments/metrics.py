"""Accuracy and timing metrics of a study (per case and estimator)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from uiest.experiments.runner import StudyResult
from uiest.results import count_names

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["accuracy", "health", "state_names", "timing"]

ACCURACY_COLUMNS = ("case", "estimator", "state", "rmse", "max_abs_error", "final_abs_error", "growth")
TIMING_COLUMNS = (
    "case",
    "estimator",
    "mean_cpu_ms",
    "median_cpu_ms",
    "p95_cpu_ms",
    "max_cpu_ms",
    "t_max_cpu_ms",
    "mean_ms",
    "median_ms",
    "p95_ms",
    "max_ms",
    "t_max_ms",
    "failed_steps",
)


def accuracy(study: StudyResult) -> pd.DataFrame:
    """Accuracy per (case, estimator, state) over all runs.

    RMSE and max ``|error|`` after ``settle``, the mean final ``|error|``, and the error growth (mean
    ``|error|`` over the last quarter of the run divided by the mean over the quarter after
    ``settle``; > 1: the error grows over the run).
    """
    import pandas as pd

    frame = study.steps
    if frame.empty:
        return pd.DataFrame(columns=list(ACCURACY_COLUMNS))
    scenario = study.scenario
    x_names = state_names(study)
    settled = frame[frame["k"] >= scenario.settle]
    span = scenario.steps - scenario.settle
    early = frame[(frame["k"] >= scenario.settle) & (frame["k"] < scenario.settle + max(1, span // 4))]
    late = frame[frame["k"] > scenario.steps - max(1, span // 4)]
    final = frame[frame["k"] == scenario.steps]
    rows = []
    for (case, name), group in settled.groupby(["case", "estimator"], sort=False):
        for state in x_names:
            err = np.abs(group[state] - group[f"{state}_hat"])

            def mean_abs(part: pd.DataFrame, state: str = state, case: str = case, name: str = name) -> float:
                sel = part[(part["case"] == case) & (part["estimator"] == name)]
                return float(np.abs(sel[state] - sel[f"{state}_hat"]).mean())

            rows.append(
                {
                    "case": case,
                    "estimator": name,
                    "state": state,
                    "rmse": float(np.sqrt((err**2).mean())),
                    "max_abs_error": float(err.max()),
                    "final_abs_error": mean_abs(final),
                    "growth": mean_abs(late) / max(mean_abs(early), 1e-300),
                }
            )
    return pd.DataFrame(rows)


def timing(study: StudyResult) -> pd.DataFrame:
    """Time per sample in ms per (case, estimator): CPU of the whole step, and wall-clock in the solver.

    Mean, median, p95 and max over all samples, and the paper's ``t_max``: the maximal (over
    runs) average (over samples) computation time; ``*_cpu_ms`` from the thread's CPU time of each
    whole step (what a shared machine's load does not inflate), the others from the solver's
    wall-clock time.
    """
    import pandas as pd

    frame = study.steps
    if frame.empty:
        return pd.DataFrame(columns=list(TIMING_COLUMNS))
    rows = []
    for (case, name), group in frame.groupby(["case", "estimator"], sort=False):
        ms = 1e3 * group["solve_time"].to_numpy()
        per_run = 1e3 * group.groupby("run")["solve_time"].mean()
        cpu = 1e3 * group["cpu_time"].to_numpy()
        cpu_per_run = 1e3 * group.groupby("run")["cpu_time"].mean()
        rows.append(
            {
                "case": case,
                "estimator": name,
                "mean_cpu_ms": float(np.mean(cpu)),
                "median_cpu_ms": float(np.median(cpu)),
                "p95_cpu_ms": float(np.percentile(cpu, 95)),
                "max_cpu_ms": float(np.max(cpu)),
                "t_max_cpu_ms": float(cpu_per_run.max()),
                "mean_ms": float(ms.mean()),
                "median_ms": float(np.median(ms)),
                "p95_ms": float(np.percentile(ms, 95)),
                "max_ms": float(ms.max()),
                "t_max_ms": float(per_run.max()),
                "failed_steps": int((~group["success"].astype(bool)).sum()),
            }
        )
    return pd.DataFrame(rows)


def health(study: StudyResult) -> pd.DataFrame:
    """Step counts per (case, estimator), summed over the runs that did not raise (:meth:`EstimationResult.counts`).

    ``runs`` counted, ``steps``, ``failures``, ``fallbacks`` (Gauss-Newton to IPOPT), ``at_bound`` (steps with
    some state's estimate at a side of X), ``at_bound_<state>``, ``held`` (part of the newest unknown input
    held), ``propagated`` (no data in the window), ``on_boundary`` (at a side against the data),
    ``window_at_bound`` (a window node at a side of its box).
    """
    import pandas as pd

    runs = study.runs
    columns = ["case", "estimator", "runs", *count_names(state_names(study) if study.truths else [])]
    if runs.empty or "steps" not in runs:
        return pd.DataFrame(columns=columns)
    counted = runs[runs["error"] == ""]
    rows = []
    for (case, name), group in counted.groupby(["case", "estimator"], sort=False):
        rows.append({"case": case, "estimator": name, "runs": len(group),
                     **{column: int(group[column].sum()) for column in columns[3:]}})  # fmt: skip
    return pd.DataFrame(rows, columns=columns)


def state_names(study: StudyResult) -> list[str]:
    """Names of the states, as used in the columns of ``study.steps``."""
    return list(study.model.system.x.names)  # also where no run was simulated
