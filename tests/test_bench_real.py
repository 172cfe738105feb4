"""scripts/bench_real.py: its error metric on a hand-computed case, its list of candidates, the
SciPy peer's new residual and diffuse form, and a ``--quick`` run that prints every column."""

import subprocess
import sys

import numpy as np
import pytest

import ctfit

from conftest import ROOT, load_script

sys.path.insert(0, str(ROOT / "scripts"))  # the scripts import their helpers by name
import _numpy_model as model

bench = load_script("bench_real")


def test_relative_error_is_median_and_p90_over_positive_samples_within_80_degrees():
    y = np.array([1.0, 2.0, 4.0, 0.5, 10.0, 0.0, 3.0])
    f = np.array([1.1, 1.0, 4.0, 0.75, 0.0, 5.0, 3.0])
    theta_i = np.array([0.0, 10.0, 20.0, 80.0, 81.0, 10.0, 30.0])
    theta_o = np.array([5.0, 10.0, 20.0, 30.0, 10.0, 10.0, 85.0])
    # Kept: rows 0–3 (y > 0, both angles ≤ 80°): |f − y|/y = 0.1, 0.5, 0, 0.5 → sorted 0, 0.1, 0.5, 0.5.
    med, p90 = bench.relative_error(f, y, theta_i, theta_o)
    assert med == pytest.approx(0.3)  # (0.1 + 0.5)/2
    assert p90 == pytest.approx(0.5)  # linear interpolation between the 3rd and 4th: both 0.5


def test_candidates_cover_every_structure_of_both_families_and_every_loss():
    cands = bench.candidates(["relative", "log"])
    metal = [c for c in cands if c[1].family == "metal"]
    assert len(metal) == 2 * 3 * 4 * 2  # Fresnel form × lobes × diffuse form × loss
    assert {(st.lobes, st.fresnel, st.diffuse) for _, st, _ in metal} == {
        (n, fr, d) for n in (1, 2, 3) for fr in ("f0", "conductor") for d in (None, "F0/pi", "spectrum", "constant")}
    plastic = [c for c in cands if c[1].family == "plastic"]
    assert {(st.lobes, st.diffuse) for _, st, _ in plastic} == {(n, d) for n in (1, 2, 3) for d in ("spectrum", "constant", "transmitted")}
    assert len(plastic) == 3 * 3 * 2 and {loss for *_, loss in cands} == {"relative", "log"}


def test_numpy_model_log_ratio_and_diffuse_spectrum_are_ctfits_model():
    """The SciPy peer's one lobe + R_d per band: R = s R_s + (1 − s) R_d, as ctfit evaluates it; ln f − ln y where y > 0."""
    st = ctfit.Structure(lobes=1, diffuse="spectrum")
    mat = ctfit.Material(st, ctfit.Params(s=np.array(0.3), m=np.array([0.2]), w=np.ones(1), f0=np.array([0.04, 0.05, 0.06]),
                                          rd=np.array([0.2, 0.1, 0.05])), channels=("R", "G", "B"))
    d = ctfit.simulate(mat, 100, seed=2)
    nd = model.NumpyData(d.theta_i, d.phi_i, d.theta_o, d.phi_o, d.band, 3, d.brdf)
    prob = model.NumpyProblem(nd, lobes=1, loss="log-ratio", diffuse="spectrum")
    u = np.concatenate([np.log([0.04 / 0.96, 0.05 / 0.95, 0.06 / 0.94]), np.log([0.2]), [np.log(0.3 / 0.7)], np.log([0.2, 0.1, 0.05])])
    np.testing.assert_allclose(prob.model(u), d.brdf, rtol=1e-10)
    nd.brdf = d.brdf * np.exp(0.1) * (np.arange(len(d)) % 7 > 0)  # every 7th sample 0: no residual there
    r = model.NumpyProblem(nd, lobes=1, loss="log-ratio", diffuse="spectrum").residual(u)
    np.testing.assert_allclose(r, np.where(nd.brdf > 0, -0.1, 0.0), atol=1e-10)


def test_numpy_reader_reads_rgb_csv(tmp_path):
    path = ROOT / "measurements" / "testbed" / "plastic.csv"
    ours, theirs = model.read_csv_numpy(path), ctfit.read_csv(path)
    for name in ("theta_i", "phi_i", "theta_o", "phi_o", "band", "brdf"):
        np.testing.assert_array_equal(getattr(ours, name), getattr(theirs, name), err_msg=name)
    assert ours.n_bands == 3


@pytest.mark.slow
def test_quick_run_prints_every_column(tmp_path):
    done = subprocess.run([sys.executable, str(ROOT / "scripts" / "bench_real.py"), "--quick", "--docs", str(tmp_path)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]
    table = [line for line in done.stdout.splitlines() if line.startswith("| pink-felt-1d.alta |")]
    assert len(table) == 1
    cells = [c.strip() for c in table[0].strip("|").split("|")]
    assert len(cells) == len(bench.COLUMNS) and all(cells)
    errors = [cells[bench.COLUMNS.index(c)] for c in ("default median", "default p90", "best median", "best p90", "SciPy median", "SciPy p90")]
    assert all(e.endswith(" %") and 0 <= float(e[:-2]) < 100 for e in errors), errors
    doc = (tmp_path / "real-materials.md").read_text()
    assert doc.startswith(bench.SECTION) and "| " + " | ".join(bench.COLUMNS) + " |" in doc and table[0] in doc


def test_default_only_section_compares_with_the_search_and_mitsuba(tmp_path):
    """``--default-only`` reads the best and Mitsuba medians of the "Results" table and divides the
    default's median by the better of the two."""
    doc = tmp_path / "real-materials.md"
    head = "| " + " | ".join(bench.COLUMNS) + " |"
    cells = ["a.csv", "10", "9.00 %", "1 %", "1", "1", "4.00 %", "1 %", "x", "1", "1 %", "1 %", "1", "5.00 %", "1 %", "1"]
    doc.write_text(f"# t\n\n{bench.SECTION}\n\nMeasured.\n\n{head}\n|" + "---|" * len(bench.COLUMNS) + "\n| " + " | ".join(cells) + " |\n")
    refs = bench.reference_errors(doc)
    assert refs == {"a.csv": (pytest.approx(0.04), pytest.approx(0.05))}
    args = type("A", (), {"argv": ["--default-only"]})()
    row = dict(file="a.csv", samples=10, default=dict(median=0.05, p90=0.1, structure="metal, 1 lobe, no diffuse", cold_s=2.0, warm_s=1.0))
    text = bench.default_section([row], refs, args, 0.0, (1.0, 1.0))
    assert text.startswith(bench.DEFAULT_SECTION)
    assert "| a.csv | 10 | 5.00 % | 10.00 % | metal, 1 lobe, no diffuse | 2.0 | 1.0 | 4.00 % | 1.25 |" in text
    row["default"].update(warm_s=1.04, warm_range=(0.93, 1.21))  # several warm runs: their median and range
    args.warm = 3
    text = bench.default_section([row], refs, args, 0.0, (1.0, 1.0))
    assert "| 2.0 | 1.0 (0.9–1.2) | 4.00 % | 1.25 |" in text and "3 runs, their median and in brackets their range" in text
