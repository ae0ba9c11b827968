"""Monte Carlo sweeps over scenario parameters: serial, local processes or a Dask cluster.

A :class:`Sweep` is a base :class:`~uiest.experiments.scenario.Scenario` and a design over
the parameters in ``SWEEPABLE`` (a full grid and/or random points). Every (design point, case,
run) is one :class:`Task`; its seeds depend only on (scenario seed, run), so results do not
depend on the number of workers or on the executor. Workers rebuild the system and the
estimators from the task (plain data); nothing compiled is shipped.

Each finished task is written at once to ``OUT/runs/<key>.parquet`` (written to a temporary name,
then renamed), one row per estimator with the swept parameters as columns; re-running skips
tasks already stored, so an interrupted sweep resumes without recomputation or duplicates.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import tomllib
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field, replace
from itertools import product
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from uiest.errors import OptionError, UiestError
from uiest.experiments.runner import BUILDERS, simulate_run
from uiest.experiments.scenario import Scenario
from uiest.window import DEFAULT_BACKEND

SWEEPABLE = ("N", "mu", "output_weight", "noise_scale", "w_gain", "initial_error", "steps", "estimator", "solver")
"""Parameters a sweep may vary: N, mu, output_weight apply to every estimator; estimator keeps only
the named one; solver selects the window backend; the rest are Scenario fields."""


@dataclass(frozen=True)
class Sweep:
    """A design over scenario parameters.

    Attributes
    ----------
    scenario : Scenario
        The base study (its runs, cases, seed and estimators).
    grid : dict
        Parameter -> list of values; the full factorial product is swept.
    random : int
        Number of additional random points, drawn (seeded by the scenario seed) uniformly from
        ``ranges`` (integers for N and steps, log-uniform for output_weight).
    ranges : dict
        Parameter -> (low, high) for the random points.

    """

    scenario: Scenario
    grid: dict[str, tuple[Any, ...]] = field(default_factory=dict)
    random: int = 0
    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name in [*self.grid, *self.ranges]:
            if name not in SWEEPABLE:
                raise OptionError(f"sweep: {name!r} cannot be swept; expected one of {SWEEPABLE}")
        if self.random < 0 or (self.random and not self.ranges):
            raise OptionError("sweep.random: expected a count >= 0, with ranges when > 0")
        names = {spec.name for spec in self.scenario.estimators}
        for value in self.grid.get("estimator", ()):
            if value not in names:
                raise OptionError(
                    f"sweep.grid.estimator: {value!r} is not an estimator of the scenario {sorted(names)}"
                )

    def points(self) -> list[dict[str, Any]]:
        """The design points: the grid product, then the random points."""
        keys = list(self.grid)
        points = [dict(zip(keys, values, strict=True)) for values in product(*(self.grid[k] for k in keys))]
        if not keys:
            points = [{}] if not self.random else []
        rng = np.random.default_rng([self.scenario.seed, 101])
        for _ in range(self.random):
            point: dict[str, Any] = {}
            for name, (low, high) in self.ranges.items():
                if name in ("N", "steps"):
                    point[name] = int(rng.integers(int(low), int(high) + 1))
                elif name == "output_weight":
                    point[name] = float(10 ** rng.uniform(math.log10(low), math.log10(high)))
                else:
                    point[name] = float(rng.uniform(low, high))
            points.append(point)
        return points

    def tasks(self, solver: str = DEFAULT_BACKEND) -> list[Task]:
        """Every (point, case, run) as a Task."""
        tasks = []
        for point in self.points():
            scenario = apply(self.scenario, point)
            for case in scenario.cases:
                for run in range(scenario.runs):
                    tasks.append(Task(scenario, tuple(sorted(point.items())), case, run, point.get("solver", solver)))
        return tasks

    @classmethod
    def from_toml(cls, path: Path) -> Sweep:
        """Read ``[scenario]`` (as in Scenario TOML) and ``[sweep]`` (``grid``, ``random``, ``ranges``)."""
        try:
            data = tomllib.loads(Path(path).read_text())
        except (OSError, tomllib.TOMLDecodeError) as exc:
            raise OptionError(f"sweep: cannot read {path}: {exc}") from exc
        unknown = set(data) - {"scenario", "sweep"}
        if unknown or "scenario" not in data:
            raise OptionError(f"sweep file: expected tables [scenario] and [sweep], got {sorted(data)}")
        design = data.get("sweep", {})
        bad = set(design) - {"grid", "random", "ranges"}
        if bad:
            raise OptionError(f"sweep: unknown keys {sorted(bad)}")
        return cls(
            Scenario.from_dict(data["scenario"]),
            grid={k: tuple(v) for k, v in design.get("grid", {}).items()},
            random=int(design.get("random", 0)),
            ranges={k: (float(v[0]), float(v[1])) for k, v in design.get("ranges", {}).items()},
        )


def apply(scenario: Scenario, point: dict[str, Any]) -> Scenario:
    """The scenario with a design point's parameters applied."""
    estimators = scenario.estimators
    spec_changes = {k: point[k] for k in ("N", "mu", "output_weight") if k in point}
    if "N" in spec_changes:
        spec_changes["N"] = int(spec_changes["N"])
    if spec_changes:
        estimators = tuple(replace(spec, **spec_changes) for spec in estimators)
    if "estimator" in point:
        estimators = tuple(spec for spec in estimators if spec.name == point["estimator"])
    fields = {k: point[k] for k in ("noise_scale", "w_gain", "initial_error") if k in point}
    if "steps" in point:
        fields["steps"] = int(point["steps"])
    return replace(scenario, estimators=estimators, **fields)


