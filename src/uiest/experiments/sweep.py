"""Monte Carlo sweeps over scenario parameters: serial, local processes or a Dask cluster.

The design (:class:`~uiest.experiments.sweep_design.Sweep`) gives the tasks; seeds depend only
on (scenario seed, run), so results do not depend on the number of workers or on the executor.
Workers rebuild the system and the estimators from the task (plain data); nothing compiled is
shipped.

Each finished task is written at once to ``OUT/runs/<key>.parquet`` (written to a temporary name,
then renamed), one row per estimator with the swept parameters as columns; re-running skips
tasks already stored, so an interrupted sweep resumes without recomputation or duplicates. A
stored file that cannot be read is moved to ``OUT/runs/corrupt/`` and its task computed again.
A task whose estimator raises records the error in its row; a task whose worker dies is
reported and left for the next run. ``OUT/manifest.json`` records the design, seeds, versions,
git revision and code version.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import json
import os
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow.parquet as pq

from uiest import models
from uiest.errors import OptionError
from uiest.experiments import provenance
from uiest.experiments.runner import BUILDERS, simulate_run
from uiest.experiments.scenario import Scenario
from uiest.experiments.sweep_design import SWEEPABLE, Sweep, Task, apply
from uiest.window import DEFAULT_BACKEND

__all__ = ["SWEEPABLE", "Sweep", "SweepProgress", "Task", "apply", "collect", "run_task", "sweep"]


def run_task(task: Task) -> pd.DataFrame:
    """Simulate and estimate one task; one row per estimator (errors are recorded, never raised)."""
    scenario = task.scenario
    base = {"key": task.key, **dict(task.params), "case": task.case, "run": task.run, "solver": task.solver}
    try:
        system, truth, prior = simulate_run(scenario, task.case, task.run)
    except Exception as exc:  # recorded, whatever it is
        return pd.DataFrame([{**base, "estimator": "", "error": f"{type(exc).__name__}: {exc}"}])
    names = truth.names.get("x") or tuple(f"x{i}" for i in range(system.nx))
    base["x_outside"] = int(truth.x_outside.sum())
    rows = []
    for spec in scenario.estimators:
        row: dict[str, Any] = {**base, "estimator": spec.name, "error": ""}
        try:
            estimator = BUILDERS[spec.kind](system, spec, prior, task.solver)
            result = estimator.run(truth.u, truth.y)  # type: ignore[attr-defined]
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
                   failures=int(result.failures))  # fmt: skip
        row["on_boundary"] = sum("boundary of X" in status for status in result.status)
        rows.append(row)
    return pd.DataFrame(rows)


def _store(frame: pd.DataFrame, folder: Path, key: str) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    tmp = folder / f".{key}.parquet.tmp"
    frame.to_parquet(tmp, index=False)
    os.replace(tmp, folder / f"{key}.parquet")


def _stored_keys(folder: Path) -> set[str]:
    """Keys of the readable stored tasks; unreadable files are moved to ``folder/corrupt/``."""
    keys = set()
    for path in folder.glob("*.parquet") if folder.exists() else ():
        try:
            pq.read_metadata(path)
        except Exception:  # any unreadable file: set it aside, its task is computed again
            aside = folder / "corrupt"
            aside.mkdir(exist_ok=True)
            os.replace(path, aside / f"{path.stem}.{time.time_ns()}.parquet")
            continue
        keys.add(path.stem)
    return keys


@contextlib.contextmanager
def _single_threaded_children() -> Iterator[None]:
    """One BLAS/OpenMP thread in spawned worker processes (they inherit the environment at spawn)."""
    names = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
    previous = {name: os.environ.get(name) for name in names}
    for name in names:
        os.environ.setdefault(name, "1")
    try:
        yield
    finally:
        for name, value in previous.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def _exit_with_parent(parent: int) -> None:
    """Worker initializer: a daemon thread ends the worker once its parent process is gone."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


Outcome = tuple[Task, pd.DataFrame | None, str]
"""A task, its rows (None when its worker failed) and why its worker failed ('' otherwise)."""


