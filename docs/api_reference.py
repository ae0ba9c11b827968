"""The API reference's pages, generated from ``__all__`` of every public module of uiest.

A public module is one whose dotted name has no component starting with ``_``. Each name in a module's
``__all__`` gets one page, at the module that defines it; a name a package re-exports from one of its
modules (``uiest.System`` is ``uiest.system.System``) is listed on the package's page with a link to that
page. ``docs/conf.py`` calls :func:`write_pages` before Sphinx reads the sources, so a name added to an
``__all__`` gets its page without editing the docs; ``tests/test_api_reference.py`` checks the lists
without building the site.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import pkgutil
import shutil
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

PACKAGE = "uiest"
LONGEST_VALUE = 120  # characters of a constant's repr shown on its page; longer values are left out


@dataclass(frozen=True)
class Entry:
    """One name in a module's ``__all__``: where it is listed and the module that defines (documents) it."""

    module: str
    name: str
    home: str
    kind: str  # "module", "class", "exception", "function" or "data"

    @property
    def target(self) -> str:
        """The dotted name of the documented object."""
        return f"{self.home}.{self.name}"

    @property
    def defined_here(self) -> bool:
        """Whether the module listing the name defines it (else it re-exports it)."""
        return self.home == self.module


def public_modules() -> list[str]:
    """Dotted names of uiest and every module under it without a component starting with ``_``."""
    package = importlib.import_module(PACKAGE)
    found = [PACKAGE]
    for info in pkgutil.walk_packages(package.__path__, f"{PACKAGE}."):
        if not any(part.startswith("_") for part in info.name.split(".")):
            found.append(info.name)
    return sorted(found)


def defined_names(module: ModuleType) -> set[str]:
    """Names a module's source binds at its top level (definitions and assignments, not imports)."""
    source = inspect.getsource(module)
    names: set[str] = set()
    for node in ast.parse(source).body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names.add(node.name)
        elif isinstance(node, ast.Assign):
            names.update(target.id for target in node.targets if isinstance(target, ast.Name))
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.add(node.target.id)
    return names


def kind_of(value: object) -> str:
    """How Sphinx documents a value: as a module, class, exception, function or data."""
    if inspect.ismodule(value):
        return "module"
    if inspect.isclass(value):
        return "exception" if issubclass(value, BaseException) else "class"
    if inspect.isfunction(value) or inspect.isbuiltin(value):
        return "function"
    return "data"


def entries() -> list[Entry]:
    """Every name of every public module's ``__all__``, with its defining module.

    Raises
    ------
    LookupError
        A module without ``__all__``, a listed name the module lacks, or a re-exported name whose defining
        module does not list it in its own ``__all__``.

    """
    modules = {name: importlib.import_module(name) for name in public_modules()}
    defined = {name: defined_names(module) for name, module in modules.items()}
    without = [name for name, module in modules.items() if "__all__" not in vars(module)]
    if without:
        raise LookupError(f"{', '.join(without)} has no __all__")
    found: list[Entry] = []
    for module_name, module in modules.items():
        for name in module.__all__:
            if not hasattr(module, name):
                raise LookupError(f"{module_name}.__all__ lists {name!r}, which {module_name} does not have")
            value = getattr(module, name)
            if name in defined[module_name]:
                home = module_name
            else:
                homes = [
                    other
                    for other, other_module in modules.items()
                    if name in defined[other]
                    and name in getattr(other_module, "__all__", ())
                    and getattr(other_module, name, None) is value
                ]
                if len(homes) != 1:
                    raise LookupError(
                        f"{module_name}.__all__ lists {name!r}, defined elsewhere; expected exactly one public "
                        f"module that defines it and lists it in its __all__, found {homes}"
                    )
                home = homes[0]
            found.append(Entry(module_name, name, home, kind_of(value)))
    return found


def page_name(target: str) -> str:
    """The document name (below docs/api) of one name's page."""
    return f"generated/{target}"


def name_page(entry: Entry) -> str:
    """The reStructuredText of one documented name's page.

    The page is in no toctree (``:orphan:``): its module's page links to it, and the site's navigation lists
    modules, not every name.
    """
    lines = [":orphan:", "", entry.target.replace("_", r"\_"), "=" * (len(entry.target) + entry.target.count("_")), ""]
    lines.append(f".. currentmodule:: {entry.home}")
    lines.append("")
    if entry.kind in ("class", "exception"):
        lines += [f".. auto{entry.kind}:: {entry.name}", "   :members:", "   :show-inheritance:"]
    elif entry.kind == "function":
        lines.append(f".. autofunction:: {entry.name}")
    else:
        value = getattr(importlib.import_module(entry.home), entry.name)
        lines.append(f".. autodata:: {entry.name}")
        if len(repr(value)) > LONGEST_VALUE:
            lines.append("   :no-value:")
    return "\n".join(lines) + "\n"


