"""
A chaotic map carrying a message
================================

A Hénon map hides random bits (+-0.02) in its state; only x1 is sent, with noise 1e-3. The designed
UISE returns the message as its unknown-input estimate, one sample late.

The committed figure (``python examples/chaotic_message.py``, 400 samples):

.. image:: ../../examples/figures/chaotic_message.png
   :alt: A chaotic map carrying a message

The script, ``examples/chaotic_message.py``:

.. literalinclude:: ../../examples/chaotic_message.py
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
spec = importlib.util.spec_from_file_location("example_chaotic_message", EXAMPLES / "chaotic_message.py")
example = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = example
spec.loader.exec_module(example)

out = Path(tempfile.mkdtemp())
metrics = example.run(out, steps=200)
for name, value in metrics.items():
    print(f"{name}: {value:.4g}")

image = plt.imread(out / "chaotic_message.png")
fig, ax = plt.subplots(figsize=(image.shape[1] / 100, image.shape[0] / 100), dpi=100)
ax.imshow(image)
ax.set_axis_off()
fig.subplots_adjust(0, 0, 1, 1)
