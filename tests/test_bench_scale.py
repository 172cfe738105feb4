"""scripts/bench_scale.py in a tiny mode: every mode of both cases runs, the SciPy peer among them,
and each prints a positive rate (no timing is judged here: the figures are docs/scaling.md's).
The one-item runs (the fixed cost) are the same commands on fewer items: ``--no-fixed`` leaves
them out here (half the processes)."""

import json
import subprocess
import sys

from conftest import ROOT


def test_bench_scale_runs_every_mode_with_the_scipy_peer(tmp_path):
    out = tmp_path / "figures.json"
    args = ["--files", "2", "--samples", "200", "--texels", "64", "--loop-texels", "2", "--scipy-texels", "3", "--no-warm-up", "--no-fixed", "--json", str(out)]
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "bench_scale.py"), *args], capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    figures = json.loads(out.read_text())
    modes = {"scipy", "fit loop", "fit_batch", "--workers 2"}
    assert set(figures["database"]) == set(figures["texels"]) == modes
    assert all(f["files_per_s"] > 0 and f["whole_s"] > 0 for f in figures["database"].values())
    assert all(f["texels_per_s"] > 0 for f in figures["texels"].values())
    assert all(f["fixed_s"] is None and f["marginal_files_per_s"] is None for f in figures["database"].values())
    assert all(f["fixed_s"] is None and f["marginal_texels_per_s"] is None for f in figures["texels"].values())
    assert figures["texels"]["fit_batch"]["texels"] == 64 and figures["texels"]["scipy"]["texels"] == 3
    lines = done.stdout.splitlines()
    assert "load average" in done.stdout
    assert sum(line.startswith("database ") for line in lines) == 4 and sum(line.startswith("texels ") for line in lines) == 4
    assert all("not run" in line for line in lines if line.startswith(("database ", "texels ")))
