"""The package's shape, read from its source with ``ast``: what a change elsewhere must not undo."""

from __future__ import annotations

import ast
from pathlib import Path

from mavattitude.estimation import METHODS

PACKAGE = Path(__file__).resolve().parents[1] / "mavattitude"
#: Where a method's name may stand in a comparison: the tables that name the methods.
REGISTRIES = {PACKAGE / "estimation" / "methods.py", PACKAGE / "estimation" / "kernel.py"}


def _modules() -> dict[Path, ast.Module]:
    return {path: ast.parse(path.read_text(encoding="utf-8")) for path in sorted(PACKAGE.rglob("*.py"))}


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
