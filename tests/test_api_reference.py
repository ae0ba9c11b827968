"""The API reference covers every public name: ``__all__`` in every public module, each name documented once.

Runs the reference's generator (docs/api_reference.py) without Sphinx.
"""

import importlib
import importlib.util
import inspect
import sys
from pathlib import Path

import pytest

import uiest

DOCS = Path(__file__).resolve().parents[1] / "docs"
SOURCE = Path(uiest.__file__).resolve().parent


def load_generator():
    spec = importlib.util.spec_from_file_location("api_reference", DOCS / "api_reference.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("api_reference", module)
    spec.loader.exec_module(module)
    return module


api_reference = load_generator()


def module_files() -> dict[str, Path]:
    """Every module file under src/uiest whose dotted name has no component starting with '_'."""
    found = {}
    for path in SOURCE.rglob("*.py"):
        parts = list(path.relative_to(SOURCE.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if not any(part.startswith("_") for part in parts):
            found[".".join(parts)] = path
    return found


def test_the_generator_finds_every_public_module_file():
    assert sorted(module_files()) == api_reference.public_modules()


@pytest.mark.parametrize("name", sorted(module_files()))
def test_public_module_lists_existing_names_in_all(name):
    module = importlib.import_module(name)
    listed = module.__dict__.get("__all__")
    assert isinstance(listed, list) and listed, f"{name} has no __all__ (or an empty one)"
    assert len(set(listed)) == len(listed), f"{name}.__all__ lists a name twice"
    missing = [entry for entry in listed if not hasattr(module, entry)]
    assert not missing, f"{name}.__all__ lists names it does not have: {missing}"
    private = [entry for entry in listed if entry.startswith("_") and entry != "__version__"]
    assert not private, f"{name}.__all__ lists private names: {private}"


def test_every_listed_name_has_one_page_at_its_defining_module():
    entries = api_reference.entries()
    listed = {(name, entry) for name in module_files() for entry in importlib.import_module(name).__all__}
    assert {(entry.module, entry.name) for entry in entries} == listed
    pages = [entry.target for entry in entries if entry.defined_here]
    assert len(pages) == len(set(pages)), "a name documented twice"
    for entry in entries:
        value = getattr(importlib.import_module(entry.module), entry.name)
        assert getattr(importlib.import_module(entry.home), entry.name) is value
        if not entry.defined_here:
            assert entry.target in pages, f"{entry.module}.{entry.name} links to {entry.target}, which has no page"
        if inspect.isclass(value) or inspect.isfunction(value):
            assert value.__module__ == entry.home, f"{entry.target} is defined in {value.__module__}"


def test_the_package_reexports_link_to_their_modules():
    homes = {entry.name: entry for entry in api_reference.entries() if entry.module == "uiest"}
    assert homes["System"].target == "uiest.system.System"
    assert homes["simulate"].target == "uiest.simulate.simulate"
    assert homes["analyse"].target == "uiest.analysis.analyse.analyse"
    assert homes["__version__"].defined_here


def test_a_module_without_all_is_refused(monkeypatch):
    module = importlib.import_module("uiest.box")
    monkeypatch.delattr(module, "__all__")
    with pytest.raises(LookupError, match=r"uiest\.box has no __all__"):
        api_reference.entries()


def test_a_listed_name_the_module_lacks_is_refused(monkeypatch):
    module = importlib.import_module("uiest.box")
    monkeypatch.setattr(module, "__all__", [*module.__all__, "NoSuchName"])
    with pytest.raises(LookupError, match="NoSuchName"):
        api_reference.entries()


def test_a_reexport_whose_home_does_not_list_it_is_refused(monkeypatch):
    module = importlib.import_module("uiest.system")
    monkeypatch.setattr(module, "__all__", [name for name in module.__all__ if name != "System"])
    with pytest.raises(LookupError, match="'System'"):
        api_reference.entries()


def test_pages_are_written_for_every_documented_name(tmp_path):
    written = api_reference.write_pages(tmp_path / "api")
    entries = api_reference.entries()
    own = [entry for entry in entries if entry.defined_here]
    assert written == len(own)
    for entry in own:
        page = (tmp_path / "api" / f"{api_reference.page_name(entry.target)}.rst").read_text()
        assert f":: {entry.name}" in page
        assert f"`~{entry.target}`" in (tmp_path / "api" / f"{entry.module}.rst").read_text()
    index = (tmp_path / "api" / "index.rst").read_text()
    assert all(f"   {name}\n" in index for name in api_reference.public_modules())
