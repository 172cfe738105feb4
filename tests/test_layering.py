"""Modules use each other's public names only: no ``from ._x import _name`` inside the package."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "ctfit"


def test_no_private_name_is_imported_from_another_module():
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.level >= 1 and node.module:
                found += [f"{path.relative_to(PACKAGE)}: from {'.' * node.level}{node.module} import {a.name}" for a in node.names if a.name.startswith("_")]
    assert not found, "\n".join(found)
