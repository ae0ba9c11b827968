"""The docs' gallery and tutorials: every example has a gallery page, and no page cites the paper by a LaTeX label."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "examples").glob("*.py"))
PAGES = sorted((ROOT / "docs" / "gallery").glob("plot_*.py")) + sorted((ROOT / "docs" / "tutorials").glob("plot_*.py"))
LABEL = re.compile(r"\b(theo|eq|ass|lem|prop|rem|def|cor):[A-Za-z_]")


@pytest.mark.parametrize("example", EXAMPLES, ids=lambda path: path.name)
def test_every_example_has_a_gallery_page_that_shows_its_source(example):
    including = [
        page.name
        for page in (ROOT / "docs" / "gallery").glob("plot_*.py")
        if f".. literalinclude:: ../../examples/{example.name}" in page.read_text()
    ]
    assert including, f"no page in docs/gallery includes examples/{example.name}"


def test_the_gallery_shows_every_committed_figure():
    text = "\n".join(page.read_text() for page in (ROOT / "docs" / "gallery").glob("plot_*.py"))
    for figure in sorted((ROOT / "examples" / "figures").glob("*.png")):
        assert f".. image:: ../../examples/figures/{figure.name}" in text, figure.name


@pytest.mark.parametrize("page", PAGES, ids=lambda path: path.name)
def test_pages_are_sphinx_gallery_scripts_without_paper_labels(page):
    text = page.read_text()
    assert re.match(r'"""\n[^\n]+\n=+\n', text), "expected a docstring that opens with a reST title"
    assert not LABEL.search(text), LABEL.search(text).group(0)
