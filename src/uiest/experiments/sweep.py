"""Monte Carlo sweeps over scenario parameters: serial, local processes or a Dask cluster.

The design (:class:`~uiest.experiments.sweep_design.Sweep`) gives the tasks; seeds depend only
on (scenario seed, run), so results do not depend on the number of workers or on the executor.
Workers rebuild the system and the estimators from the task (plain data); nothing compiled is
shipped.

Each finished task is written at once to ``OUT/runs/<key>.parquet`` (written to a temporary name,
then renamed), one row per estimator with the swept parameters as columns; re-running skips
tasks already stored, so an interrupted sweep resumes without recomputation or duplicates. A
stored file that cannot be read in full, or holds another task's rows, is moved to
``OUT/runs/corrupt/`` and its task computed again. A task whose estimator raises records the
error in its row (``retry_failed`` computes such tasks again); a task that kills its worker is
recorded too (:mod:`uiest.experiments.executors`); a task computed by other code (a cluster
worker with another uiest) is not stored. ``OUT/manifest.json`` records the design, seeds and,
per call, versions, git revision, code version and the model file's SHA-256 (task keys include it: an edited
model file is computed again).
"""

from __future__ import annotations

import datetime as dt
import functools
import json
import os
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from uiest import models
from uiest.atomic import remove_unwritten, storage_error, write_file, write_text
from uiest.checks import check_callable, check_flag, shown, user_stacklevel
from uiest.errors import OptionError
from uiest.experiments import executors, provenance
from uiest.experiments.runner import BUILDERS, simulate_run
from uiest.experiments.scenario import Scenario
from uiest.experiments.study_model import study_model
from uiest.experiments.sweep_design import SWEEPABLE, Sweep, Task, apply
from uiest.health import quiet_bound_warnings
from uiest.json_text import json_text
from uiest.lock import holds_folder
from uiest.paths import writable_file, writable_folder
from uiest.plotting import pyplot
from uiest.window import DEFAULT_BACKEND

if TYPE_CHECKING:
    import pandas as pd

OUTPUT_FILES = ("results.parquet", "summary.csv", "manifest.json", "lost_tasks.log")
"""Files a sweep writes into ``out`` (besides ``runs/`` and the plots); each is checked to be writable first."""

__all__ = ["SWEEPABLE", "Sweep", "SweepProgress", "Task", "apply", "collect", "run_task", "sweep"]


class CodeMismatchError(RuntimeError):
    """The worker runs other code than the sweep's: its results must not be stored under this key."""


class ModelChangedError(CodeMismatchError):
    """The model file's bytes differ from those the sweep's keys were made for (edited during the run)."""


def run_task(task: Task) -> pd.DataFrame:
    """Simulate and estimate one task; one row per estimator (errors are recorded, never raised).

    Raises :class:`CodeMismatchError` when this process runs other code than the task was made for
    (:class:`ModelChangedError` when the model file's bytes changed).
    """
    import pandas as pd

    if provenance.code_version() != task.code:
        raise CodeMismatchError(f"this worker runs code {provenance.code_version()}, the sweep {task.code}")
    if provenance.model_digest(task.scenario.model) != task.model_sha256:
        raise ModelChangedError(f"the model file {task.scenario.model} changed after the sweep started")
    scenario = task.scenario
    base = {"key": task.key, **dict(task.params), "case": task.case, "run": task.run, "solver": task.solver}
    try:
        study = study_model(scenario.model)
        system, truth, prior = simulate_run(scenario, task.case, task.run, study)
    except Exception as exc:  # recorded, whatever it is
        return pd.DataFrame([{**base, "estimator": "", "error": f"{type(exc).__name__}: {exc}"}])
    names = truth.names.get("x") or tuple(f"x[{i}]" for i in range(system.nx))
    base["x_outside"], base["v_outside"] = int(truth.x_outside.sum()), int(truth.v_outside.sum())
    rows = []
    for spec in scenario.estimators:
        row: dict[str, Any] = {**base, "estimator": spec.name, "error": ""}
        try:
            estimator = BUILDERS[spec.kind](study, spec, prior, task.solver)
            with quiet_bound_warnings():  # counted in the row
                result = estimator.run(truth.u, truth.y)
        except Exception as exc:  # recorded, whatever it is; the sweep goes on
            row["error"] = f"{type(exc).__name__}: {exc}"
            rows.append(row)
            continue
        err = np.abs(truth.x - result.x_hat)[scenario.settle :]
        for i, name in enumerate(names):
            row[f"rmse_{name}"] = float(np.sqrt((err[:, i] ** 2).mean()))
            row[f"max_abs_{name}"] = float(err[:, i].max())
            row[f"final_abs_{name}"] = float(err[-1, i])
        ms = 1e3 * result.solve_time
        row.update(mean_ms=float(ms.mean()), median_ms=float(np.median(ms)), max_ms=float(ms.max()),
                   **result.counts())  # fmt: skip
        rows.append(row)
    return pd.DataFrame(rows)


