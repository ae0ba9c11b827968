"""
Your own continuous-time model and CSV data
===========================================

This tutorial builds a model from a continuous-time right-hand side, writes a CSV file of
measurements the way a data logger would, reads it back, and estimates the states and the unknown
input with a designed UISE and an EKF fitted to the same data.

The process: two tanks in cascade. A pump with known flow ``u`` fills tank 1; tank 1 drains into
tank 2, which drains out. A leak or an unmeasured inflow ``w`` changes tank 1's level; nothing is
known about it (it may grow without bound). Only the level of tank 1 is measured:

.. math::

    \\dot h_1 = u + w - a_1 \\sqrt{h_1}, \\qquad
    \\dot h_2 = a_1 \\sqrt{h_1} - a_2 \\sqrt{h_2}, \\qquad
    y = h_1 + v .
"""

# %%
# The model
# ---------
# :py:meth:`uiest.System.from_ode` samples ``dx/dt = rhs(x, u, w)`` every ``dt`` (RK4; the unknown
# input enters through its per-sample integral at X's centre, so its direction stays constant; where
# that integral varies over X by more than a quarter of its size, ``from_ode`` warns, and by more than its
# size it keeps the input inside the integrator instead, as ``input_channel="rk4"`` does). The
# callables receive CasADi symbols, so use ``numpy`` functions that CasADi overloads (``np.sqrt``,
# ``np.exp``, ``np.sin``). The boxes are part of the model: ``x_bounds`` is the domain X the
# estimators constrain their estimates to, ``v_bounds`` the measurement noise's range V, and
# ``u_bounds`` the range of the known input.
import tempfile
import time
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from uiest import System, UniformNoise, simulate
from uiest.estimators import EKF, UISE
from uiest.results import read_record

cpu_start = time.thread_time()
A1, A2 = 0.5, 0.7  # outflow coefficients, m^(1/2)/min


def rhs(x, u, w):
    """dx/dt of the two levels (m/min)."""
    return [u[0] + w[0] - A1 * np.sqrt(x[0]), A1 * np.sqrt(x[0]) - A2 * np.sqrt(x[1])]


tanks = System.from_ode(
    rhs,
    lambda x, v: [x[0] + v[0]],
    nx=2,
    nu=1,
    nw=1,
    nv=1,
    dt=1.0,
    x_bounds=((0.2, 0.2), (3.0, 3.0)),
    u_bounds=(0.0, 1.0),
    v_bounds=(-0.005, 0.005),
    x_names=("h1", "h2"),
    x_units=("m", "m"),
    u_names=("pump",),
    w_names=("leak",),
    y_names=("h1_measured",),
    y_units=("m",),
    time_unit="min",
    name="tanks",
)
print(tanks)

