"""The README's and the user pages' Python examples run as written, their links resolve, and no paper label appears."""

import re
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
PAGES = [README, DOCS / "getting-started.md", *sorted((DOCS / "concepts").glob("*.md")),
         *sorted((DOCS / "guides").glob("*.md"))]  # fmt: skip
"""Pages whose ```python blocks run as tests (the README, getting started, concepts and guides)."""
USER_PAGES = [*PAGES, DOCS / "performance.md", DOCS / "limitations.md", DOCS / "changelog.md", ROOT / "CHANGELOG.md"]
"""Pages a user reads: every page of this list is held to the link and label checks."""
BLOCKS = [
    (page, index, block)
    for page in PAGES
    for index, block in enumerate(re.findall(r"```python\n(.*?)```", page.read_text(), flags=re.DOTALL))
]
PAPER_LABEL = re.compile(r"\b(?:theo|eq|ass|lem|prop|rem|def|cor|sec):[A-Za-z_][\w-]*")


@pytest.mark.parametrize(
    ("page", "index", "block"), BLOCKS, ids=[f"{page.relative_to(ROOT)}:{index}" for page, index, _ in BLOCKS]
)
@pytest.mark.slow
def test_python_block_runs(page, index, block, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    exec(compile(block, f"{page.relative_to(ROOT)} block {index}", "exec"), {"__name__": "__readme__"})


def test_readme_has_examples_and_every_user_page_exists():
    assert sum(page == README for page, _, _ in BLOCKS) >= 1
    assert all(page.is_file() for page in USER_PAGES)
    assert len(PAGES) >= 10, PAGES


def test_readme_is_a_short_page():
    assert len(README.read_text().splitlines()) <= 150


@pytest.mark.parametrize("page", USER_PAGES, ids=[str(page.relative_to(ROOT)) for page in USER_PAGES])
def test_relative_links_and_images_resolve(page):
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.DOTALL)
    targets = re.findall(r"\]\(([^)\s]+)\)", text)
    local = [target.split("#")[0] for target in targets if not re.match(r"[a-z]+:", target)]
    missing = [target for target in local if target and not (page.parent / target).exists()]
    assert not missing, f"{page.name}: links to missing files {missing}"


@pytest.mark.parametrize("page", USER_PAGES, ids=[str(page.relative_to(ROOT)) for page in USER_PAGES])
def test_no_paper_label_on_a_user_page(page):
    labels = PAPER_LABEL.findall(page.read_text())
    assert not labels, f"{page.name}: paper labels {labels}; name results in words and link the theory map"


def test_ci_runs_the_readmes_test_command_on_the_pinned_versions():
    commands = re.findall(r"^(python3 -m venv .*)$", README.read_text(), flags=re.MULTILINE)
    assert len(commands) == 2 and all("-c constraints.txt" in command for command in commands)
    assert commands[1] in (ROOT / ".ci" / "run").read_text().splitlines()
    pinned = {
        line.split("==")[0].lower().replace("_", "-")
        for line in (ROOT / "constraints.txt").read_text().splitlines()
        if "==" in line and not line.startswith("#")
    }
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    extras = project["optional-dependencies"]
    requirements = [*project["dependencies"], *extras["dev"], *extras["docs"]]
    declared = [re.match(r"[A-Za-z0-9_.-]+", requirement).group(0) for requirement in requirements]
    unpinned = sorted({name.lower().replace("_", "-") for name in declared} - pinned)
    assert declared and not unpinned, f"dependencies without a tested version in constraints.txt: {unpinned}"
