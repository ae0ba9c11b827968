"""The layer contract: imports between uiest modules run one way, from a layer to its own or lower ones.

The graph is read with ``ast`` from the sources, imports inside functions included (a lazy import is still a
dependency). Imports under ``if TYPE_CHECKING:`` are left out: they are for the type checker only. A function may
import a uiest module only when it is a package's module-level ``__getattr__`` (a lazy attribute that keeps
``import uiest`` light); its edge still counts for cycles and layers.
"""

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

import uiest
from uiest.estimators.design_hook import design_function

SOURCES = Path(uiest.__file__).resolve().parent

LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("base", ("errors", "checks", "box", "paths", "atomic", "lock", "progress_lines", "theory", "sampling",
              "guarantee", "health", "input_model")),
    ("system", ("signal", "system", "ode", "noise", "simulate", "results", "run_data", "covariance", "likelihood",
                "filter_fit", "scales", "augmented", "plotting")),
    ("window and certificates", ("window", "detectability", "delay")),
    ("models", ("reduction", "models")),
    ("estimators", ("estimators.*", "kalman", "tuning")),
    ("design", ("design", "estimators")),
    ("analysis", ("analysis", "estimate")),
    ("experiments", ("experiments",)),
    ("interface", ("cli", "__main__", "")),
)  # fmt: skip
"""Layers from the lowest up; names relative to ``uiest``. A name covers its submodules; ``pkg.*`` covers only the
submodules of ``pkg`` (``estimators.*`` are the estimators, the package ``uiest.estimators`` is the facade that
also loads the design layer); ``""`` is the package ``uiest`` itself."""


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


def imports(root: Path) -> list[tuple[str, str, bool, bool]]:
    """``(importer, imported, in_function, in_lazy_getattr)`` for every import between uiest modules."""
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
            functions = [q for q in chain if isinstance(q, ast.FunctionDef | ast.AsyncFunctionDef)]
            lazy = (
                path.name == "__init__.py"
                and len(functions) == 1
                and functions[0].name == "__getattr__"
                and parents[functions[0]] is tree
            )
            if isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    stem = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join([*stem, *([node.module] if node.module else [])])
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
            else:
                targets = [a.name for a in node.names]
            found += [(module, t, bool(functions), lazy) for t in targets if t in modules and t != module]
    return found


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


def fresh_environment() -> dict[str, str]:
    """The environment of a fresh interpreter that imports these sources."""
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(SOURCES.parent), os.environ.get("PYTHONPATH", "")])}


def test_the_graph_is_read():
    importers = {a for a, *_ in GRAPH}
    assert {"uiest.estimators.uise", "uiest.design", "uiest.cli"} <= importers
    assert ("uiest.system", "uiest.box", False, False) in GRAPH


def test_function_level_type_checking_and_lazy_imports_are_told_apart(tmp_path):
    package = tmp_path / "uiest"
    (package / "sub").mkdir(parents=True)
    (package / "a.py").write_text("from uiest import b\n\ndef f():\n    from uiest.sub import c\n")
    (package / "b.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from uiest import a\n")
    (package / "__init__.py").write_text("def __getattr__(name):\n    from . import a\n")
    (package / "sub" / "__init__.py").write_text("")
    (package / "sub" / "c.py").write_text("from ..b import x\nimport uiest.a\n")
    assert sorted(imports(package)) == [
        ("uiest", "uiest.a", True, True),
        ("uiest.a", "uiest.b", False, False),
        ("uiest.a", "uiest.sub.c", True, False),
        ("uiest.sub.c", "uiest.a", False, False),
        ("uiest.sub.c", "uiest.b", False, False),
    ]
    assert cycles({(a, b) for a, b, *_ in imports(package)}) == [["uiest.a", "uiest.sub.c"]]


def test_no_import_cycles():
    assert cycles({(a, b) for a, b, *_ in GRAPH}) == []


def test_no_function_level_imports_between_uiest_modules():
    local = sorted({(a, b) for a, b, in_function, lazy in GRAPH if in_function and not lazy})
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
    [("uiest", "interface"), ("uiest.estimators", "design"), ("uiest.estimators.uise", "estimators"),
     ("uiest.window.gauss_newton", "window and certificates"), ("uiest.box", "base")],
)  # fmt: skip
def test_layer_of(module, layer):
    assert LAYERS[layer_of(module)][0] == layer


def test_the_checks_catch_a_cycle_and_an_upward_import():
    assert cycles({("a", "b"), ("b", "c"), ("c", "a"), ("c", "d")}) == [["a", "b", "c"]]
    assert layer_of("uiest.experiments.scenario") > layer_of("uiest.models.crop_growth")


def test_the_design_layer_is_registered_whenever_an_estimator_is_reachable():
    code = (
        "from uiest.estimators.uise import UISE; from uiest.estimators.design_hook import design_function as f; "
        "assert f('design_uise').__module__ == 'uiest.design' and UISE.design"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=fresh_environment())
    assert done.returncode == 0, done.stderr


def test_an_unregistered_design_function_is_named():
    with pytest.raises(LookupError, match="no_such_design"):
        design_function("no_such_design")
