"""sphinx-gallery settings for the tutorials and the gallery; docs/conf.py imports ``SPHINX_GALLERY_CONF``.

Two galleries, both executed in the build (every ``plot_*.py`` script runs top to bottom and the
matplotlib figures it leaves open are captured):

- ``docs/tutorials`` -> ``docs/auto_tutorials``: the tutorials, in file-name order.
- ``docs/gallery`` -> ``docs/auto_examples``: one page per script of ``examples/``. Each page shows the
  example's whole source and its committed figure from ``examples/figures`` and runs the example on a
  short record in a temporary folder (the examples' own ``__main__`` blocks write into ``examples/``,
  which a docs build must not touch).

Each script is kept under about 30 s of CPU; the build writes the measured times to
``sg_execution_times.rst``.
"""

from __future__ import annotations

from typing import Any

SPHINX_GALLERY_CONF: dict[str, Any] = {
    "examples_dirs": ["tutorials", "gallery"],
    "gallery_dirs": ["auto_tutorials", "auto_examples"],
    "filename_pattern": r"/plot_",  # execute every plot_*.py
    "within_subsection_order": "FileNameSortKey",  # plot_01_..., plot_02_...: the reading order
    "download_all_examples": False,
    "remove_config_comments": True,
    "min_reported_time": 0,
}
