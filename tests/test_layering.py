"""The package's layout: one subpackage per concern, each ``__init__`` the list of what it exports,
``ctfit/__init__.py`` the one public list, and no module reaching into another's private names."""

import ast
import importlib
import re
from pathlib import Path

import pytest

import ctfit

PACKAGE = Path(__file__).resolve().parents[1] / "ctfit"
SUBPACKAGES = sorted(p.parent.name for p in PACKAGE.glob("_*/__init__.py"))


def _imports(path: Path):
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.level >= 1:
            yield node


def _table(package: str) -> dict[str, str]:
    """name -> module of a subpackage's lazy export table (its ``submod_attrs``)."""
    tree = ast.parse((PACKAGE / package / "__init__.py").read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if isinstance(node, ast.keyword) and node.arg == "submod_attrs":
            table = ast.literal_eval(node.value)
            return {name: module for module, names in table.items() for name in names}
    raise AssertionError(f"{package}/__init__.py has no submod_attrs table")


def test_the_concerns_have_their_folders():
    assert SUBPACKAGES == ["_cli", "_colour", "_export", "_fitting", "_io", "_model", "_render", "_runtime", "_sampling"]
    assert sorted(p.name for p in PACKAGE.glob("*.py")) == ["__init__.py", "__main__.py", "cli.py", "internal.py"]  # __main__: python -m ctfit


def test_no_private_name_is_imported_from_another_module():
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in _imports(path):
            found += [f"{path.relative_to(PACKAGE)}: from {'.' * node.level}{node.module} import {a.name}" for a in node.names if a.name.startswith("_")]
    assert not found, "\n".join(found)


def test_other_subpackages_are_reached_through_their_init():
    """``from .._fitting import fit_core``, never ``from .._fitting.least_squares import ...``."""
    found = []
    for path in sorted(PACKAGE.glob("_*/*.py")):
        for node in _imports(path):
            if node.level == 2 and node.module and "." in node.module:
                found.append(f"{path.relative_to(PACKAGE)}: from ..{node.module} import ...")
    assert not found, "\n".join(found)


def test_every_name_a_module_takes_from_a_subpackage_is_in_its_table():
    missing = []
    tables = {p: _table(p) for p in SUBPACKAGES}
    for path in sorted(PACKAGE.glob("_*/*.py")):
        for node in _imports(path):
            if node.level == 2 and node.module in tables:
                missing += [f"{path.relative_to(PACKAGE)}: {node.module}.{a.name}" for a in node.names if a.name not in tables[node.module]]
    assert not missing, "\n".join(missing)


def test_each_subpackage_table_names_real_objects_and_no_submodule():
    """Every listed name exists in its module, and none is also the name of a module of the same
    folder (importing that module would replace the exported object on the package)."""
    for package in SUBPACKAGES:
        modules = {p.stem for p in (PACKAGE / package).glob("*.py")}
        for name, module in _table(package).items():
            assert name not in modules, f"{package}: {name} is both an export and a module"
            assert module in modules, f"{package}: no module {module}"
            assert hasattr(importlib.import_module(f"ctfit.{package}.{module}"), name), f"{package}.{module} has no {name}"


def test_the_public_list_is_one_table():
    """The public names are written once, in ``ctfit/__init__.pyi`` (what type checkers read and
    what ``lazy_loader.attach_stub`` loads from): ``__all__`` is that list, ``__init__.py`` spells
    no name out, and every public name is what its subpackage exports."""
    tree = ast.parse((PACKAGE / "__init__.pyi").read_text(encoding="utf-8"))
    listed = {}
    for imp in tree.body:
        if isinstance(imp, ast.ImportFrom):
            assert imp.level == 1 and all(a.name == a.asname for a in imp.names)
            listed |= {a.name: imp.module for a in imp.names}
    assert set(ctfit.__all__) == set(listed) and len(listed) > 100
    init = ast.parse((PACKAGE / "__init__.py").read_text(encoding="utf-8"))
    spelled = {n.value for n in ast.walk(init) if isinstance(n, ast.Constant) and isinstance(n.value, str)}
    spelled |= {n.id for n in ast.walk(init) if isinstance(n, ast.Name)}
    spelled |= {a.asname or a.name for n in ast.walk(init) if isinstance(n, ast.ImportFrom) for a in n.names}
    assert not spelled & set(listed)  # no second list in __init__.py
    for name, package in listed.items():
        assert name in _table(package), f"{name}: not exported by ctfit.{package}"
        assert getattr(ctfit, name) is getattr(importlib.import_module(f"ctfit.{package}"), name)


def test_the_architecture_page_names_every_module():
    """``docs/architecture.md`` has a row per folder that names each of its modules."""
    rows = {}
    for line in (PACKAGE.parent / "docs" / "architecture.md").read_text(encoding="utf-8").splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) == 3 and cells[0].startswith("`_"):
            rows[cells[0].strip("`/")] = cells[2]
    assert sorted(rows) == SUBPACKAGES
    for package in SUBPACKAGES:
        modules = sorted(p.stem for p in (PACKAGE / package).glob("*.py") if p.stem != "__init__")
        assert [m for m in modules if f"`{m}`" not in rows[package]] == [], package


def test_no_function_is_longer_than_80_lines():
    """Counting its decorators' lines, signature and docstring."""
    long = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                first = min([node.lineno] + [d.lineno for d in node.decorator_list])
                if node.end_lineno - first + 1 > 80:
                    long.append(f"{path.relative_to(PACKAGE)}:{node.lineno} {node.name}: {node.end_lineno - first + 1} lines")
    assert not long, "\n".join(long)


def test_scripts_and_notebooks_use_the_public_api():
    """``scripts/`` and ``notebooks/`` import ``ctfit`` and ``ctfit.internal`` only, never ``ctfit._*``."""
    root = PACKAGE.parent
    found = [f"{p.relative_to(root)}" for p in sorted([*root.glob("scripts/*.py"), *root.glob("notebooks/*.ipynb")])
             if re.search(r"\bctfit\._[a-z]", p.read_text(encoding="utf-8"))]
    assert not found, found


def test_every_name_of_ctfit_internal_resolves():
    import ctfit.internal

    assert all(getattr(ctfit.internal, name) is not None for name in ctfit.internal.__all__)
    with pytest.raises(AttributeError):
        ctfit.internal.not_a_name  # noqa: B018


LAYERS = ["_model", "_io", "_runtime", "_colour", "_fitting", "_render", "_export", "_sampling", "_cli"]
"""Lowest first: a folder imports only folders before it (docs/architecture.md)."""


def test_folders_import_only_lower_folders():
    assert sorted(LAYERS) == SUBPACKAGES
    upward = []
    for path in sorted(PACKAGE.glob("_*/*.py")):
        here = LAYERS.index(path.parent.name)
        for node in _imports(path):
            if node.level == 2 and node.module in LAYERS and LAYERS.index(node.module) >= here:
                upward.append(f"{path.relative_to(PACKAGE)} imports {node.module}")
    assert not upward, "\n".join(upward)
