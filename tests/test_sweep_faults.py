"""A sweep killed with SIGKILL (process pool and Dask) leaves no workers behind and resumes to the same rows."""

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import psutil
import pytest

from uiest.experiments import EstimatorSpec, Scenario
from uiest.experiments.sweep import Sweep, sweep


def design() -> Sweep:
    scenario = Scenario(
        name="killed-sweep",
        model="closed-form",
        steps=60,
        runs=3,
        cases=("noisy",),
        prior=(math.nan, 0.0),
        prior_from_output=((0, 0),),
        settle=5,
        focus_state=1,
        estimators=(EstimatorSpec("UISE", "uise", N=5, mu=0.64, output_weight=1e4),),
    )
    return Sweep(scenario, grid={"N": (3, 5, 8)})


def numbers(frame: pd.DataFrame) -> pd.DataFrame:
    cols = [c for c in frame.columns if not c.endswith("_ms")]
    return frame[cols].sort_values(["key", "estimator"]).reset_index(drop=True)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    return sweep(design(), tmp_path_factory.mktemp("whole"), workers=1)


@pytest.mark.slow
@pytest.mark.parametrize("scheduler", [None, "local"])
def test_a_killed_sweep_leaves_no_workers_and_resumes_to_the_same_rows(tmp_path, uninterrupted, scheduler):
    out = tmp_path / "sweep"
    code = (
        f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "from pathlib import Path\nfrom test_sweep_faults import design\nfrom uiest.experiments.sweep import sweep\n"
        f"sweep(design(), Path({str(out)!r}), workers=2, scheduler={scheduler!r})\n"
    )
    parent = subprocess.Popen([sys.executable, "-c", code], start_new_session=True)
    runs = out / "runs"
    deadline = time.monotonic() + 180
    while not (runs.exists() and any(runs.glob("*.parquet"))):
        assert parent.poll() is None, "the sweep ended before it could be killed"
        assert time.monotonic() < deadline, "no task finished within 180 s"
        time.sleep(0.2)
    workers = psutil.Process(parent.pid).children(recursive=True)
    assert workers, "the sweep runs no worker processes"
    os.kill(parent.pid, signal.SIGKILL)
    parent.wait()
    _, alive = psutil.wait_procs(workers, timeout=60)
    for process in alive:  # keep the machine clean even when the test fails
        process.kill()
    assert not alive, f"orphaned workers: {[p.pid for p in alive]}"
    stored = len(list(runs.glob("*.parquet")))
    assert 0 < stored < len(design().tasks())
    resumed = sweep(design(), out, workers=1)
    assert resumed["key"].is_unique and len(resumed) == len(uninterrupted)
    pd.testing.assert_frame_equal(numbers(resumed), numbers(uninterrupted))
