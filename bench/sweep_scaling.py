"""Runs per second of a fixed crop sweep: 1 and 2 local worker processes, and a 2-worker LocalCluster.

Run: ``python bench/sweep_scaling.py``. Issue 8 target: 2 workers reach at least 1.6x one worker.
Each configuration starts from an empty output folder; process start-up is included.
"""

from __future__ import annotations

import tempfile
import time
from dataclasses import replace
from pathlib import Path

from uiest.experiments import crop_growth_study
from uiest.experiments.sweep import Sweep, sweep


def main() -> None:
    base = crop_growth_study()
    scenario = replace(
        base,
        runs=8,
        steps=300,
        cases=("noisy",),
        estimators=tuple(spec for spec in base.estimators if spec.kind == "uise"),
    )
    design = Sweep(scenario, grid={"N": (10, 20)})
    tasks = len(design.tasks())
    rates = {}
    for label, options in (
        ("1 local worker", {"workers": 1}),
        ("2 local workers", {"workers": 2}),
        ("LocalCluster, 2 workers", {"workers": 2, "scheduler": "local"}),
    ):
        with tempfile.TemporaryDirectory() as folder:
            start = time.perf_counter()
            results = sweep(design, Path(folder), **options)
            elapsed = time.perf_counter() - start
        assert len(results) == tasks and (results["error"] == "").all()
        rates[label] = tasks / elapsed
        print(f"{label:26s} {tasks} runs in {elapsed:6.1f} s: {rates[label]:.2f} runs/s")
    one = rates["1 local worker"]
    for label in ("2 local workers", "LocalCluster, 2 workers"):
        print(f"speed-up {label}: {rates[label] / one:.2f}x (target >= 1.6x)")


if __name__ == "__main__":
    main()
