"""The declared version ranges (issue 24): they hold the versions the suite runs on, and a package
whose private parts ctfit uses has an upper bound."""

import importlib.metadata
import re
import tomllib

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

from conftest import ROOT

NOT_IN_TEST = {"bench"}  # installed by make install-bench (make report), not by make test
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
DECLARED = [Requirement(r) for r in PROJECT["dependencies"]] + [
    Requirement(r) for extra, reqs in PROJECT["optional-dependencies"].items() for r in reqs if not r.startswith("ctfit[") and extra not in NOT_IN_TEST
]


def test_the_installed_versions_are_inside_the_declared_ranges():
    outside = []
    for req in DECLARED:
        version = importlib.metadata.version(req.name)
        if not req.specifier.contains(version, prereleases=True):
            outside.append(f"{req} (installed {version})")
    assert outside == []


def test_a_package_whose_private_parts_ctfit_uses_has_an_upper_bound():
    private = set()
    for path in (ROOT / "ctfit").rglob("*.py"):
        for name in re.findall(r"^\s*(?:from|import)\s+(\w+)\.(?:_\w+|experimental)\b", path.read_text(), flags=re.M):
            if name != "ctfit":
                private.add(canonicalize_name(name))
    assert {"jax"} <= private  # what this test is about: found by the scan (jax.experimental.serialize_executable)
    bounded = {canonicalize_name(r.name) for r in DECLARED if any(s.operator in ("<", "<=", "~=", "==") for s in r.specifier)}
    assert private <= bounded, private - bounded


def test_ctfit_uses_no_private_module_of_jax_optimistix_lineax_or_equinox():
    """Their public API only (issue 24): no ``jax._src``, ``optimistix._misc``, … imported anywhere."""
    found = []
    for path in (ROOT / "ctfit").rglob("*.py"):
        for line in path.read_text().splitlines():
            if re.match(r"\s*(?:from|import)\s+(?:jax|optimistix|lineax|equinox)\._\w+", line):
                found.append(f"{path.relative_to(ROOT)}: {line.strip()}")
    assert not found, found
