"""scripts/bench_sample.py --small --docs DIR: writes the section "## Sampling" with finite figures,
keeps the other sections of DIR/benchmarks.md, and carries the coverage part over."""

import math
import pathlib
import re
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_bench_sample_small_writes_its_section(tmp_path):
    doc = tmp_path / "benchmarks.md"
    doc.write_text(
        "# Benchmarks\n\n## Evaluation\n\nkept\n\n## Sampling\n\nold figures\n\n"
        "### Coverage of the posterior intervals\n\ncoverage kept\n\n## Colour\n\nkept too\n",
        encoding="utf-8",
    )
    r = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "bench_sample.py"), "--small", "--docs", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    text = doc.read_text(encoding="utf-8")
    assert "## Evaluation\n\nkept" in text and "## Colour\n\nkept too" in text and "old figures" not in text
    sec = text[text.index("## Sampling") : text.index("## Colour")]
    assert "coverage kept" in sec  # the coverage part is carried over
    rows = [ln for ln in sec.splitlines() if re.match(r"^\| 100 \| ", ln)]
    assert len(rows) == 1
    cells = [c.strip().strip("*") for c in rows[0].strip("|").split("|")]
    # pairs, samples, ctfit, NumPy, speed-up, grid, speed-up, emcee alone, ceiling: positive and finite.
    nums = [float(c.split()[0].strip("*").replace(",", "").rstrip("×")) for c in cells[:9]]
    assert nums[0] == 100 and nums[1] == 800
    assert all(math.isfinite(v) and v > 0 for v in nums)
    assert "chains agree to rounding: True" in sec