@dataclass(frozen=True)
class Task:
    """One (design point, case, run): plain data, rebuilt into a system and estimators by a worker."""

    scenario: Scenario
    params: tuple[tuple[str, Any], ...]
    case: str
    run: int
    solver: str

    @property
    def key(self) -> str:
        """Stable identifier of the task (hash of the scenario, the point, the case and the run)."""
        payload = json.dumps(
            [self.scenario.to_dict(), list(self.params), self.case, self.run, self.solver], sort_keys=True, default=str
        )
        return hashlib.sha256(payload.encode()).hexdigest()[:20]


def run_task(task: Task) -> pd.DataFrame:
    """Simulate and estimate one task; one row per estimator (errors are recorded, never raised)."""
    scenario = task.scenario
    base = {"key": task.key, **dict(task.params), "case": task.case, "run": task.run, "solver": task.solver}
    try:
        system, truth, prior = simulate_run(scenario, task.case, task.run)
    except (UiestError, RuntimeError) as exc:
        return pd.DataFrame([{**base, "estimator": "", "error": f"{type(exc).__name__}: {exc}"}])
    names = truth.names.get("x") or tuple(f"x{i}" for i in range(system.nx))
    rows = []
    for spec in scenario.estimators:
        row: dict[str, Any] = {**base, "estimator": spec.name, "error": ""}
        try:
            estimator = BUILDERS[spec.kind](system, spec, prior, task.solver)
            result = estimator.run(truth.u, truth.y)  # type: ignore[attr-defined]
        except (UiestError, RuntimeError, KeyError) as exc:
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
        rows.append(row)
    return pd.DataFrame(rows)


@dataclass(frozen=True)
class SweepProgress:
    """Counts passed to the progress callback after each task."""

    done: int
    failed: int
    remaining: int
    skipped: int


def _store(frame: pd.DataFrame, folder: Path, key: str) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    tmp = folder / f".{key}.parquet.tmp"
    frame.to_parquet(tmp, index=False)
    os.replace(tmp, folder / f"{key}.parquet")


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


def _executor_results(tasks: list[Task], workers: int | None, scheduler: str | None) -> Iterator[pd.DataFrame]:
    """Run tasks and yield their frames as they finish (serial, processes or Dask)."""
    if scheduler is None and workers == 1:
        for task in tasks:
            yield run_task(task)
        return
    if scheduler is None:
        with (
            _single_threaded_children(),
            ProcessPoolExecutor(max_workers=workers or os.cpu_count(), mp_context=get_context("spawn")) as pool,
        ):
            futures: list[Future[pd.DataFrame]] = [pool.submit(run_task, task) for task in tasks]
            for future in as_completed(futures):
                yield future.result()
        return
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
        with Client(cluster if cluster is not None else scheduler) as client:
            dask_futures = client.map(run_task, tasks, pure=False)
            for future in dask_completed(dask_futures):
                yield future.result()
    finally:
        if cluster is not None:
            cluster.close()


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
        the per-point summary to ``out/summary.csv`` and plots to ``out/sweep_*.png``.
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

    """
    runs_dir = Path(out) / "runs"
    tasks = design.tasks(solver)
    stored = {p.stem for p in runs_dir.glob("*.parquet")} if runs_dir.exists() else set()
    todo = [task for task in tasks if task.key not in stored]
    skipped = len(tasks) - len(todo)
    if max_tasks is not None:
        todo = todo[:max_tasks]
    done = failed = 0
    if todo:
        for frame in _executor_results(todo, workers, scheduler):
            _store(frame, runs_dir, str(frame["key"].iloc[0]))
            done += 1
            failed += int((frame["error"] != "").any())
            if progress is not None:
                progress(SweepProgress(done, failed, len(todo) - done, skipped))
    return collect(design, Path(out), solver)


def collect(design: Sweep, out: Path, solver: str = DEFAULT_BACKEND) -> pd.DataFrame:
    """Union of the stored tasks of ``design`` (in task order), written to results.parquet with a summary."""
    runs_dir = out / "runs"
    frames = [
        pd.read_parquet(runs_dir / f"{task.key}.parquet")
        for task in design.tasks()
        if (runs_dir / f"{task.key}.parquet").exists()
    ]
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
