"""The package's shape, read from its source with ``ast``: what a change elsewhere must not undo.

The import graph counts every import: at the top, inside functions, and under ``TYPE_CHECKING`` (a module
that names another's types knows it as much as one that calls it).
"""

from __future__ import annotations

import ast
from pathlib import Path

from mavattitude.estimation import METHODS

PACKAGE = Path(__file__).resolve().parents[1] / "mavattitude"
#: Where a method's name may stand in a comparison: the tables that name the methods.
REGISTRIES = {PACKAGE / "estimation" / "methods.py", PACKAGE / "estimation" / "kernel.py"}


def _modules() -> dict[Path, ast.Module]:
    return {path: ast.parse(path.read_text(encoding="utf-8")) for path in sorted(PACKAGE.rglob("*.py"))}


def _name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _import_graph() -> dict[str, set[str]]:
    """Module → the package's modules it imports (``from a import b``: ``a.b`` when that is a module, else ``a``)."""
    trees = {_name(path): (path, tree) for path, tree in _modules().items()}
    graph: dict[str, set[str]] = {}
    for name, (path, tree) in trees.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        targets = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                targets |= {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom):
                base = ".".join(package.split(".")[: len(package.split(".")) - node.level + 1]) if node.level else ""
                module = ".".join(p for p in (base, node.module or "") if p)
                targets |= {f"{module}.{a.name}" if f"{module}.{a.name}" in trees else module for a in node.names}
        graph[name] = {_owner(t, trees) for t in targets} - {name, ""}
    return graph


def _owner(target: str, modules: dict) -> str:
    """The package's module ``target`` names (itself, or the module holding it), "" outside the package."""
    while target and target not in modules:
        target = target.rpartition(".")[0]
    return target


def _layer(module: str) -> str:
    """The top-level module or sub-package: ``mavattitude.link.tlog`` → ``mavattitude.link``."""
    return ".".join(module.split(".")[:2])


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one node (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = stack[stack.index(v) :]
            del stack[stack.index(v) :]
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_graph_is_read_from_the_imports():
    """Not vacuous: the edges the package is known to have are found (one per kind of import)."""
    graph = _import_graph()
    assert "mavattitude.pipeline" in graph["mavattitude.dispatch"]  # from mavattitude.pipeline import Pushed
    assert "mavattitude.estimation.kernel" in graph["mavattitude.estimation.methods"]  # from . import kernel
    assert "mavattitude.link.tlog" in graph["mavattitude.link.logs"]
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_module_imports_one_that_imports_it_back():
    assert _cycles(_import_graph()) == []


def test_no_layer_imports_one_that_imports_it_back():
    """The same between the package's top-level modules and sub-packages (sensors, estimation, link, dispatch,
    cli, commands, …): a layer below never reaches back up, even through another module."""
    layers: dict[str, set[str]] = {}
    for module, targets in _import_graph().items():
        layers.setdefault(_layer(module), set()).update(_layer(t) for t in targets)
    assert _cycles({k: v - {k} for k, v in layers.items()}) == []


def test_no_method_name_is_compared_outside_the_registry():
    """``== "fused"``, ``!= "ml"``, ``in ("ign", …)``: each is a rule the method table (estimation/methods.py,
    the kernel's RULES) holds, and a new method would have to find."""
    found = []
    for path, tree in _modules().items():
        if path in REGISTRIES:
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.Compare):
                names = [
                    c.value
                    for c in ast.walk(node)
                    if isinstance(c, ast.Constant) and isinstance(c.value, str) and c.value in METHODS
                ]
                found += [f"{path.relative_to(PACKAGE)}:{node.lineno}: {name}" for name in names]
    assert found == []
