"""
Studies, sweeps and Dask
========================

A *study* (:py:class:`uiest.experiments.Scenario`) runs several estimators on Monte Carlo runs of one
model; a *sweep* (:py:class:`uiest.experiments.sweep.Sweep`) repeats a study over a grid (or random
points) of its parameters: the horizon ``N``, the rate ``mu``, the noise scale, the unknown input's
gain, the run length, the estimator, the solver. Each (design point, case, run) is one task; the tasks
run serially, on local processes or on a Dask cluster, and give the same numbers on each, since every
run's seed depends only on the study's seed and the run.

This tutorial sweeps the window length and the noise level on the built-in ``closed-form`` model (a
nonlinear system whose unknown-input estimation error has a closed form) with a tiny grid, first
serially, then on a Dask ``LocalCluster``, and reads the results table. A real sweep would use the
default 20 runs of a few hundred samples each (``uiest sweep`` runs one from a TOML file).
"""

# %%
# The study and the grid
# ----------------------
# The scenario names a registered model (``uiest models`` lists them) or a model file, its run length
# and number of runs, the cases (``"noisy"``, ``"noise-free"``) and the estimators. Here: a UISE with
# explicit weights, the standard MHE (which treats the unknown input as bounded) and an EKF with a
# random-walk input model. ``noise_scale`` multiplies the model's noise; values up to 1 keep it within
# V, where the UISE's guarantee applies.
import tempfile
import time
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import tomli_w

from uiest.experiments import EstimatorSpec, Scenario
from uiest.experiments.sweep import Sweep, sweep

cpu_start = time.thread_time()
scenario = Scenario(
    name="closed-form-sweep",
    model="closed-form",
    steps=60,  # a real study: a few hundred samples
    runs=2,  # a real study: 20 or more
    cases=("noisy",),
    settle=20,  # errors are scored from k = 20 on
    estimators=(
        EstimatorSpec("UISE", "uise", N=10, mu=0.6, output_weight=1.0),
        EstimatorSpec("standard MHE", "standard-mhe", N=10, mu=0.6, output_weight=1.0),
        EstimatorSpec("EKF", "ekf", w_variance=1.0),
    ),
)
design = Sweep(scenario, grid={"N": [5, 10], "noise_scale": [0.1, 1.0]})
tasks = design.tasks()
print(len(tasks), "tasks; the first:", dict(tasks[0].params), tasks[0].case, "run", tasks[0].run)

# %%
# The same design as a file, the form ``uiest sweep FILE --out OUT`` takes (``examples/crop_sweep.toml``
# is one): a ``[scenario]`` table with the scenario's fields (:py:meth:`~uiest.experiments.Scenario.to_dict`,
# as :py:meth:`~uiest.experiments.Scenario.to_toml` writes them) and a ``[sweep]`` table with the grid
# (or ``random`` points in ``ranges``). :py:meth:`~uiest.experiments.sweep.Sweep.from_toml` reads it.
folder = Path(tempfile.mkdtemp())
text = tomli_w.dumps({"scenario": scenario.to_dict(), "sweep": {"grid": {"N": [5, 10], "noise_scale": [0.1, 1.0]}}})
(folder / "sweep.toml").write_text(text)
print(text[-120:])
from_file = Sweep.from_toml(folder / "sweep.toml")
print("same tasks:", [t.key for t in from_file.tasks()] == [t.key for t in tasks])

# %%
# Running it serially
# -------------------
# :py:func:`uiest.experiments.sweep.sweep` writes each finished task at once to ``OUT/runs/`` (so an
# interrupted sweep resumes where it stopped, computing only what is missing), and at the end
# ``results.parquet`` (one row per run and estimator), ``summary.csv`` (means per design point), a plot
# per swept parameter and ``manifest.json`` (design, seeds, versions, machine). ``workers=1`` runs in
# this process.
out = folder / "out"
t0 = time.perf_counter()
serial = sweep(design, out / "serial", workers=1)
print(f"serial: {len(serial)} rows in {time.perf_counter() - t0:.1f} s wall")
print(sorted(path.name for path in (out / "serial").iterdir()))

