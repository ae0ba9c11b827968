"""The README's Python examples run as written."""

import re
import tomllib
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
BLOCKS = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.DOTALL)


@pytest.mark.parametrize("index", range(len(BLOCKS)))
@pytest.mark.slow
def test_readme_python_block_runs(index, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    exec(compile(BLOCKS[index], f"README.md block {index}", "exec"), {"__name__": "__readme__"})


def test_readme_has_examples():
    assert len(BLOCKS) >= 2


def test_ci_runs_the_readmes_test_command_on_the_pinned_versions():
    root = README.parent
    commands = re.findall(r"^(python3 -m venv .*)$", README.read_text(), flags=re.MULTILINE)
    assert len(commands) == 2 and all("-c constraints.txt" in command for command in commands)
    assert commands[1] in (root / ".ci" / "run").read_text().splitlines()
    pinned = {
        line.split("==")[0].lower().replace("_", "-")
        for line in (root / "constraints.txt").read_text().splitlines()
        if "==" in line and not line.startswith("#")
    }
    project = tomllib.loads((root / "pyproject.toml").read_text())["project"]
    requirements = [*project["dependencies"], *project["optional-dependencies"]["dev"]]
    declared = [re.match(r"[A-Za-z0-9_.-]+", requirement).group(0) for requirement in requirements]
    unpinned = sorted({name.lower().replace("_", "-") for name in declared} - pinned)
    assert declared and not unpinned, f"dependencies without a tested version in constraints.txt: {unpinned}"