def summary(entry: Entry, attribute_docs: dict[str, str]) -> str:
    """The first paragraph of a name's docstring (of a constant: its ``#:`` comment or string), on one line."""
    value = getattr(importlib.import_module(entry.home), entry.name)
    text = attribute_docs.get(entry.name, "") if entry.kind == "data" else inspect.getdoc(value) or ""
    return " ".join(text.strip().split("\n\n")[0].split())


def module_page(module_name: str, listed: list[Entry], attribute_docs: dict[str, str] | None = None) -> str:
    """The reStructuredText of a module's page: its docstring, a table of its names, its re-exports."""
    title = f"``{module_name}``"
    lines = [title, "=" * len(title), "", f".. automodule:: {module_name}", "   :no-members:", ""]
    own = [entry for entry in listed if entry.defined_here]
    reexported = [entry for entry in listed if not entry.defined_here]
    role = {"module": "mod", "class": "class", "exception": "exc", "function": "func", "data": "data"}
    if own:
        lines += [".. list-table::", "   :widths: 30 70", ""]
        for entry in own:
            lines += [
                f"   * - :py:{role[entry.kind]}:`~{entry.target}`",
                f"     - {summary(entry, attribute_docs or {})}",
            ]
        lines.append("")
    if reexported:
        lines += ["Also available here, documented where they are defined:", ""]
        lines += [f"- ``{module_name}.{entry.name}``: :py:{role[entry.kind]}:`{entry.target}`" for entry in reexported]
        lines.append("")
    return "\n".join(lines)


def index_page(modules: list[str]) -> str:
    """The reStructuredText of the reference's index: every public module, by package."""
    lines = [
        "API reference",
        "=============",
        "",
        "Every public name of uiest, one page each, generated from the ``__all__`` of every public module.",
        "Names a package re-exports (such as ``uiest.System``) are documented at the module that defines them",
        "and linked from the package's page.",
        "",
        ".. toctree::",
        "   :maxdepth: 1",
        "",
    ]
    lines += [f"   {module}" for module in modules]
    return "\n".join(lines) + "\n"


def attribute_docs(module_name: str) -> dict[str, str]:
    """The docstrings of a module's constants, by name (a string after the assignment, or ``#:`` comments above)."""
    source = inspect.getsource(importlib.import_module(module_name))
    lines = source.splitlines()
    body = ast.parse(source).body
    found: dict[str, str] = {}
    for node, after in zip(body, [*body[1:], None], strict=True):
        if isinstance(node, ast.Assign):
            names = [target.id for target in node.targets if isinstance(target, ast.Name)]
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names = [node.target.id]
        else:
            continue
        comments = []
        row = node.lineno - 2
        while row >= 0 and lines[row].lstrip().startswith("#:"):
            comments.insert(0, lines[row].lstrip()[2:].strip())
            row -= 1
        text = "\n".join(comments)
        if isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant) and isinstance(after.value.value, str):
            text = inspect.cleandoc(after.value.value)
        for name in names:
            if text:
                found[name] = text
    return found


def write_pages(folder: Path, found: list[Entry] | None = None) -> int:
    """Write the reference (index, one page per module, one per documented name) into ``folder``.

    Parameters
    ----------
    folder
        The reference's folder (docs/api); it is emptied first.
    found
        The entries to document (default: :func:`entries`).

    Returns
    -------
    int
        The number of name pages written.

    """
    found = entries() if found is None else found
    modules = sorted({entry.module for entry in found} | set(public_modules()))
    if folder.exists():
        shutil.rmtree(folder)
    (folder / "generated").mkdir(parents=True)
    (folder / "index.rst").write_text(index_page(modules))
    for module_name in modules:
        listed = [entry for entry in found if entry.module == module_name]
        (folder / f"{module_name}.rst").write_text(module_page(module_name, listed, attribute_docs(module_name)))
    own = [entry for entry in found if entry.defined_here]
    for entry in own:
        (folder / f"{page_name(entry.target)}.rst").write_text(name_page(entry))
    return len(own)
