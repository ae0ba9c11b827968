"""``import uiest``, ``import uiest.estimators`` and ``import uiest.cli`` leave the heavy optional libraries unloaded.

pandas (records and tables), cvxpy (certificates), dask (clusters) and matplotlib (figures) are
imported where they are used; each check runs a fresh interpreter, since this one has them loaded.
"""

import os
import subprocess
import sys
from pathlib import Path

import pytest

import uiest

HEAVY = ("pandas", "cvxpy", "dask", "distributed", "matplotlib")
SOURCES = Path(uiest.__file__).resolve().parents[1]


def loaded_after(statement: str) -> list[str]:
    """The packages of :data:`HEAVY` in ``sys.modules`` after ``statement`` in a fresh interpreter."""
    code = f"{statement}; import sys; print(sorted({{m.split('.')[0] for m in sys.modules}} & {set(HEAVY)!r}))"
    path = os.pathsep.join([str(SOURCES), os.environ.get("PYTHONPATH", "")])
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env={**os.environ, "PYTHONPATH": path}
    )
    assert done.returncode == 0, done.stderr
    return eval(done.stdout)  # a printed list of names


@pytest.mark.parametrize("statement", ["import uiest", "import uiest.estimators", "import uiest.cli"])
def test_import_loads_no_heavy_library(statement):
    assert loaded_after(statement) == []


def test_the_fresh_interpreter_sees_what_it_loads():
    assert loaded_after("import uiest, pandas") == ["pandas"]


def test_a_certificate_loads_cvxpy_when_computed():
    statement = (
        "import uiest.estimators; from uiest.models.linear import example as model; "
        "from uiest.detectability import certify_strong_detectability as certify; certify(model())"
    )
    assert "cvxpy" in loaded_after(statement)
