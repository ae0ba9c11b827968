"""
A reactor with a drifting actuator fault
========================================

The continuous-time CSTR of ``examples/reactor.py``, only the temperature measured, the coolant
actuator's fault as the unknown input. The designed (certified) UISE beside an EKF whose random-walk
variance is tuned on a separate simulation; the fault drifts smoothly, the EKF's case.

The committed figure (``python examples/reactor_fault.py``, 400 samples):

.. image:: ../../examples/figures/reactor_fault.png
   :alt: A reactor with a drifting actuator fault

The script, ``examples/reactor_fault.py``:

.. literalinclude:: ../../examples/reactor_fault.py
   :language: python

Below, the build runs the script's ``run`` on 200 samples, in a temporary folder, and shows the figure
it writes and the numbers it returns.
"""

import importlib.util
import sys
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt

# the repository's examples/: sphinx-gallery runs each script in its own folder (docs/gallery), without __file__
HERE = Path(__file__).resolve().parent if "__file__" in globals() else Path.cwd()
EXAMPLES = HERE.parents[1] / "examples"
spec = importlib.util.spec_from_file_location("example_reactor_fault", EXAMPLES / "reactor_fault.py")
example = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = example
spec.loader.exec_module(example)

out = Path(tempfile.mkdtemp())
metrics = example.run(out, steps=200)
for name, value in metrics.items():
    print(f"{name}: {value:.4g}")

image = plt.imread(out / "reactor_fault.png")
fig, ax = plt.subplots(figsize=(image.shape[1] / 100, image.shape[0] / 100), dpi=100)
ax.imshow(image)
ax.set_axis_off()
fig.subplots_adjust(0, 0, 1, 1)
