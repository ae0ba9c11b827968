"""The layer contract: imports between uiest modules run one way, from a layer to its own or lower ones.

The graph is read with ``ast`` from the sources, imports inside functions included (a lazy import is still a
dependency), and so are the packages Python imports on the way to a module (``import uiest.a.b`` runs
``uiest/a/__init__.py`` first; the root package ``uiest`` is left out: every import runs it, and it imports only
the base and system layers). Imports under ``if TYPE_CHECKING:`` are left out: they are for the type checker
only. No function imports a uiest module.
"""

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

import uiest

SOURCES = Path(uiest.__file__).resolve().parent

LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("base", ("errors", "checks", "box", "paths", "atomic", "json_text", "lock", "progress_lines", "theory", "sampling",
              "guarantee", "health", "input_model")),
    ("system", ("signal", "system", "ode", "noise", "simulate", "results", "run_data", "covariance", "likelihood",
                "filter_fit", "scales", "augmented", "plotting")),
    ("window and certificates", ("window", "detectability", "delay")),
    ("models", ("reduction", "models")),
    ("estimators", ("estimators", "tuning")),
    ("design", ("design",)),
    ("analysis", ("analysis", "estimate")),
    ("experiments", ("experiments",)),
    ("interface", ("cli", "__main__", "")),
)  # fmt: skip
"""Layers from the lowest up; names relative to ``uiest``. A name covers its submodules; ``pkg.*`` covers only the
submodules of ``pkg``; ``""`` is the package ``uiest`` itself."""


def module_names(root: Path) -> dict[str, Path]:
    """``uiest.a.b`` -> its file, for every module under ``root`` (the ``uiest`` package folder)."""
    names = {}
    for path in root.rglob("*.py"):
        parts = path.relative_to(root.parent).with_suffix("").parts
        names[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return names


def layer_of(module: str) -> int:
    """The index in :data:`LAYERS` of ``module`` (``uiest.x.y``): its exact name first, then the longest prefix."""
    best, length = None, -1
    for index, (_, names) in enumerate(LAYERS):
        for name in names:
            full = "uiest" if name == "" else f"uiest.{name}"
            if name.endswith(".*"):
                covers = module.startswith(full[:-1]) and module != full[:-2]
            else:
                covers = module == full or (name != "" and module.startswith(full + "."))
            size = len(full) + (1000 if module == full else 0)
            if covers and size > length:
                best, length = index, size
    if best is None:
        raise AssertionError(f"{module} is in no layer of LAYERS")
    return best


def imports(root: Path) -> list[tuple[str, str, bool]]:
    """``(importer, imported, in_function)`` for every import between uiest modules."""
    modules = module_names(root)
    found = []
    for module, path in modules.items():
        tree = ast.parse(path.read_text())
        parents = {child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)}
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        for node in ast.walk(tree):
            if not isinstance(node, ast.Import | ast.ImportFrom):
                continue
            chain, q = [], node
            while q in parents:
                q = parents[q]
                chain.append(q)
            if any(isinstance(q, ast.If) and "TYPE_CHECKING" in ast.unparse(q.test) for q in chain):
                continue
            in_function = any(isinstance(q, ast.FunctionDef | ast.AsyncFunctionDef) for q in chain)
            if isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    stem = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join([*stem, *([node.module] if node.module else [])])
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
            else:
                targets = [a.name for a in node.names]
            own = packages_on_the_way(module) + ([module] if path.name == "__init__.py" else [])
            targets += [p for t in targets for p in packages_on_the_way(t) if p in modules and p not in own]
            targets = [t for t in dict.fromkeys(targets) if t in modules and t != module]
            found += [(module, t, in_function) for t in targets]
    return found


def packages_on_the_way(module: str) -> list[str]:
    """The packages Python imports before ``module`` (``uiest.a.b.c`` -> ``uiest.a``, ``uiest.a.b``), not ``uiest``.

    A module's own packages are not its dependencies: they are being imported when it runs."""
    parts = module.split(".")
    return [".".join(parts[:i]) for i in range(2, len(parts))]


