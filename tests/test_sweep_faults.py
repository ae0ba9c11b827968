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

from uiest import OptionError
from uiest.experiments import EstimatorSpec, Scenario
from uiest.experiments.sweep import Sweep, sweep


def design() -> Sweep:
    scenario = Scenario(
        name="killed-sweep",
        model="closed-form",
        steps=300,  # a task takes about 0.5 s: the kill comes while most are still running
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
        time.sleep(0.02)
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


def small() -> Sweep:
    base = design().scenario
    return Sweep(Scenario(**{**base.__dict__, "steps": 10, "runs": 1}), grid={"N": (2, 3, 4, 5, 6, 7)})


@pytest.mark.slow
def test_a_task_that_kills_its_worker_is_recorded_and_the_others_complete(tmp_path, monkeypatch):
    # every spawned worker runs this sitecustomize: building the N = 4 estimator ends the process
    inject = tmp_path / "inject"
    inject.mkdir()
    (inject / "sitecustomize.py").write_text(
        "import os\n"
        "from uiest.experiments import runner\n"
        "real = runner.BUILDERS['uise']\n"
        "def crash(study, spec, prior, solver):\n"
        "    if spec.N == 4:\n        os._exit(9)\n"
        "    return real(study, spec, prior, solver)\n"
        "runner.BUILDERS['uise'] = crash\n"
    )
    monkeypatch.setenv("PYTHONPATH", f"{inject}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    seen = []
    results = sweep(small(), tmp_path / "out", workers=2, progress=seen.append)
    assert len(results) == 6 and results["key"].is_unique and seen[-1].lost == 0
    died = results[results["error"].str.startswith("WorkerDied")]
    assert list(died["N"]) == [4] and (results[results["N"] != 4]["error"] == "").all()
    again = sweep(small(), tmp_path / "out", workers=2, progress=seen.append)  # recorded: not retried
    assert len(again) == 6 and seen[-1].skipped == 6


def test_a_damaged_page_is_detected_and_its_task_computed_again(tmp_path):
    out = tmp_path / "out"
    sweep(small(), out, workers=1, max_tasks=1)
    (stored,) = (out / "runs").glob("*.parquet")
    data = bytearray(stored.read_bytes())
    for i in range(40, 120):  # a data page; the footer stays intact
        data[i] ^= 0xFF
    stored.write_bytes(bytes(data))
    with pytest.warns(UserWarning, match=r"could not be read .*set aside as .*corrupt"):
        results = sweep(small(), out, workers=1)
    assert len(results) == 6 and results["key"].is_unique and (results["error"] == "").all()
    assert len(list((out / "runs" / "corrupt").glob("*.parquet"))) == 1


@pytest.mark.slow
def test_rows_of_other_code_are_never_stored(tmp_path):
    from dataclasses import replace

    from uiest.experiments import executors
    from uiest.experiments.sweep import run_task

    tasks = [replace(task, code="other code") for task in small().tasks()[:2]]
    outcomes = list(executors.processes(tasks, run_task, 2))
    assert all(rows is None and "CodeMismatchError" in why for _, rows, why in outcomes)


@pytest.mark.slow
def test_an_interrupted_pool_ends_its_workers_at_once():
    from uiest.experiments import executors
    from uiest.experiments.sweep import run_task

    long = Sweep(Scenario(**{**design().scenario.__dict__, "steps": 400, "runs": 4}), grid={"N": (3, 5, 8)})
    outcomes = executors.processes(long.tasks(), run_task, 2)
    next(outcomes)
    tracker = "multiprocessing.resource_tracker"  # multiprocessing's own helper, alive as long as this process
    workers = [p for p in psutil.Process().children(recursive=True) if tracker not in " ".join(p.cmdline())]
    assert workers
    start = time.monotonic()
    outcomes.close()  # what Ctrl-C or an exception in the caller does
    _, alive = psutil.wait_procs(workers, timeout=10)
    assert not alive and time.monotonic() - start < 10


def test_repeated_values_are_refused_and_coinciding_random_points_are_one_task():
    with pytest.raises(OptionError, match="distinct"):
        Sweep(design().scenario, grid={"N": (2, 2, 3)})
    with pytest.raises(OptionError, match="cases"):
        Scenario(**{**design().scenario.__dict__, "cases": ("noisy", "noisy")})
    coinciding = Sweep(design().scenario, random=6, ranges={"N": (2, 3)})
    assert len(coinciding.tasks()) == 2 * design().scenario.runs
