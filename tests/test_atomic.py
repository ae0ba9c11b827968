"""Writes that fail (disk full, file-size limit) end in one line naming the path; nothing stored is lost."""

import errno
import os
import resource
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from uiest import simulate
from uiest.atomic import staged_folder, write_file, write_text
from uiest.cli import app
from uiest.errors import StorageError
from uiest.models import linear

runner = CliRunner()
SRC = Path(__file__).resolve().parents[1] / "src"
FULL = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def contents(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (relative name -> bytes), hidden ones included."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def partly_then_full(original):
    """A writer that writes part of its file, then fails as a full disk does (no file name in the error)."""

    def write(self, path=None, *args, **kwargs):
        if path is not None:
            Path(path).write_text("k,x\n0,1.")
        raise FULL

    return write


def chain_record(folder: Path) -> Path:
    """A 60-step record of a linear chain (two states, one unknown input), with its truth, as CSV."""
    system = linear.linear_system(np.array([[0.9, 0.1], [0.0, 0.7]]), [[0.0], [1.0]], np.eye(2),
                                  x_bounds=(-10, 10), v_bounds=(-0.01, 0.01))  # fmt: skip
    rng = np.random.default_rng(3)
    truth = simulate(system, [0.2, -0.1], 60, w=np.sin(0.1 * np.arange(60))[:, None],
                     v=rng.uniform(-0.01, 0.01, (61, 2)))  # fmt: skip
    (folder / "chain.py").write_text(
        "import numpy as np\nfrom uiest.models import linear\nsystem = linear.linear_system(np.array([[0.9, 0.1], "
        "[0.0, 0.7]]), [[0.0], [1.0]], np.eye(2), x_bounds=(-10, 10), v_bounds=(-0.01, 0.01))\n"
    )
    data = folder / "chain.csv"
    truth.to_pandas().to_csv(data)
    return data


def test_write_file_keeps_the_previous_file_when_a_write_fails(tmp_path):
    target = tmp_path / "table.csv"
    target.write_text("the good table\n")

    def write(tmp):
        tmp.write_text("half a ta")
        raise FULL

    with pytest.raises(StorageError, match=f"cannot write {target}: No space left on device") as caught:
        write_file(target, write)
    assert caught.value.path == str(target) and isinstance(caught.value, OSError)
    assert target.read_text() == "the good table\n" and contents(tmp_path) == {"table.csv": b"the good table\n"}
    assert write_text(target, "new\n") == target and contents(tmp_path) == {"table.csv": b"new\n"}


def test_a_staged_folder_replaces_its_files_all_together_or_not_at_all(tmp_path):
    (tmp_path / "a.csv").write_text("old a")
    (tmp_path / "b.csv").write_text("old b")
    full = f"cannot write {tmp_path / 'b.csv'}: No space left on device"
    with pytest.raises(StorageError, match=full), staged_folder(tmp_path) as stage:
        (stage / "a.csv").write_text("new a")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(stage / "b.csv"))
    assert contents(tmp_path) == {"a.csv": b"old a", "b.csv": b"old b"}
    with staged_folder(tmp_path) as stage:
        (stage / "a.csv").write_text("new a")
        (stage / "c.csv").write_text("new c")
    assert contents(tmp_path) == {"a.csv": b"new a", "b.csv": b"old b", "c.csv": b"new c"}
    # a rename that fails part-way (the third file's rename): the files already renamed are put back
    real_replace = os.replace

    def failing_replace(source, target):
        if Path(source).name == "c.csv" and Path(source).parent.name.startswith(".staged-"):
            raise OSError(errno.EIO, os.strerror(errno.EIO), str(target))
        real_replace(source, target)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(os, "replace", failing_replace)
        with pytest.raises(StorageError, match=f"cannot write {tmp_path / 'c.csv'}"), staged_folder(tmp_path) as stage:
            for name in ("a.csv", "b.csv", "c.csv"):
                (stage / name).write_text(f"newer {name[0]}")
    assert contents(tmp_path) == {"a.csv": b"new a", "b.csv": b"old b", "c.csv": b"new c"}
    # a folder where a file goes is refused before any rename
    (tmp_path / "d.csv").mkdir()
    with pytest.raises(StorageError, match=r"d\.csv"), staged_folder(tmp_path) as stage:
        (stage / "a.csv").write_text("newer a")
        (stage / "d.csv").write_text("new d")
    assert contents(tmp_path) == {"a.csv": b"new a", "b.csv": b"old b", "c.csv": b"new c"}


@pytest.mark.slow
def test_estimate_on_a_full_disk_ends_in_one_line_and_keeps_the_earlier_estimates(tmp_path, monkeypatch):
    data = chain_record(tmp_path)
    out = tmp_path / "out"
    args = ["estimate", str(tmp_path / "chain.py"), "--data", str(data), "--estimator", "ekf", "--out", str(out)]
    first = runner.invoke(app, args)
    assert first.exit_code == 0, first.output
    before = contents(out)
    assert "estimates_ekf.csv" in before and "estimates.png" in before
    monkeypatch.setattr(pd.DataFrame, "to_csv", partly_then_full(pd.DataFrame.to_csv))
    failed = runner.invoke(app, args)
    assert failed.exit_code != 0 and not isinstance(failed.exception, OSError)
    last = failed.output.strip().splitlines()[-1]
    assert last == f"error: cannot write {out / 'estimates_ekf.csv'}: No space left on device"
    assert "Traceback" not in failed.output
    assert contents(out) == before  # nothing half-written, nothing lost, no temporary file left


