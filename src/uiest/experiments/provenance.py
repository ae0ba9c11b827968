"""Where results come from: machine, package versions, git revision and a hash of uiest's own code."""

from __future__ import annotations

import datetime as dt
import functools
import hashlib
import os
import platform
import subprocess
import sys
from importlib import metadata
from pathlib import Path
from typing import Any

__all__ = [
    "code_version",
    "file_digest",
    "git_revision",
    "keyed_scenario",
    "machine",
    "model_digest",
    "stamp",
    "versions",
]

PACKAGE = Path(__file__).resolve().parents[1]
"""The ``uiest`` package folder."""


def machine() -> str:
    """CPU model and core count of this machine."""
    name = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                name = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{name}, {os.cpu_count()} cores, {platform.system()} {platform.release()}"


def git_revision() -> str:
    """The git commit of the package's checkout (with '-dirty' for uncommitted changes), or why none."""
    try:  # the package must be tracked by the checkout (an installed copy inside some project is not)
        subprocess.run(["git", "ls-files", "--error-unmatch", "__init__.py"], capture_output=True, check=True,
                       cwd=PACKAGE)  # fmt: skip
        head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True, cwd=PACKAGE)
        dirty = subprocess.run(["git", "--no-optional-locks", "status", "--porcelain", "--", "."],  # index unwritten
                               capture_output=True, text=True, check=True, cwd=PACKAGE)  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        return "unknown (not a git checkout)"
    return head.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")


def versions() -> dict[str, str]:
    """Python and the versions of the packages results depend on."""
    found = {"python": sys.version.split()[0]}
    for package in ("uiest", "casadi", "numpy", "scipy", "cvxpy", "clarabel", "pandas", "matplotlib", "dask"):
        try:
            found[package] = metadata.version(package)
        except metadata.PackageNotFoundError:
            found[package] = "not installed"
    return found


PRESENTATION = frozenset(
    {"cli.py", "plotting.py", "paths.py", "experiments/report.py", "experiments/provenance.py",
     "experiments/executors.py", "experiments/solver_bench.py", "experiments/dompc_peer.py",
     "experiments/study_store.py", "progress_lines.py"}
)  # fmt: skip
"""Modules that do not change computed numbers (how results are shown, stored or run): not hashed."""


@functools.cache
def code_version() -> str:
    """A hash of the uiest code that computes results and of the numerical libraries' versions.

    The ``.py`` files of the installed package except :data:`PRESENTATION`.
    Results computed by different code (a changed estimator, another CasADi) get different
    versions, with or without git; 16 hex digits.
    """
    digest = hashlib.sha256()
    for path in sorted(PACKAGE.rglob("*.py")):
        if str(path.relative_to(PACKAGE)) in PRESENTATION:
            continue
        digest.update(str(path.relative_to(PACKAGE)).encode())
        digest.update(path.read_bytes())
    for package in ("casadi", "numpy", "scipy", "cvxpy", "clarabel"):
        digest.update(versions().get(package, "").encode())
    return digest.hexdigest()[:16]


def keyed_scenario(scenario: Any) -> dict[str, Any]:
    """What of a scenario keys its stored runs: its fields but the run count and a model file's path.

    A run's result does not depend on how many runs there are (each run's seeds are its own), nor on how the model
    file's path is spelled (its bytes are keyed by :func:`model_digest`): adding runs, or naming the same file by
    another path, reuses the runs stored.
    """
    data: dict[str, Any] = scenario.to_dict()
    data.pop("runs", None)
    if str(data.get("model", "")).endswith(".py"):
        data["model"] = "model file"
    return data


def stamp() -> dict[str, Any]:
    """What every manifest records of the call that wrote it: when (UTC), machine, versions, git revision, code."""
    return {
        "created": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "machine": machine(),
        "versions": versions(),
        "git_revision": git_revision(),
        "code_version": code_version(),
    }


def file_digest(path: str | os.PathLike[str]) -> str:
    """The SHA-256 (hex) of a file's bytes; ``"unreadable: <reason>"`` for a file that cannot be read."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError as exc:
        return f"unreadable: {exc.strerror or exc}"


def model_digest(model: str) -> str:
    """The SHA-256 (hex) of a model file's bytes; ``""`` for a registered name (built-ins: in :func:`code_version`).

    Keys of stored runs include it, so an edited model file is computed again, never taken from the store.
    A file that cannot be read gives ``"unreadable: <reason>"`` (loading it then fails with the reason).
    """
    return file_digest(model) if model.endswith(".py") else ""
