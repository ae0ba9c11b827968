"""
A linear benchmark: UIO, UISE and EKF
=====================================

Three states, two outputs, noise 0.05 and an unknown input that steps to 5 and then ramps. The
Chen-Patton-Zhang unknown-input observer and the designed UISE ignore it; the EKF, tuned on a
random-walk record, lags after each change.

The committed figure (``python examples/linear_uio_benchmark.py``, 200 samples):

.. image:: ../../examples/figures/linear_uio_benchmark.png
   :alt: A linear benchmark: UIO, UISE and EKF

The script, ``examples/linear_uio_benchmark.py``:

.. literalinclude:: ../../examples/linear_uio_benchmark.py
   :language: python

Below, the build runs the script's ``run`` on 120 samples, in a temporary folder, and shows the figure
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
spec = importlib.util.spec_from_file_location("example_linear_uio_benchmark", EXAMPLES / "linear_uio_benchmark.py")
example = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = example
spec.loader.exec_module(example)

out = Path(tempfile.mkdtemp())
metrics = example.run(out, steps=120)
for name, value in metrics.items():
    print(f"{name}: {value:.4g}")

image = plt.imread(out / "linear_uio_benchmark.png")
fig, ax = plt.subplots(figsize=(image.shape[1] / 100, image.shape[0] / 100), dpi=100)
ax.imshow(image)
ax.set_axis_off()
fig.subplots_adjust(0, 0, 1, 1)