def _store(frame: pd.DataFrame, folder: Path, key: str) -> None:
    write_file(folder / f"{key}.parquet", lambda tmp: frame.to_parquet(tmp, index=False))


def _set_aside(path: Path, why: Exception) -> None:
    aside = path.parent / "corrupt"
    aside.mkdir(exist_ok=True)
    target = aside / f"{path.stem}.{time.time_ns()}.parquet"
    os.replace(path, target)
    warnings.warn(f"runs: the stored task file {path.name} could not be read ({type(why).__name__}); set aside as "
                  f"{target} and computed again", UserWarning, stacklevel=2)  # fmt: skip


def _read(path: Path) -> pd.DataFrame | None:
    """A stored task's rows, or None after moving an unreadable or mislabelled file to ``corrupt/``."""
    import pyarrow.parquet as pq

    try:
        frame = pq.read_table(path).to_pandas()
        if "key" not in frame or not (frame["key"] == path.stem).all():
            raise ValueError("rows of another task")
    except Exception as exc:  # any damage (footer, pages, contents): set it aside, the task is computed again
        _set_aside(path, exc)
        return None
    return frame


def _stored(folder: Path, keys: set[str], retry_failed: bool) -> tuple[set[str], int]:
    """(keys of the design's readable stored tasks, count of stored files of other designs or code).

    With ``retry_failed`` the stored tasks whose rows record an error count as not stored.
    """
    found, other = set(), 0
    for path in folder.glob("*.parquet"):
        if path.stem not in keys:
            other += 1
            continue
        frame = _read(path)
        if frame is not None and not (retry_failed and (frame["error"] != "").any()):
            found.add(path.stem)
    return found, other


@dataclass(frozen=True)
class SweepProgress:
    """Counts passed to the progress callback after each task."""

    done: int
    failed: int
    remaining: int
    skipped: int
    lost: int = 0
    """Tasks not computed (a cluster failure, other code on a worker, an edited model file): not stored, left for the
    next run."""
    lost_to_model_change: int = 0
    """Of the ``lost``, the tasks refused because the model file's bytes changed during the run (those finished before
    the change are stored under the earlier content's keys, not this design's as the file now is)."""


