"""
Missing data and outages
========================

Real records have holes: a channel that drops out for a while, a few rows where the logger wrote
nothing, and gaps in the time column where it was not running at all. This tutorial writes such a
record, reads it back, and shows what the estimators do with the holes and what each step's health
fields say about them.
"""

# %%
# A model with two outputs
# ------------------------
# ``x1`` and ``x2`` are measured, ``x3`` is not; the unknown input moves ``x1``. There is no known
# input: a record's known inputs must be given at every ``k < K`` (a gap in ``t`` is refused where
# the model has a known input, since the model cannot be propagated across it without ``u``).
import tempfile
import time
import warnings
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from uiest import System, UniformNoise, simulate
from uiest.estimators import EKF, UISE
from uiest.health import Outcome
from uiest.results import read_record

cpu_start = time.thread_time()


def f(x, u, w):
    return [
        0.6 * x[0] + 0.2 * np.sin(x[2]) + w[0],
        0.7 * x[1] + 0.1 * x[0] + 0.1 * x[2],
        0.5 * x[2] + 0.3 * np.tanh(x[0]) + 0.1 * x[1],
    ]


system = System.from_callables(
    f,
    lambda x, v: [x[0] + v[0], x[1] + v[1]],
    nx=3,
    nw=1,
    nv=2,
    x_bounds=(-20.0, 20.0),
    v_bounds=(-0.01, 0.01),
    dt=0.1,
    x_names=("x1", "x2", "x3"),
    y_names=("y1", "y2"),
    name="two-outputs",
)
steps = 200
truth = simulate(
    system,
    [1.0, -1.0, 0.5],
    steps,
    w=lambda k, x: [1.5 * np.sin(0.05 * k) + 2.0 * (k > 100)],
    v=UniformNoise.symmetric(0.01),
    seed=4,
)

# %%
# Three kinds of holes
# --------------------
# - ``y1`` is missing for ``k = 40 .. 60`` (one channel, NaN in its column);
# - rows ``k = 80 .. 82`` have no measurement at all (NaN in every output);
# - rows ``k = 120 .. 149`` are absent from the file: a gap of 3 s in ``t``.
frame = truth.to_pandas()[["t", "y1", "y2"]].copy()
frame.loc[40:60, "y1"] = np.nan
frame.loc[80:82, ["y1", "y2"]] = np.nan
frame = frame.drop(index=range(120, 150))
path = Path(tempfile.mkdtemp()) / "record.csv"
frame.to_csv(path, index=False)

# %%
# Reading it places every row on the sampling grid by ``t``: the absent samples come back as rows of
# NaN (with a warning that says how many and where), so that ``y[k]`` stays the measurement at
# ``k dt``. A file without ``t`` (and without a ``k`` column) is taken as contiguous, also with a
# warning; a time column under another name (``time``, ``timestamp``) is refused, because without the
# times a dropped row would shift every later sample.
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    record = read_record(path, system)
for warning in caught:
    print("warning:", warning.message)
print("rows:", record.y.shape[0], "| missing per output:", np.isnan(record.y).sum(axis=0))

# %%
# What the estimators do
# ----------------------
# Window estimators (the UISE here) drop the missing entries from the window's cost. When ``y[k]``
# misses an output the newest unknown input reaches (``y1``), nothing in the window determines that
# input's last value: the UISE holds that part of it at its last estimate and predicts ``x[k]`` with
# it (``held_input``). When the whole window holds no measurement (an outage longer than the window),
# the model propagates the last estimate: outcome ``propagated``, which is not a failure (there was
# nothing to estimate from). Filters (the EKF here) drop missing channels from their update and
# predict through rows without data (outcome ``propagated`` too).
prior = np.zeros(3)
uise = UISE.design(system, x0_prior=prior, trials=1, max_horizon=15)
print("UISE: mu =", uise.weights.mu, "N =", uise.N, "|", uise.guarantee)
results = {
    "UISE": uise.run(None, record.y),
    "EKF": EKF(system, w_variance=0.1, x0_prior=prior).run(None, record.y),
}

# %%
# The health fields
# -----------------
# Every step's health is data: ``outcome`` (an :py:class:`uiest.health.Outcome`), ``missing`` (which
# outputs were NaN), ``held_input``, ``at_bound`` (states at a side of X), ``window_at_bound``,
# ``on_boundary``, ``fallback`` (the Gauss-Newton solver handed the window to IPOPT), the solver's own
# status; ``status`` is a display line derived from them. ``counts()`` sums them per run:
for name, result in results.items():
    print(name, result.counts())
uise_result = results["UISE"]
for k in (30, 45, 81, 125, 140, 160):
    print(f"k = {k:3d}: missing {uise_result.missing[k].astype(int)}, UISE: {uise_result.status[k]}")

# %%
# The guarantee assumes every output is measured, so it says nothing during the holes: the error is
# whatever the unknown input does while it is not seen. The figure shows the error growing during the
# outage (the unknown input steps at ``k = 100`` and is not seen from 120 to 149) and recovering within
# a window of the data's return. Count ``propagated`` and ``held`` steps before reading a run's errors.
for name, result in results.items():
    error = np.abs(result.error(truth.x))
    during = error[120:150].max(axis=0)
    after = error[170:].max(axis=0)
    print(f"{name}: largest error during the outage {np.round(during, 3)}, from k = 170 on {np.round(after, 3)}")

fig, axes = plt.subplots(3, 1, figsize=(7.5, 7), sharex=True, gridspec_kw={"height_ratios": [2, 2, 1]})
k = np.arange(steps + 1)
for ax in axes[:2]:
    for lo, hi in ((40, 60), (80, 82), (120, 149)):
        ax.axvspan(lo - 0.5, hi + 0.5, color="0.9")
axes[0].plot(k, truth.x[:, 0], "k", lw=1.2, label="true x1")
axes[0].plot(k, record.y[:, 0], ".", ms=2, color="0.4", label="y1 as recorded")
axes[1].plot(k, truth.x[:, 2], "k", lw=1.2, label="true x3 (unmeasured)")
for name, result in results.items():
    axes[0].plot(k, result.x_hat[:, 0], lw=1, label=name)
    axes[1].plot(k, result.x_hat[:, 2], lw=1, label=name)
axes[0].legend(fontsize=7, ncol=4)
axes[1].legend(fontsize=7, ncol=3)
for row, result in enumerate(results.values()):
    for value, color in ((Outcome.PROPAGATED, "C3"), (Outcome.SOLVED, "C2"), (Outcome.UPDATED, "C2")):
        hit = result.outcome == value
        axes[2].plot(k[hit], np.full(hit.sum(), row), "|", color=color, ms=8)
    held = result.held_input
    axes[2].plot(k[held], np.full(held.sum(), row + 0.3), "|", color="C1", ms=6)
axes[2].set_yticks([0, 1], list(results))
axes[2].set_ylim(-0.5, 1.6)
axes[2].set_title("green: solved/updated, red: propagated, orange: input held", fontsize=8)
axes[2].set_xlabel("k (grey: holes in the record)")
fig.tight_layout()

print(f"CPU time of this tutorial: {time.thread_time() - cpu_start:.1f} s")
