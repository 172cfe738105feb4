"""scripts/fit_tradeoffs.py: the small sweep runs and writes a well-formed report, and the committed
report's recommended default is what ctfit actually uses by default."""

import inspect
import json
import math
import os
import re
import subprocess
import sys

import jax.numpy as jnp
import pytest
import typer.main

import ctfit
from ctfit.cli import app

from conftest import ROOT

SECTION = "## Fitting: error against run time"
RECOMMENDED = re.compile(r"^\*\*Recommended default:\*\* solver `([^`]+)`, precision `([^`]+)`, loss `([^`]+)`", re.M)
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _table(text):
    """Rows (as lists of cells) of the first Markdown table after the section heading."""
    lines = text[text.index(SECTION):].splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith("| axis |"))
    rows = []
    for ln in lines[start + 2:]:
        if not ln.startswith("|"):
            break
        rows.append([c.strip() for c in re.split(r"(?<!\\)\|", ln.strip())[1:-1]])
    return lines[start], rows


def _ctfit_defaults():
    sig = inspect.signature(ctfit.fit).parameters
    library = (sig["solver"].default, jnp.dtype(sig["dtype"].default).name, sig["loss"].default)
    opts = {p.name: p.default for p in typer.main.get_command(app).commands["fit"].params}
    default = opts.__getitem__

    command = (default("solver"), "float32" if default("float32") else "float64", default("loss"))
    return library, command


@pytest.fixture(scope="module")
def small_report(tmp_path_factory):
    out = tmp_path_factory.mktemp("tradeoffs")
    env = dict(os.environ, JAX_PLATFORMS="cpu", MPLBACKEND="Agg")
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    proc = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "fit_tradeoffs.py"), "--small", "--docs", str(out), "--json", str(out / "raw.json")],
        capture_output=True, text=True, cwd=ROOT, env=env, timeout=900,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out, proc.stdout


@pytest.mark.slow
def test_small_sweep_writes_a_wellformed_report(small_report):
    out, stdout = small_report
    doc = out / "fitting-tradeoffs.md"
    text = doc.read_text(encoding="utf-8")
    assert SECTION in text and SECTION in stdout
    header, rows = _table(text)
    ncol = len([c for c in re.split(r"(?<!\\)\|", header.strip())[1:-1]])
    assert all(len(r) == ncol for r in rows)
    runs = {(r[0], r[1], r[2]) for r in rows}
    assert ("standard", "standard", "ctfit lm float64") in runs
    assert ("standard", "standard", "SciPy lm") in runs
    assert ("precision", "float32", "ctfit lm float32") in runs
    assert any(a == "samples" and run == "ctfit lm float64" for a, _, run in runs)
    assert any(a == "samples" and run == "SciPy lm" for a, _, run in runs)
    assert all(r[-1] == "0" for r in rows), "non-finite values in a fit"
    for r in rows:  # times and errors are positive finite numbers
        for cell in (r[4], r[5], r[8], r[9], r[12]):
            assert math.isfinite(float(cell)) and float(cell) > 0, r
    assert RECOMMENDED.search(text)
    figure = out / "figures" / "fit_error_vs_time.png"
    assert "figures/fit_error_vs_time.png" in text
    data = figure.read_bytes()
    assert data[:8] == PNG_MAGIC and len(data) > 10_000
    raw = json.loads((out / "raw.json").read_text())
    assert len(raw["rows"]) == len(rows)
    assert all(r["converged"] and r["nonfinite"] == 0 for r in raw["rows"])


def test_committed_recommendation_matches_ctfit_defaults():
    text = (ROOT / "docs" / "fitting-tradeoffs.md").read_text(encoding="utf-8")
    assert SECTION in text
    m = RECOMMENDED.search(text)
    assert m, "no '**Recommended default:**' line in docs/fitting-tradeoffs.md"
    library, command = _ctfit_defaults()
    assert m.groups() == library, f"docs recommend {m.groups()}, ctfit.fit defaults to {library}"
    assert m.groups() == command, f"docs recommend {m.groups()}, `ctfit fit` defaults to {command}"
    assert (ROOT / "docs" / "figures" / "fit_error_vs_time.png").read_bytes()[:8] == PNG_MAGIC
