"""An output folder in use by another run is refused; a lock left by a killed run is taken over with a note."""

import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from test_atomic import chain_record
from typer.testing import CliRunner

from uiest.cli import app
from uiest.errors import StorageError
from uiest.lock import LOCK_NAME, folder_lock

runner = CliRunner()
SRC = Path(__file__).resolve().parents[1] / "src"
HOLDER = "import sys\nfrom uiest.lock import folder_lock\nwith folder_lock(sys.argv[1], 'out'):\n" \
         "    print('held', flush=True)\n    sys.stdin.read()\n"  # fmt: skip


@pytest.fixture
def held(tmp_path):
    """A folder held by another process (running until the test ends); yields (folder, its pid)."""
    folder = tmp_path / "out"
    folder.mkdir()
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(folder)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True, env=env)  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "held"
        yield folder, holder
    finally:
        holder.kill()
        holder.wait()


def test_a_second_estimate_into_a_folder_in_use_is_refused_naming_the_folder_and_owner(tmp_path, held):
    folder, holder = held
    data = chain_record(tmp_path)
    args = ["estimate", str(tmp_path / "chain.py"), "--data", str(data), "--estimator", "ekf", "--out", str(folder)]
    result = runner.invoke(app, args)
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: --out: {folder} is in use by another run")
    assert f"pid {holder.pid} on host {socket.gethostname()}" in lines[0]
    assert sorted(p.name for p in folder.iterdir()) == [LOCK_NAME]  # nothing written by the refused run


def test_the_api_writers_refuse_a_folder_in_use(tmp_path, held):
    from uiest.experiments.sweep import Sweep, sweep

    folder, holder = held
    toml = tmp_path / "sweep.toml"
    toml.write_text(
        "[scenario]\nname = 'locked'\nmodel = 'closed-form'\nsteps = 6\nruns = 1\ncases = ['noise-free']\n"
        "settle = 2\n[[scenario.estimators]]\nname = 'UISE'\nkind = 'uise'\nN = 3\nmu = 0.64\n"
        "[sweep]\ngrid = { N = [2, 3] }\n"
    )
    design = Sweep.from_toml(toml)
    with pytest.raises(StorageError, match=f"in use by another run \\(pid {holder.pid} "):
        sweep(design, folder, workers=1)
    assert sorted(p.name for p in folder.iterdir()) == [LOCK_NAME]


@pytest.mark.slow
def test_a_lock_left_by_a_killed_run_is_taken_over_with_a_note(tmp_path):
    folder = tmp_path / "out"
    folder.mkdir()
    env = {**os.environ, "PYTHONPATH": str(SRC)}
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, str(folder)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True, env=env)  # fmt: skip
    assert holder.stdout.readline().strip() == "held"
    os.kill(holder.pid, signal.SIGKILL)
    holder.wait()
    assert (folder / LOCK_NAME).exists()  # a killed run cannot remove its lock file ...
    (folder / ".staged-abc.tmp").mkdir()  # ... nor the report it was writing
    (folder / ".staged-abc.tmp" / "report.md").write_text("half a rep")
    data = chain_record(tmp_path)
    args = ["estimate", str(tmp_path / "chain.py"), "--data", str(data), "--estimator", "ekf", "--out", str(folder)]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    note = [line for line in result.output.splitlines() if line.startswith("warning: --out: took over the lock")]
    assert len(note) == 1 and f"pid {holder.pid} on host" in note[0] and "removed the 1 unfinished write" in note[0]
    assert sorted(p.name for p in folder.iterdir()) == ["estimates.png", "estimates_ekf.csv", "manifest.json"]


def test_the_lock_is_reentrant_in_one_process_and_released_on_errors(tmp_path):
    with folder_lock(tmp_path, "out"):
        with folder_lock(tmp_path, "out"):
            assert (tmp_path / LOCK_NAME).exists()
        assert (tmp_path / LOCK_NAME).exists()
    assert not (tmp_path / LOCK_NAME).exists()
    bad = runner.invoke(app, ["estimate", "closed-form", "--data", str(tmp_path / "none.csv"), "--out", str(tmp_path)])
    assert bad.exit_code == 2 and not (tmp_path / LOCK_NAME).exists()