def cycles(edges: set[tuple[str, str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    graph: dict[str, set[str]] = {}
    for a, b in edges:
        graph.setdefault(a, set()).add(b)
        graph.setdefault(b, set())
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


GRAPH = imports(SOURCES)


def test_the_graph_is_read():
    importers = {a for a, *_ in GRAPH}
    assert {"uiest.estimators.uise", "uiest.design", "uiest.cli"} <= importers
    assert ("uiest.system", "uiest.box", False) in GRAPH


def test_function_level_and_type_checking_imports_are_told_apart(tmp_path):
    package = tmp_path / "uiest"
    (package / "sub").mkdir(parents=True)
    (package / "a.py").write_text("from uiest import b\n\ndef f():\n    from uiest.sub import c\n")
    (package / "b.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from uiest import a\n")
    (package / "__init__.py").write_text("")
    (package / "sub" / "__init__.py").write_text("")
    (package / "sub" / "c.py").write_text("from ..b import x\nimport uiest.a\n")
    assert sorted(imports(package)) == [
        ("uiest.a", "uiest.b", False),
        ("uiest.a", "uiest.sub", True),
        ("uiest.a", "uiest.sub.c", True),
        ("uiest.sub.c", "uiest.a", False),
        ("uiest.sub.c", "uiest.b", False),
    ]
    assert cycles({(a, b) for a, b, *_ in imports(package)}) == [["uiest.a", "uiest.sub.c"]]


def test_a_cycle_through_a_package_init_is_found(tmp_path):
    package = tmp_path / "uiest"
    (package / "sub").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "sub" / "__init__.py").write_text("from uiest.sub.d import y\n")  # the facade loads d
    (package / "sub" / "d.py").write_text("from uiest import e\n")
    (package / "sub" / "c.py").write_text("")
    (package / "e.py").write_text("from uiest.sub.c import z\n")  # runs uiest/sub/__init__.py first
    assert ("uiest.e", "uiest.sub", False) in imports(package)
    assert cycles({(a, b) for a, b, *_ in imports(package)}) == [["uiest.e", "uiest.sub", "uiest.sub.d"]]


def test_no_import_cycles():
    assert cycles({(a, b) for a, b, *_ in GRAPH}) == []


def test_no_function_level_imports_between_uiest_modules():
    local = sorted({(a, b) for a, b, in_function in GRAPH if in_function})
    assert local == []


def test_every_module_imports_its_own_or_lower_layers():
    upward = sorted(
        f"{a} ({LAYERS[layer_of(a)][0]}) -> {b} ({LAYERS[layer_of(b)][0]})"
        for a, b, *_ in GRAPH
        if layer_of(b) > layer_of(a)
    )
    assert upward == []


def test_every_module_has_a_layer():
    for module in module_names(SOURCES):
        layer_of(module)


@pytest.mark.parametrize(
    ("module", "layer"),
    [("uiest", "interface"), ("uiest.estimators", "estimators"), ("uiest.estimators.uise", "estimators"),
     ("uiest.design", "design"),
     ("uiest.window.gauss_newton", "window and certificates"), ("uiest.box", "base")],
)  # fmt: skip
def test_layer_of(module, layer):
    assert LAYERS[layer_of(module)][0] == layer


def test_the_checks_catch_a_cycle_and_an_upward_import():
    assert cycles({("a", "b"), ("b", "c"), ("c", "a"), ("c", "d")}) == [["a", "b", "c"]]
    assert layer_of("uiest.experiments.scenario") > layer_of("uiest.models.crop_growth")


FIRST_IMPORTS = """
import importlib, pkgutil, sys
import uiest
names = sorted(m.name for m in pkgutil.walk_packages(uiest.__path__, "uiest.") if m.name != "uiest.__main__")
part, parts = int(sys.argv[1]), int(sys.argv[2])
for name in names[part::parts]:
    for loaded in [m for m in sys.modules if m == "uiest" or m.startswith("uiest.")]:
        del sys.modules[loaded]
    try:
        importlib.import_module(name)
    except Exception as exc:
        print(name, repr(exc))
"""


@pytest.mark.slow
def test_every_module_imports_first():
    """Each module imported before any other uiest module (a cycle through a package's __init__ breaks this)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(SOURCES.parent), os.environ.get("PYTHONPATH", "")])}
    parts = max(1, min(os.cpu_count() or 1, 4))  # a share of the modules per interpreter, run side by side
    pipes = {"stdout": subprocess.PIPE, "stderr": subprocess.PIPE, "text": True, "env": env}
    runs = [
        subprocess.Popen([sys.executable, "-c", FIRST_IMPORTS, str(part), str(parts)], **pipes) for part in range(parts)
    ]
    outputs = [run.communicate() for run in runs]  # every interpreter waited for before any assert
    for run, (stdout, stderr) in zip(runs, outputs, strict=True):
        assert run.returncode == 0, stderr
        assert stdout == ""
