"""The notebooks in notebooks/ run top to bottom without an error, their own asserts included.

Each notebook is executed in memory (nothing is written back) in a fresh ``python3`` kernel with
the working directory notebooks/, exactly as ``scripts/run_notebooks.py`` runs them, within
``NOTEBOOK_TIMEOUT_S`` seconds for the whole notebook (environment variable
``CTFIT_NOTEBOOK_TIMEOUT`` to change it). The kernel is a separate process: pytest's
``filterwarnings = error`` does not apply inside it.
"""

import os
import time

import pytest

from conftest import ROOT, load_script

pytest.importorskip("nbclient")
pytest.importorskip("nbformat")
pytest.importorskip("ipykernel")

import nbformat
from nbclient import NotebookClient
from nbclient.exceptions import CellExecutionError, CellTimeoutError

pytestmark = pytest.mark.slow

NOTEBOOKS = ROOT / "notebooks"
EXPECTED = ("fitted_vs_tabulated", "measured_data", "quickstart")
NOTEBOOK_TIMEOUT_S = float(os.environ.get("CTFIT_NOTEBOOK_TIMEOUT", "120"))


def test_the_notebooks_are_there():
    assert {p.stem for p in NOTEBOOKS.glob("*.ipynb")} >= set(EXPECTED)


def _listing():
    return {p.name: p.stat().st_mtime_ns for p in NOTEBOOKS.iterdir()}


@pytest.mark.parametrize("name", sorted({p.stem for p in NOTEBOOKS.glob("*.ipynb")} | set(EXPECTED)))
def test_notebook_runs(name, monkeypatch):
    path = NOTEBOOKS / f"{name}.ipynb"
    # Jupyter's own paths, in this process too (no platformdirs migration warning under filterwarnings = error).
    monkeypatch.setenv("JUPYTER_PLATFORM_DIRS", "1")
    nb = nbformat.read(path, as_version=4)
    before = _listing()
    deadline = time.monotonic() + NOTEBOOK_TIMEOUT_S
    client = NotebookClient(
        nb,
        timeout=int(NOTEBOOK_TIMEOUT_S),
        # the time left for the whole notebook bounds each cell
        timeout_func=lambda cell: max(1, int(deadline - time.monotonic())),
        kernel_name="python3",
        resources={"metadata": {"path": str(NOTEBOOKS)}},
        record_timing=False,
    )
    try:
        client.execute(env=load_script("run_notebooks").kernel_env(), cwd=str(NOTEBOOKS))
    except CellTimeoutError as err:
        pytest.fail(f"{path.name} did not finish within {NOTEBOOK_TIMEOUT_S:g} s: {err}")
    except CellExecutionError as err:
        pytest.fail(f"{path.name} failed:\n{err}")
    errors = [o for c in nb.cells for o in c.get("outputs", []) if o.get("output_type") == "error"]
    assert not errors, errors
    assert _listing() == before, "executing the notebook wrote into notebooks/"