# %%
# The results table
# -----------------
# One row per (design point, case, run, estimator): the swept parameters as columns, the accuracy per
# state (RMSE, largest and final absolute error after ``settle``), the time per step (ms) and the step
# health counts of tutorial 5 (failures, IPOPT fallbacks, estimates at X's sides, ...). An estimator
# that raised has its message in ``error``, and the sweep goes on.
columns = ["N", "noise_scale", "run", "estimator", "rmse_x1", "rmse_x2", "median_ms", "failures", "error"]
serial[columns].sort_values(["estimator", "N", "noise_scale", "run"]).reset_index(drop=True)

# %%
# On a Dask cluster
# -----------------
# ``scheduler="local"`` starts a ``distributed.LocalCluster`` of ``workers`` processes (one thread
# each); any other value is the address of a running scheduler (``tcp://HOST:8786``), whose workers
# need the same uiest. The workers rebuild the model and the estimators from each task (plain data),
# and a worker running other code refuses the task, so results of other code are never stored. Starting
# the cluster and its worker processes (each imports uiest and builds the model) costs seconds, tens
# of seconds on a loaded machine (compare the wall times printed), which pays off for sweeps of
# minutes, not for this one. Start a cluster only under
# ``if __name__ == "__main__":``: Dask's worker processes import the main module (in a script, this
# file), and without the guard each would try to start a cluster of its own. Everything outside the
# guard also runs again in each worker: run as a script, this file computes its serial sweep once more
# per worker. A script of your own puts all its work under the guard (or in a function called there);
# the tutorial keeps the steps at the top level to show them one by one.
if __name__ == "__main__":
    t0 = time.perf_counter()
    distributed = sweep(design, out / "dask", workers=2, scheduler="local")
    print(f"Dask LocalCluster: {len(distributed)} rows in {time.perf_counter() - t0:.1f} s wall")
    keys = ["N", "noise_scale", "run", "estimator"]
    first = serial.sort_values(keys)[["rmse_x1", "rmse_x2"]].to_numpy()
    second = distributed.sort_values(keys)[["rmse_x1", "rmse_x2"]].to_numpy()
    print("the same errors as the serial run, bit for bit:", bool(np.array_equal(first, second)))

# %%
# The summary: means over the runs, per design point and estimator.
summary = serial.groupby(["estimator", "N", "noise_scale"])[["rmse_x1", "rmse_x2", "median_ms"]].mean()
summary

# %%
# Reading the table: the UISE's error scales with the noise and hardly changes with ``N``; the standard
# MHE's, which treats the unknown input as bounded, stays near the same value whatever the noise: the
# input dominates it. The EKF, whose random walk has a large variance here (``w_variance = 1`` in units
# of ``w.scale^2``), is as accurate as the UISE on these records; what it lacks is a bound that holds
# whatever the input does (tutorial 3 shows a jump).
fig, axes = plt.subplots(1, 2, figsize=(9, 3.5), sharey=True)
for ax, state in zip(axes, ("rmse_x1", "rmse_x2"), strict=True):
    for (estimator, N), group in serial.groupby(["estimator", "N"]):
        means = group.groupby("noise_scale")[state].mean()
        ax.loglog(means.index, means.to_numpy(), "o-", label=f"{estimator}, N={N}")
    ax.set_xlabel("noise scale (1 = V's half-width)")
    ax.set_title(state.replace("rmse_", "RMSE of "), fontsize=9)
axes[0].set_ylabel("mean RMSE over the runs")
axes[1].legend(fontsize=7)
fig.tight_layout()

print(f"CPU time of this tutorial (this process): {time.thread_time() - cpu_start:.1f} s")
