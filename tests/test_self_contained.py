"""The repository stands on its own: nothing refers to files beside it, saved notebook outputs
hold no machine paths, and an installed (non-editable) wheel carries the optical constants."""

import json
import os
import re
import shutil
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from ctfit import read_optical_constants

from conftest import MEASURED, ROOT, TABLES

# Built by concatenation so that this file does not match itself.
OUTSIDE = ("../" + "shared", "shared" + "/data", "FORMATS" + ".md")
MACHINE_PATH = re.compile(r"/work/|/home/|/root/|/tmp/|/Users/|\b[A-Za-z]:\\")


def repo_files() -> list:
    """Every file git would commit: tracked or untracked, not ignored (.venv, caches, builds)."""
    out = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"],
        cwd=ROOT, capture_output=True, check=True,
    ).stdout  # fmt: skip
    return [ROOT / p for p in sorted(set(out.decode().split("\0"))) if p and (ROOT / p).is_file()]


def test_the_real_measurements_are_in_the_repository():
    files = {p.relative_to(ROOT).as_posix() for p in repo_files()}
    for name in ("README.md", "pink-felt-1d.alta", "retro-3M-jaune.dat", "retro-gray-tape.dat"):
        assert (MEASURED / name).relative_to(ROOT).as_posix() in files, name
    # optical-constant tables belong in ctfit/data; the only CSVs under measurements/ are the
    # model-mismatch test-bed's renders (measurements/testbed/README.md)
    assert not any(f.startswith("measurements/") and f.endswith(".csv") and not f.startswith("measurements/testbed/") for f in files), (
        "tables belong in ctfit/data")


def test_nothing_refers_to_files_beside_the_repository():
    found = []
    for path in repo_files():
        text = path.read_bytes()
        for lineno, line in enumerate(text.split(b"\n"), 1):
            found += [f"{path.relative_to(ROOT)}:{lineno}: {s}" for s in OUTSIDE if s.encode() in line]
    assert not found, "\n".join(found)


def _output_texts(output: dict):
    """The text of a saved cell output (images left out: base64 can spell anything)."""
    yield from output.get("traceback", [])
    for key in ("text", "evalue"):
        if key in output:
            yield "".join(output[key]) if isinstance(output[key], list) else output[key]
    for mime, value in output.get("data", {}).items():
        if not mime.startswith("image/") or mime == "image/svg+xml":
            yield json.dumps(value)


def test_saved_notebook_outputs_hold_no_machine_paths():
    notebooks = sorted((ROOT / "notebooks").glob("*.ipynb"))
    assert notebooks
    found = []
    for path in notebooks:
        for i, cell in enumerate(json.loads(path.read_text(encoding="utf-8"))["cells"]):
            for output in cell.get("outputs", []):
                found += [f"{path.name} cell {i}: {m[0]!r}" for t in _output_texts(output) for m in MACHINE_PATH.finditer(t)]
    assert not found, "\n".join(found)


def test_machine_path_pattern():
    for text in ("/work/x/a.dat", "DataWarning: /home/u/a.dat", "/tmp/x", "C:\\Users\\me", "/Users/me"):
        assert MACHINE_PATH.search(text), text
    for text in ("../measurements/brdf/retro-gray-tape.dat", "measurements/brdf", "ratio 3:1"):
        assert not MACHINE_PATH.search(text), text


# --- the wheel ------------------------------------------------------------------------------------

CHECK = """
import json, sys
import numpy as np
import ctfit
m = ctfit.load_material(sys.argv[1])
print(json.dumps({"file": ctfit.__file__, "fresnel": m.structure.fresnel,
                  "n": np.asarray(m.params.n).tolist(), "k": np.asarray(m.params.k).tolist(),
                  "source": ctfit.read_optical_constants("Cu")["meta"]["source"]}))
"""


@pytest.mark.slow
def test_installed_wheel_finds_the_optical_constants(tmp_path):
    # Build from a copy of what git would commit (no stale build/ folder can leak in).
    src = tmp_path / "src"
    for path in repo_files():
        rel = path.relative_to(ROOT)
        if len(rel.parts) == 1 or rel.parts[0] == "ctfit":
            (src / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, src / rel)
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check"]
    # With build isolation: the project needs a newer setuptools than the venv may hold.
    build = subprocess.run(pip + ["wheel", "-q", "--no-deps", "-w", tmp_path / "wheels", src], capture_output=True, text=True)
    assert build.returncode == 0, build.stdout + build.stderr
    (wheel,) = (tmp_path / "wheels").glob("ctfit-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    for table in sorted(TABLES.glob("*.csv")):
        assert f"ctfit/data/optical_constants/{table.name}" in names, table.name
    assert not any(n.startswith(("measurements/", "tests/", "notebooks/")) for n in names)
    assert "ctfit/py.typed" in names  # PEP 561: type checkers read the package's annotations
    assert "ctfit/__init__.pyi" in names  # the public names: import ctfit reads it (lazy_loader.attach_stub)
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)  # the licence pyproject.toml names (MIT)

    site = tmp_path / "site"
    install = subprocess.run(pip + ["install", "-q", "--no-deps", "--target", site, wheel], capture_output=True, text=True)
    assert install.returncode == 0, install.stdout + install.stderr
    material = shutil.copy(ROOT / "configs" / "copper.toml", tmp_path / "copper.toml")  # optical_constants = "Cu"
    assert 'optical_constants = "Cu"' in (tmp_path / "copper.toml").read_text()
    env = {**os.environ, "PYTHONPATH": str(site), "JAX_PLATFORMS": "cpu"}
    run = subprocess.run([sys.executable, "-c", CHECK, material], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    got = json.loads(run.stdout.splitlines()[-1])
    # The installed copy, not the editable install of this checkout.
    assert os.path.commonpath([got["file"], str(site)]) == str(site), got["file"]
    table = read_optical_constants(TABLES / "Cu.csv")
    assert got["fresnel"] == "conductor"
    np.testing.assert_array_equal(got["n"], table["n"])
    np.testing.assert_array_equal(got["k"], table["k"])
    assert "Johnson" in got["source"]