# %%
# The index convention
# --------------------
# uiest works on the sampled model ``x[k+1] = f(x[k], u[k], w[k])``, ``y[k] = h(x[k], v[k])``:
#
# - ``x[k]`` is the state at ``t[k] = k dt``;
# - ``u[k]`` and ``w[k]`` act from ``k`` to ``k+1`` (held over the sample);
# - ``y[k]`` is measured at ``k``.
#
# A record of ``K`` transitions therefore has ``K+1`` rows of ``t``, ``x`` and ``y`` and ``K`` rows of
# ``u`` and ``w``. In a table (one row per ``k``) the last row's ``u`` is not used.
#
# A CSV file from a "data logger"
# -------------------------------
# We simulate a record (in practice it comes from the plant) and write only what a logger would
# have: the time, the pump flow and the measured level. The true levels and the leak are kept in
# separate columns here only to score the estimates at the end; a real file does not have them and
# does not need them.
steps = 100  # 100 minutes; a real record would be longer
k = np.arange(steps)
pump = (0.6 + 0.2 * (k // 25 % 2))[:, None]  # steps between 0.6 and 0.8 every 25 min
leak = np.where(k * tanks.dt > 30.0, -0.15 * (1.0 - np.exp(-(k * tanks.dt - 30.0) / 10.0)), 0.0)[:, None]
truth = simulate(tanks, [1.4, 0.7], steps, u=pump, w=leak, v=UniformNoise.symmetric(0.005), seed=3)

folder = Path(tempfile.mkdtemp())
logged = truth.to_pandas()[["t", "pump", "h1_measured"]]
logged.to_csv(folder / "tanks.csv", index=False, float_format="%.6g")
print((folder / "tanks.csv").read_text().splitlines()[:4])

# %%
# Reading it back
# ---------------
# :py:func:`uiest.results.read_record` (or :py:meth:`uiest.Trajectory.from_pandas` for a DataFrame)
# matches columns by the model's signal names: every output (NaN = missing) and every known input
# are required; ``t`` places the rows on the sampling grid (tutorial 5 shows gaps). The result is a
# :py:class:`uiest.Trajectory` with the shapes above; its states are NaN because the file has none.
record = read_record(folder / "tanks.csv", tanks)
print(record.u.shape, record.y.shape, record.has_states)

# %%
# Estimating
# ----------
# :py:meth:`uiest.estimators.UISE.design` certifies strong detectability at several rates and keeps
# the rate and horizon that are most accurate under the model's noise (tutorial 3 explains the
# design). The UISE makes no assumption on the leak. :py:meth:`uiest.estimators.EKF.fit` models the
# leak as a random walk (or an integrated one) and chooses its variance by the likelihood of the
# record's innovations; it needs no true states either.
#
# ``uiest estimate tanks.py --data tanks.csv`` does the same from the shell, for a model file
# ``tanks.py`` that defines ``system`` (this script's ``tanks``); it writes the estimates as CSV and a
# figure to ``out/estimate/``.
prior = np.array([1.2, 0.9])
uise = UISE.design(tanks, x0_prior=prior, trials=1, max_horizon=20)
print("UISE:", uise.weights.mu, uise.N, uise.guarantee)
ekf = EKF.fit(tanks, record.u, record.y, x0_prior=prior)
print("EKF:", ekf.filter_fit.summary())

results = {"UISE": uise.run(record.u, record.y), "EKF": ekf.run(record.u, record.y)}
for name, result in results.items():
    rmse = np.sqrt(np.nanmean(result.error(truth.x)[20:] ** 2, axis=0))
    print(f"{name}: RMSE after 20 min h1 {rmse[0]:.2e} m, h2 {rmse[1]:.2e} m; {result.counts()}")

# %%
# Each result is an :py:class:`uiest.results.EstimationResult`: ``x_hat`` (K+1, nx) estimates
# ``x[k]``, ``w_hat`` (K, nw) estimates ``w[k]`` (the leak acting from ``k`` to ``k+1``), and the
# per-step health fields (tutorial 5). ``to_pandas()`` gives the table ``uiest estimate`` writes.
print(results["UISE"].to_pandas().head(3).T)

fig, axes = plt.subplots(3, 1, figsize=(7, 6.5), sharex=True)
t = truth.t
axes[0].plot(t, record.y[:, 0], ".", ms=2, color="0.5", label="measured h1")
for i, ax in enumerate(axes[:2]):
    ax.plot(t, truth.x[:, i], "k", lw=1.2, label="true")
    for name, result in results.items():
        ax.plot(t, result.x_hat[:, i], lw=1, label=name)
    ax.set_ylabel(f"{tanks.x.names[i]} (m)")
axes[2].step(t[:-1], truth.w[:, 0], "k", where="post", lw=1.2, label="true leak")
for name, result in results.items():
    axes[2].plot(t[:-1], result.w_hat[:, 0], lw=1, label=name)
axes[2].set_ylabel("leak (m/min)")
axes[2].set_xlabel("t (min)")
axes[0].legend(fontsize=7, ncol=4)
axes[2].legend(fontsize=7, ncol=3)
fig.tight_layout()

# %%
# The UISE's leak estimate ``w_hat[k]`` follows the leak from the next measurement on: an unknown
# input acting from ``k`` to ``k+1`` is seen in ``y[k+1]``. The EKF's input model (the one its fit chose,
# printed above) smooths it.
print(f"CPU time of this tutorial: {time.thread_time() - cpu_start:.1f} s")