def _executor_results(tasks: list[Task], workers: int | None, scheduler: str | None) -> Iterator[Outcome]:
    """Run tasks and yield their outcomes as they finish (serial, processes or Dask)."""
    if scheduler is None and workers == 1:
        for task in tasks:
            yield task, run_task(task), ""
        return
    if scheduler is None:
        with (
            _single_threaded_children(),
            ProcessPoolExecutor(
                max_workers=workers or os.cpu_count(),
                mp_context=get_context("spawn"),
                initializer=_exit_with_parent,
                initargs=(os.getpid(),),
            ) as pool,  # fmt: skip
        ):
            futures: dict[Future[pd.DataFrame], Task] = {pool.submit(run_task, task): task for task in tasks}
            for future in as_completed(futures):
                yield _outcome(futures[future], future)
        return
    yield from _dask_results(tasks, workers, scheduler)


def _outcome(task: Task, future: Any) -> Outcome:
    try:
        return task, future.result(), ""
    except Exception as exc:  # the worker died (or the cluster failed): nothing of the task is stored
        return task, None, f"{type(exc).__name__}: {exc}"


def _dask_results(tasks: list[Task], workers: int | None, scheduler: str) -> Iterator[Outcome]:
    import dask
    from distributed import Client, LocalCluster
    from distributed import as_completed as dask_completed

    cluster = None
    if scheduler == "local":
        # Dask's default worker environment sets MALLOC_TRIM_THRESHOLD_=65536, which makes the
        # allocation-heavy CasADi/IPOPT window solves about 3x slower (measured: 7.2 s against
        # 2.2 s per crop run); keep its thread limits, drop the malloc setting.
        environ = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}))
        environ.pop("MALLOC_TRIM_THRESHOLD_", None)
        with dask.config.set({"distributed.nanny.pre-spawn-environ": environ}):
            cluster = LocalCluster(n_workers=workers or os.cpu_count(), threads_per_worker=1, processes=True)
    try:
        try:
            client = Client(cluster if cluster is not None else scheduler, timeout=10)
        except (OSError, TimeoutError, ValueError) as exc:
            raise OptionError(f"scheduler: no Dask scheduler answers at {scheduler!r} within 10 s ({exc})") from None
        with client:
            dask_futures = client.map(run_task, tasks, pure=False)
            by_key = {future.key: task for future, task in zip(dask_futures, tasks, strict=True)}
            for future in dask_completed(dask_futures):
                yield _outcome(by_key[future.key], future)
    finally:
        if cluster is not None:
            cluster.close()


@dataclass(frozen=True)
class SweepProgress:
    """Counts passed to the progress callback after each task."""

    done: int
    failed: int
    remaining: int
    skipped: int
    lost: int = 0
    """Tasks whose worker died: not stored, computed again by the next run."""