@holds_folder("out")
def sweep(
    design: Sweep,
    out: Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    solver: str = DEFAULT_BACKEND,
    progress: Callable[[SweepProgress], None] | None = None,
    max_tasks: int | None = None,
    retry_failed: bool = False,
) -> pd.DataFrame:
    """Run every task of ``design`` not yet stored in ``out``; return all stored results.

    Parameters
    ----------
    design : Sweep
    out : Path
        Folder; finished tasks go to ``out/runs/<key>.parquet``, the union to ``out/results.parquet``,
        the per-point summary to ``out/summary.csv``, plots to ``out/sweep_*.png``, the
        provenance of every call to ``out/manifest.json`` and the tasks this call lost to
        ``out/lost_tasks.log`` (an earlier call's log is removed first).
    workers : int, optional
        Worker processes (default: all cores; 1 with no scheduler: serial in this process).
    scheduler : str, optional
        ``"local"`` starts a ``distributed.LocalCluster``; any other value is a Dask scheduler address.
    solver : str
        Default window backend (a swept ``solver`` overrides it).
    progress : callable, optional
        Called with a :class:`SweepProgress` before the first task and after each task.
    max_tasks : int, optional
        Stop after this many new tasks (the rest is left for a later call).
    retry_failed : bool
        Compute again the stored tasks whose rows record an error.

    Raises
    ------
    OptionError
        Bad ``workers``, ``solver`` or ``max_tasks``, an ``out`` that cannot be written, or a
        scheduler that does not answer.

    """
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise OptionError(f"workers: expected an integer >= 1 or None (all cores), got {workers!r}")
    if max_tasks is not None and (isinstance(max_tasks, bool) or not isinstance(max_tasks, int) or max_tasks < 0):
        raise OptionError(f"max_tasks: expected an integer >= 0, got {max_tasks!r}")
    check_callable(progress, "progress")
    if not isinstance(design, Sweep):
        raise OptionError(f"design: expected a Sweep, got {shown(design)}")
    retry_failed = check_flag(retry_failed, "retry_failed")
    tasks = design.tasks(solver)
    out = Path(out)
    runs_dir = out / "runs"
    if runs_dir.exists() and not runs_dir.is_dir():
        raise OptionError(f"out: {runs_dir} is a file; expected a folder for the stored tasks")
    writable_folder(runs_dir, "out")
    for name in OUTPUT_FILES:
        writable_file(out / name, "out")
    model = models.load(design.scenario.model).build()
    design.scenario.check_model(model.nx, model.ny, model.x.bounds)
    stored, other = _stored(runs_dir, {task.key for task in tasks}, retry_failed)
    todo = [task for task in tasks if task.key not in stored]
    skipped = len(tasks) - len(todo)
    if max_tasks is not None:
        todo = todo[:max_tasks]
    _write_manifest(design, out, solver, workers, scheduler, new=len(todo), other=other)
    remove_unwritten([out / "lost_tasks.log"], ())  # the log lists this run's lost tasks only
    done = failed = lost = model_lost = 0
    if progress is not None:
        progress(SweepProgress(0, 0, len(todo), skipped))
    for task, frame, why in executors.results(todo, run_task, workers, scheduler):
        if frame is None or not (frame["key"] == task.key).all():
            lost += 1
            _log_lost(out, task, why or "its rows carry another key (other code on the worker)")
            model_lost += why.startswith(f"{ModelChangedError.__name__}:")  # the executors' "Type: message"
        else:
            _store(frame, runs_dir, task.key)
            done += 1
            failed += int((frame["error"] != "").any())
        if progress is not None:
            progress(SweepProgress(done, failed, len(todo) - done - lost, skipped, lost, model_lost))
    if model_lost:
        _warn_model_changed(design.scenario.model, done, model_lost, lost - model_lost)
    return collect(design, out, solver)


def _warn_model_changed(model: str, done: int, refused: int, other: int) -> None:
    """Warn that ``model`` (a file) changed during a run: ``done`` tasks stored, ``refused`` lost to the change."""
    before = (f", and the {done} task{'s' * (done != 1)} finished before it {'are' if done != 1 else 'is'} stored for "
              "the file's earlier content, not for the file as it is now") if done else ""  # fmt: skip
    others = (f"; {other} more task{'s were' if other != 1 else ' was'} lost for another reason (see lost_tasks.log)"
              if other else "")  # fmt: skip
    refusal = f"the {refused} tasks begun after it were refused" if refused != 1 else "1 task begun after it was" \
        " refused"  # fmt: skip
    warnings.warn(
        f"the model file {model} changed during the run: {refusal}{before}{others}; run the same command again to "
        "compute the design for the file as it is now",
        UserWarning,
        stacklevel=user_stacklevel(),
    )


def _log_lost(out: Path, task: Task, why: str) -> None:
    path = out / "lost_tasks.log"
    try:
        with path.open("a") as log:
            log.write(f"{dt.datetime.now(dt.UTC).isoformat(timespec='seconds')} {task.key} {task.case} run "
                      f"{task.run} {dict(task.params)}: {why}\n")  # fmt: skip
    except OSError as exc:
        raise storage_error(exc, path) from None


