"""
A continuous stirred-tank reactor with an actuator fault
========================================================

A dimensionless CSTR (concentration c_A, temperature T), only the temperature measured; a coolant
actuator fault drifts as the unknown input. Sampled every 0.05 by ``System.from_ode``; its
``setup()`` is the default simulation and its ``study()`` what ``uiest reproduce
examples/reactor.py`` runs. ``examples/data/reactor.csv`` is a record of it, the data of ``uiest
estimate examples/reactor.py --data examples/data/reactor.csv``.

The model file, ``examples/reactor.py`` (a module with ``system`` and ``setup()``: any command that
takes a model name takes its path):

.. literalinclude:: ../../examples/reactor.py
   :language: python

Below, the build loads it with :py:func:`uiest.models.load`, prints what ``uiest analyse
examples/reactor.py`` prints (:py:func:`uiest.analyse`) and simulates its default setup.
"""

from pathlib import Path

import matplotlib.pyplot as plt

from uiest import analyse, simulate
from uiest.models import load

# the repository's examples/: sphinx-gallery runs each script in its own folder (docs/gallery), without __file__
HERE = Path(__file__).resolve().parent if "__file__" in globals() else Path.cwd()
EXAMPLES = HERE.parents[1] / "examples"
entry = load(EXAMPLES / "reactor.py")
system = entry.build()
print(analyse(system).text())

setup = entry.setup()
truth = simulate(system, setup.x0, setup.steps, u=setup.u, w=setup.w, v=setup.noise, seed=0)
fig, axes = plt.subplots(system.nx + 1, 1, figsize=(7, 1.8 * (system.nx + 1)), sharex=True)
for i, ax in enumerate(axes[:-1]):
    ax.plot(truth.t, truth.x[:, i], "k", lw=1)
    ax.set_ylabel(f"{system.x.names[i]} ({system.x.units[i]})")
axes[-1].step(truth.t[:-1], truth.w[:, 0], where="post", color="C3", lw=1)
axes[-1].set_ylabel(f"{system.w.names[0]} (unknown)")
axes[-1].set_xlabel(f"t ({system.time_unit})")
fig.tight_layout()