def sweep(
    design: Sweep,
    out: Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    solver: str = DEFAULT_BACKEND,
    progress: Callable[[SweepProgress], None] | None = None,
    max_tasks: int | None = None,
) -> pd.DataFrame:
    """Run every task of ``design`` not yet stored in ``out``; return all stored results.

    Parameters
    ----------
    design : Sweep
    out : Path
        Folder; finished tasks go to ``out/runs/<key>.parquet``, the union to ``out/results.parquet``,
        the per-point summary to ``out/summary.csv``, plots to ``out/sweep_*.png`` and the
        provenance to ``out/manifest.json``.
    workers : int, optional
        Worker processes (default: all cores; 1 with no scheduler: serial in this process).
    scheduler : str, optional
        ``"local"`` starts a ``distributed.LocalCluster``; any other value is a Dask scheduler address.
    solver : str
        Default window backend (a swept ``solver`` overrides it).
    progress : callable, optional
        Called with a :class:`SweepProgress` after each task.
    max_tasks : int, optional
        Stop after this many new tasks (the rest is left for a later call).

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
    tasks = design.tasks(solver)
    out = Path(out)
    writable_folder(out, "out")
    model = models.get(design.scenario.model).build()
    design.scenario.check_model(model.nx, model.ny)
    _write_manifest(design, out, solver, workers, scheduler)
    runs_dir = out / "runs"
    stored = _stored_keys(runs_dir)
    todo = [task for task in tasks if task.key not in stored]
    skipped = len(tasks) - len(todo)
    if max_tasks is not None:
        todo = todo[:max_tasks]
    done = failed = lost = 0
    if todo:
        for task, frame, why in _executor_results(todo, workers, scheduler):
            if frame is None:
                lost += 1
                failed += 1
                _log_lost(out, task, why)
            else:
                _store(frame, runs_dir, task.key)
                done += 1
                failed += int((frame["error"] != "").any())
            if progress is not None:
                progress(SweepProgress(done, failed, len(todo) - done - lost, skipped, lost))
    return collect(design, out, solver)


def writable_folder(folder: Path, name: str) -> None:
    """Create ``folder`` and check a file can be written there, else OptionError naming ``name``."""
    probe = Path(folder) / f".write-test-{os.getpid()}"
    try:
        Path(folder).mkdir(parents=True, exist_ok=True)
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise OptionError(f"{name}: cannot write to {folder} ({exc.strerror or exc})") from None


def _log_lost(out: Path, task: Task, why: str) -> None:
    with (out / "lost_tasks.log").open("a") as log:
        log.write(f"{dt.datetime.now(dt.UTC).isoformat(timespec='seconds')} {task.key} {task.case} run {task.run} "
                  f"{dict(task.params)}: {why}\n")  # fmt: skip


def _write_manifest(design: Sweep, out: Path, solver: str, workers: int | None, scheduler: str | None) -> None:
    """``out/manifest.json``: the design, seeds, versions, git revision, code version, machine."""
    scenario = design.scenario
    manifest = {
        "design": design.to_dict(),
        "created": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "machine": provenance.machine(),
        "solver": solver,
        "workers": workers,
        "scheduler": scheduler,
        "versions": provenance.versions(),
        "git_revision": provenance.git_revision(),
        "code_version": provenance.code_version(),
        "seeds": {"base": scenario.seed, "noise": [scenario.seed + r for r in range(scenario.runs)]},
        "tasks": len(design.tasks(solver)),
    }
    (out / "manifest.json").write_text(json.dumps(manifest, indent=2, default=str))


def collect(design: Sweep, out: Path, solver: str = DEFAULT_BACKEND) -> pd.DataFrame:
    """Union of the stored tasks of ``design`` (in task order), written to results.parquet with a summary."""
    runs_dir = out / "runs"
    frames = []
    for task in design.tasks(solver):
        path = runs_dir / f"{task.key}.parquet"
        if path.exists():
            frames.append(pd.read_parquet(path))
    if not frames:
        return pd.DataFrame()
    results = pd.concat(frames, ignore_index=True)
    results.to_parquet(out / "results.parquet", index=False)
    swept = [k for k in SWEEPABLE if (k in design.grid or k in design.ranges) and k != "estimator"]
    metrics = [c for c in results.columns if c.startswith(("rmse_", "max_abs_", "final_abs_")) or c.endswith("_ms")]
    ok = results[results["error"] == ""]
    if not ok.empty and metrics:
        summary = ok.groupby([*swept, "case", "estimator"], dropna=False)[metrics].mean().reset_index()
        summary.to_csv(out / "summary.csv", index=False)
        _plots(summary, swept, design.scenario, out)
    return results


def _plots(summary: pd.DataFrame, swept: list[str], scenario: Scenario, out: Path) -> None:
    import matplotlib.pyplot as plt

    from uiest import models

    names = models.get(scenario.model).build().x.names
    focus = f"rmse_{names[scenario.focus_state]}"
    for param in swept:
        if param in ("estimator", "solver") or not pd.api.types.is_numeric_dtype(summary[param]):
            continue
        fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
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
        fig.savefig(out / f"sweep_{param}.png", dpi=130)
        plt.close(fig)