def _write_manifest(
    design: Sweep, out: Path, solver: str, workers: int | None, scheduler: str | None, *, new: int, other: int
) -> None:
    """``out/manifest.json``: the design and seeds, and one record per call (versions, code, machine)."""
    path = out / "manifest.json"
    try:
        calls = json.loads(path.read_text()).get("calls", [])
    except (OSError, ValueError, AttributeError):
        calls = []
    scenario = design.scenario
    calls.append({
        **provenance.stamp(), "solver": solver, "workers": workers, "scheduler": scheduler, "new_tasks": new,
        "stored_for_other_designs_or_code": other, "model_sha256": provenance.model_digest(scenario.model),
    })  # fmt: skip
    manifest = {
        "design": design.to_dict(),
        "model": {"name": scenario.model, "sha256": provenance.model_digest(scenario.model)},
        "solver": solver,
        "tasks": len(design.tasks(solver)),
        "seeds": {"base": scenario.seed, "noise": [scenario.seed + r for r in range(scenario.runs)]},
        "calls": calls,
    }
    write_text(path, json_text(manifest, default=str))


@holds_folder("out")
def collect(design: Sweep, out: Path, solver: str | None = None) -> pd.DataFrame:
    """Union of the stored tasks of ``design`` (in task order), written to results.parquet with a summary.

    ``solver`` defaults to the one ``out/manifest.json`` records (else the default backend). A
    stored file that cannot be read is set aside (its task is computed by the next sweep).
    """
    import pandas as pd

    out = Path(out)
    if solver is None:
        try:
            solver = str(json.loads((out / "manifest.json").read_text())["solver"])
        except (OSError, ValueError, KeyError, TypeError):
            solver = DEFAULT_BACKEND
    runs_dir = out / "runs"
    frames = []
    for task in design.tasks(solver):
        path = runs_dir / f"{task.key}.parquet"
        frame = _read(path) if path.exists() else None
        if frame is not None:
            frames.append(frame)
    if not frames and runs_dir.exists() and any(runs_dir.glob("*.parquet")):
        warnings.warn(
            f"{runs_dir} holds results, but none of this design with solver {solver!r}, this code version "
            f"({provenance.code_version()}) and this model file content",
            stacklevel=2,
        )
    results = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
    written = [write_file(out / "results.parquet", lambda tmp: results.to_parquet(tmp, index=False))]
    swept = [k for k in SWEEPABLE if (k in design.grid or k in design.ranges) and k != "estimator"]
    metrics = [c for c in results.columns if c.startswith(("rmse_", "max_abs_", "final_abs_")) or c.endswith("_ms")]
    ok = results[results["error"] == ""] if frames else results
    if not ok.empty and metrics:
        summary = ok.groupby([*swept, "case", "estimator"], dropna=False)[metrics].mean().reset_index()
        written.append(write_file(out / "summary.csv", lambda tmp: summary.to_csv(tmp, index=False)))
        written += _plots(summary, swept, design.scenario, out)
    stale = remove_unwritten([out / "summary.csv", *out.glob("sweep_*.png")], written)
    if stale:
        warnings.warn(
            f"out: removed {', '.join(path.name for path in stale)} from {out}: made from an earlier design's or "
            "model file's results, not from this one's",
            UserWarning,
            stacklevel=user_stacklevel(),
        )
    return results


def _plots(summary: pd.DataFrame, swept: list[str], scenario: Scenario, out: Path) -> list[Path]:
    """``out/sweep_<parameter>.png`` for each numeric swept parameter; returns their paths."""
    import pandas as pd

    names = models.load(scenario.model).build().x.names
    focus = f"rmse_{names[scenario.focus_state]}"
    written = []
    for param in swept:
        if param in ("estimator", "solver") or not pd.api.types.is_numeric_dtype(summary[param]):
            continue
        fig, axes = pyplot().subplots(1, 2, figsize=(10, 3.6))
        for (case, name), group in summary.groupby(["case", "estimator"]):
            line = group.groupby(param)[[focus, "mean_ms"]].mean()
            axes[0].plot(line.index, line[focus], marker="o", label=f"{name}, {case}")
            axes[1].plot(line.index, line["mean_ms"], marker="o", label=f"{name}, {case}")
        axes[0].set_ylabel(focus)
        axes[0].set_yscale("log")
        axes[1].set_ylabel("mean solve time per sample [ms]")
        for ax in axes:
            ax.set_xlabel(param)
            ax.grid(alpha=0.3)
        axes[0].legend(fontsize=7)
        fig.tight_layout()
        try:
            png = functools.partial(fig.savefig, dpi=130, format="png")
            written.append(write_file(out / f"sweep_{param}.png", png))
        finally:
            pyplot().close(fig)
    return written