def test_reproduce_on_a_full_disk_ends_in_one_line_and_keeps_the_earlier_report(tmp_path, monkeypatch):
    from test_experiments import tiny

    scenario = tiny().with_overrides(runs=1, cases=("noise-free",)).to_toml(tmp_path / "tiny.toml")
    out = tmp_path / "out"
    args = ["reproduce", "--scenario", str(scenario), "--solver", "gn", "--out", str(out)]
    first = runner.invoke(app, args)
    assert first.exit_code == 0, first.output
    before = contents(out)
    assert {"report.md", "manifest.json", "steps.parquet", "table1.md"} <= set(before)
    monkeypatch.setattr(pd.DataFrame, "to_csv", partly_then_full(pd.DataFrame.to_csv))
    failed = runner.invoke(app, args)
    assert failed.exit_code != 0 and not isinstance(failed.exception, OSError)
    lines = failed.output.strip().splitlines()
    assert lines[-1] == f"error: cannot write {out / 'runs.csv'}: No space left on device"
    assert contents(out) == before


def test_sweep_on_a_full_disk_keeps_the_stored_tasks_and_resumes(tmp_path, monkeypatch):
    design = tmp_path / "sweep.toml"
    design.write_text(
        "[scenario]\nname = 'full-disk'\nmodel = 'closed-form'\nsteps = 8\nruns = 1\ncases = ['noise-free']\n"
        "settle = 2\n[[scenario.estimators]]\nname = 'UISE'\nkind = 'uise'\nN = 3\nmu = 0.64\n"
        "[sweep]\ngrid = { N = [2, 3, 4] }\n"
    )
    out = tmp_path / "out"
    args = ["sweep", str(design), "--out", str(out), "--workers", "1"]
    real = pd.DataFrame.to_parquet
    calls = []

    def second_fails(self, path, *a, **k):  # the first task is stored, the second finds the disk full
        calls.append(path)
        if len(calls) == 2:
            Path(path).write_bytes(b"PAR1")
            raise FULL
        return real(self, path, *a, **k)

    monkeypatch.setattr(pd.DataFrame, "to_parquet", second_fails)
    failed = runner.invoke(app, args)
    assert failed.exit_code != 0 and not isinstance(failed.exception, OSError)
    last = failed.output.strip().splitlines()[-1]
    assert last.startswith(f"error: cannot write {out / 'runs'}") and last.endswith("No space left on device")
    stored = sorted(p.name for p in (out / "runs").iterdir())
    assert len(stored) == 1 and stored[0].endswith(".parquet")  # the finished task, and no partial file
    monkeypatch.setattr(pd.DataFrame, "to_parquet", real)
    again = runner.invoke(app, args)
    assert again.exit_code == 0, again.output
    assert "3 of 3 tasks stored (0 with an error)" in again.output


@pytest.mark.slow
def test_a_file_size_limit_ends_estimate_in_one_line_naming_the_file(tmp_path):
    data = chain_record(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    (out / "estimates_ekf.csv").write_text("an earlier result\n")

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))

    command = [sys.executable, "-m", "uiest", "estimate", str(tmp_path / "chain.py"), "--data", str(data),
               "--estimator", "ekf", "--out", str(out)]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(SRC), "MPLCONFIGDIR": str(tmp_path / "mpl")}
    done = subprocess.run(command, capture_output=True, text=True, env=env, preexec_fn=limit, timeout=300)
    assert done.returncode != 0 and "Traceback" not in done.stderr, done.stderr
    errors = [line for line in done.stderr.splitlines() if line.startswith("error: ")]
    assert errors == [f"error: cannot write {out / 'estimates_ekf.csv'}: File too large"], done.stderr
    assert contents(out) == {"estimates_ekf.csv": b"an earlier result\n"}


def test_the_git_revision_of_a_run_leaves_the_users_checkout_unwritten(tmp_path, monkeypatch):
    # under a file-size limit, a git that rewrites the index is killed and leaves .git/index.lock behind
    from uiest.experiments import provenance

    def git(*args):
        subprocess.run(["git", *args], cwd=tmp_path, check=True, capture_output=True)

    git("init", "-q")
    (tmp_path / "__init__.py").write_text("")
    git("add", "__init__.py")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "init")
    index = tmp_path / ".git" / "index"
    os.utime(tmp_path / "__init__.py", ns=(10**18, 10**18))  # stat data the index does not have: git would refresh
    before = index.stat().st_mtime_ns
    monkeypatch.setattr(provenance, "PACKAGE", tmp_path)
    assert not provenance.git_revision().endswith("-dirty")
    assert index.stat().st_mtime_ns == before and not (tmp_path / ".git" / "index.lock").exists()
