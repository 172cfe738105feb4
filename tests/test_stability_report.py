"""The stability report (``scripts/stability.py``): its small version runs here so it cannot rot.

One run of ``scripts/stability.py --small --docs tmp --json tmp/raw.json`` in a subprocess
(one lobe, effective index: m = 0.00935 and 3, data up to 89.9°, F0 = 1e-6 and 0.999999, each in
float64 and float32); the tests read its Markdown and its raw numbers.
"""

import json
import math
import os
import subprocess
import sys

import pytest

from conftest import ROOT

SCRIPT = ROOT / "scripts" / "stability.py"


@pytest.fixture(scope="module")
def small_report(tmp_path_factory):
    out = tmp_path_factory.mktemp("stability")
    raw = out / "raw.json"
    env = dict(os.environ, JAX_PLATFORMS="cpu")
    proc = subprocess.run(
        [sys.executable, str(SCRIPT), "--small", "--docs", str(out), "--json", str(raw)],
        capture_output=True, text=True, timeout=600, env=env, cwd=ROOT,
    )
    rows = json.loads(raw.read_text())["rows"] if raw.exists() else []
    md = (out / "stability.md").read_text(encoding="utf-8") if (out / "stability.md").exists() else ""
    return proc, md, {(r["case"], r["dtype"]): r for r in rows}


def _finite_everywhere(row):
    return sum(row["non_finite"].values()) == 0


@pytest.mark.slow
def test_small_report_exits_0_and_writes_the_table(small_report):
    proc, md, rows = small_report
    assert proc.returncode == 0, proc.stdout[-1500:] + proc.stderr[-3000:]
    assert md.splitlines()[0] == "# Stability"
    assert "## Stability: stiff and extreme cases" in md
    assert "| case | truth | dtype | converged | steps | error | parameters | time (s) | non-finite | what ctfit reports |" in md
    table = [ln for ln in md.splitlines() if ln.startswith("| ") and "| float" in ln]
    assert len(table) == len(rows) == 10
    assert {d for _, d in rows} == {"float64", "float32"}
    # The Markdown printed is the Markdown written.
    assert md.split("## Stability")[1].strip() in proc.stdout


@pytest.mark.slow
def test_small_report_has_no_non_finite_values(small_report):
    _, md, rows = small_report
    assert all(_finite_everywhere(r) for r in rows.values()), {k: r["non_finite"] for k, r in rows.items() if not _finite_everywhere(r)}
    assert "Non-finite values in the results: **0**" in md


@pytest.mark.slow
@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("case", ["m = 0.00935 (chrome-like)", "m = 3", "data up to θ = 89.9°", "F0 = 1e-06"])
def test_stiff_cases_converge_and_recover_the_truth(small_report, case, dtype):
    row = small_report[2][(case, dtype)]
    assert row["converged"], row
    assert row["error"] < 0.01
    assert row["param_error"]["m"] < 2e-3
    assert row["param_error"]["F0"] < 2e-3


@pytest.mark.slow
def test_f0_near_one_in_float32_converges_finite_and_reports_the_bound(small_report):
    """F0 = 0.999999: float32 converges; the effective index n (~10⁶–10⁷) stays finite; F0 on
    its bound is reported, and the standard errors of the free parameters are still computed."""
    row = small_report[2][("F0 = 0.999999", "float32")]
    assert row["converged"]
    assert _finite_everywhere(row), (row["non_finite"], row["python_warnings"], row["fitted"])
    assert not row["python_warnings"], row["python_warnings"]
    assert row["error"] < 0.01 and row["param_error"]["F0"] < 1e-3
    assert any("F0 at a bound" in w for w in row["reports"])
    assert row["stderr"] is not None and all(map(math.isfinite, row["stderr"]["m"]))


@pytest.mark.slow
def test_f0_near_one_in_float64_is_finite_and_reports_the_bound(small_report):
    row = small_report[2][("F0 = 0.999999", "float64")]
    assert _finite_everywhere(row), (row["non_finite"], row["python_warnings"], row["fitted"])
    assert not row["python_warnings"], row["python_warnings"]
    assert row["error"] < 0.01 and row["param_error"]["F0"] < 1e-3
    assert any("F0 at a bound" in w for w in row["reports"])
