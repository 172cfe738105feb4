"""The ctfit command: simulate → fit → eval round trip, JSON equality, errors and exit codes."""

import json
import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

import ctfit
from ctfit.cli import SAMPLE_NOT_USABLE, app

from conftest import ROOT

runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    csv = d / "copper.csv"
    r = run("simulate", ROOT / "configs" / "copper-vase.toml", "-o", csv, "--samples", 300, "--seed", 2, "--noise", 0.01, "--wavelengths", "400:700:50")
    assert r.exit_code == 0, r.output
    return d, csv


def test_version_is_fast_and_does_not_import_jax():
    out = subprocess.run(
        [sys.executable, "-c", "import sys; from ctfit.cli import main; sys.argv=['ctfit','--version']\ntry: main()\nexcept SystemExit: pass\nprint('jax' in "
                               "sys.modules)"],
        capture_output=True, text=True, check=True,
    )
    assert out.stdout.strip().splitlines() == [f"ctfit {ctfit.__version__}", "False"]


def test_simulate_is_reproducible_with_a_seed(simulated, tmp_path):
    d, csv = simulated
    again = tmp_path / "again.csv"
    r = run("simulate", ROOT / "configs" / "copper-vase.toml", "-o", again, "--samples", 300, "--seed", 2, "--noise", 0.01, "--wavelengths", "400:700:50")
    assert r.exit_code == 0, r.output
    assert again.read_bytes() == csv.read_bytes()


def test_fit_json_equals_library_serialisation_and_file(simulated):
    d, csv = simulated
    out = d / "fit.json"
    r = run("fit", csv, "--lobes", 2, "--no-diffuse", "--json", "-o", out)
    assert r.exit_code == 0, r.output
    printed = json.loads(r.stdout)
    written = json.loads(out.read_text())
    for doc in (printed, written):
        doc["fit"].pop("time_s")
    assert printed == written
    assert printed["fit"]["converged"] is True
    np.testing.assert_allclose(sorted(lobe["m"] for lobe in printed["lobes"]), [0.2, 0.4], rtol=0.02)
    # The library produces the same document for the same data and options.
    from ctfit import fit, fit_result_to_dict, read_measurement

    res = fit(read_measurement(csv), ctfit.Structure(lobes=2))
    res.material.meta["data"] = str(csv)
    lib = json.loads(json.dumps(fit_result_to_dict(res)))
    lib["fit"].pop("time_s")
    assert lib == printed


def test_fit_json_printed_is_the_files_text_and_escapes_what_is_not_ascii(simulated, tmp_path):
    d, csv = simulated
    out = tmp_path / "fit.json"
    r = run("fit", csv, "--lobes", 2, "--no-diffuse", "--json", "-o", out)  # (the model of the data: no warnings, all ASCII)
    assert r.exit_code == 0, r.output
    assert r.stdout == out.read_text(encoding="utf-8")  # one document, encoded once: the same text
    accented = tmp_path / "café" / "copper.csv"  # the data's path is in the document (meta.data)
    accented.parent.mkdir()
    accented.write_bytes(csv.read_bytes())
    out2 = tmp_path / "fit-café.json"
    r = run("fit", accented, "--lobes", 2, "--no-diffuse", "--json", "-o", out2)
    assert r.exit_code == 0, r.output
    text = out2.read_text(encoding="utf-8")
    assert "café" in text and "caf\\u00e9" in r.stdout and r.stdout.isascii()  # the file in UTF-8; stdout escaped, as json.dumps does
    assert json.loads(r.stdout) == json.loads(text)


def test_fit_result_is_a_material_for_eval(simulated):
    d, csv = simulated
    out = d / "fit2.json"
    assert run("fit", csv, "--lobes", 2, "--no-diffuse", "-o", out).exit_code == 0
    model = d / "model.csv"
    r = run("eval", out, csv, "-o", model)
    assert r.exit_code == 0, r.output
    from ctfit import read_measurement

    data, fitted = read_measurement(csv), read_measurement(model)
    rel = np.abs(fitted.brdf - data.brdf) / np.maximum(data.brdf, 1e-3 * data.brdf.max())
    assert np.sqrt(np.mean(rel**2)) < 0.03
    # The model's values, described as such: not the data's "# noise:" and "# source:" lines.
    assert "# noise:" in csv.read_text() and "# noise:" not in model.read_text()
    assert fitted.meta == {"source": "ctfit eval", "material": str(out), "directions": str(csv)}


@pytest.mark.filterwarnings("ignore:.*samples with theta_o")  # the file's grazing rows, dropped
def test_eval_of_data_without_a_wavelength_needs_a_material_of_one_band(tmp_path):
    """An ALTA file's one band has no wavelength: a spectral material's values there are not
    defined (eval used the 550 nm placeholder without a word); a material of one band is fine."""
    alta = ROOT / "measurements" / "brdf" / "retro-3M-jaune.dat"
    r = run("eval", ROOT / "configs" / "copper-vase.toml", alta, "-o", tmp_path / "e.csv")
    assert r.exit_code == 2 and "its one band has no known wavelength" in r.output and not (tmp_path / "e.csv").exists()
    grey = tmp_path / "grey.json"
    grey.write_text(json.dumps({"s": 1, "d": 0, "lobes": [{"m": 0.3}], "F0": [0.5], "wavelength_nm": [550]}))
    r = run("eval", grey, alta, "-o", tmp_path / "e.csv")
    assert r.exit_code == 0, r.output
    assert "# band: unknown" in (tmp_path / "e.csv").read_text()


def test_eval_of_data_in_other_bands_than_the_materials_names_the_data_file(tmp_path):
    """A spectral material and RGB data said "material 'copper' is spectral; data asks for
    channels ['R', 'G', 'B']", naming no file; the data file is named, and what to give."""
    alta = ROOT / "measurements" / "brdf" / "pink-felt-1d.alta"
    r = run("eval", ROOT / "configs" / "copper.toml", alta, "-o", tmp_path / "e.csv")
    assert r.exit_code == 2 and not (tmp_path / "e.csv").exists()
    assert f"error: {alta}: its bands are the channels ['R', 'G', 'B'] and the material " in r.output, r.output
    assert "copper.toml is spectral" in r.output and "give a material with those channels" in r.output
    rgb = tmp_path / "rgb.toml"
    rgb.write_text('s = 1\nlobes = [{ m = 0.3 }]\nchannels = ["R", "G", "B"]\nF0 = [0.5, 0.6, 0.7]\n')
    (tmp_path / "geo.csv").write_text("theta_i,phi_i,theta_o,phi_o,wavelength_nm\n10,0,20,180,550\n")
    r = run("eval", rgb, tmp_path / "geo.csv", "-o", tmp_path / "e.csv")
    assert r.exit_code == 2 and f"error: {tmp_path / 'geo.csv'}: its bands are not channels (550 nm)" in r.output, r.output


def test_a_material_of_other_channels_than_r_g_b_has_no_colour_anywhere(tmp_path):
    """channels = ["X"]: color and render said "material 'x' has no channel(s) ['R', 'G', 'B']"
    and export --to gltf or merl wrote it as grey. Every one refuses it, naming the file."""
    x = tmp_path / "x.toml"
    x.write_text('name = "x"\ns = 1\nlobes = [{ m = 0.3 }]\nchannels = ["X"]\nF0 = [0.5]\n')
    said = f"error: {x}: material 'x' has channels ['X'], not R, G, B: it has no colour to report, render or export"
    for args in (["color"], ["render", "-o", tmp_path / "r.png"], *(["export", "--to", to, "-o", tmp_path / f"e.{to}"] for to in ("gltf", "merl", "mitsuba"))):
        r = run(args[0], x, *args[1:])
        assert r.exit_code == 2 and said in r.output, (args, r.output)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.toml"]


def test_eval_says_when_the_model_overflows_not_the_data(tmp_path):
    """m = 1e-160: 1/m² overflows float64 (1e-20 overflows float32) and the model is NaN at the
    mirror. The error named the data file and a 'brdf' it does not have ("Measurement geo.csv:
    brdf[0]: NaN is not allowed"); it names the material, the row and the dtype."""
    (tmp_path / "tiny.toml").write_text("s = 1\nlobes = [{ m = 1e-160 }]\nF0 = [0.9]\nwavelength_nm = [550]\n")
    (tmp_path / "geo.csv").write_text("theta_i,phi_i,theta_o,phi_o,wavelength_nm\n10,0,20,180,550\n0,0,0,180,550\n")
    r = run("eval", tmp_path / "tiny.toml", tmp_path / "geo.csv", "-o", tmp_path / "e.csv")
    assert r.exit_code == 2 and not (tmp_path / "e.csv").exists()
    assert "tiny.toml: the model is not finite at 1 of 2 rows of" in r.output and "(the first: line 3, θ_i 0°" in r.output, r.output
    assert "overflow float64 there (m = 1e-160; ctfit fits m ≥ 1e-5)" in r.output and "Measurement" not in r.output


def test_table_is_printed(simulated):
    d, csv = simulated
    r = run("fit", csv, "--lobes", 1, "--no-diffuse")
    assert r.exit_code == 0, r.output
    assert "lobe 0: m =" in r.stdout and "converged: True" in r.stdout and "±" in r.stdout


@pytest.mark.parametrize(
    "args, message",
    [
        (("fit", "missing.csv"), "no such file"),
        (("fit", "{csv}", "--lobes", "x"), "--lobes"),
        (("fit", "{csv}", "--geometry", "flat"), "--geometry"),
        (("simulate", "{root}/configs/copper-vase.toml", "-o", "{tmp}/x.csv", "--wavelengths", "a:b"), "--wavelengths"),
    ],
)
def test_bad_input_exits_2_with_one_error_line(simulated, tmp_path, args, message):
    d, csv = simulated
    args = [a.format(csv=csv, root=ROOT, tmp=tmp_path) for a in args]
    r = run(*args)
    assert r.exit_code == 2
    assert message in r.output and "Traceback" not in r.output


def test_an_input_link_that_leads_nowhere_is_named_so(tmp_path):
    (tmp_path / "a.csv").symlink_to(tmp_path / "b.csv")
    (tmp_path / "b.csv").symlink_to(tmp_path / "a.csv")
    (tmp_path / "gone.csv").symlink_to(tmp_path / "deleted.csv")
    loop, dangling = run("fit", tmp_path / "a.csv"), run("fit", tmp_path / "gone.csv")
    assert loop.exit_code == dangling.exit_code == 2
    assert "a.csv: is a symbolic link that leads to itself" in loop.output
    assert "gone.csv: is a symbolic link to " in dangling.output and "deleted.csv, which does not exist" in dangling.output


def test_one_file_named_in_several_spellings_is_fitted_once(simulated, tmp_path, monkeypatch):
    """``s.csv``, its absolute path and a link to it were fitted as two or three files (results
    ``s.fit.json`` and ``s-2.fit.json``, a summary of three): the inputs are one file each,
    by resolved path, under the name first given."""
    d, csv = simulated
    (tmp_path / "link.csv").symlink_to(csv)
    monkeypatch.chdir(d)
    r = run("fit", csv.name, csv, tmp_path / "link.csv", "--lobes", 1, "--family", "metal", "--no-diffuse", "-q", "-o", f"{tmp_path / 'out'}/")
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["copper.fit.json", "summary.json"]
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["files"] == 1 and [row["data"] for row in summary["results"]] == ["copper.csv"]


def test_bad_csv_names_file_line_and_column(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n10,0,10,180,500,0.5\n10,0,95,180,500,0.5\n")
    r = run("eval", ROOT / "configs" / "copper-vase.toml", bad, "-o", tmp_path / "o.csv")
    assert r.exit_code == 2
    assert "bad.csv:3" in r.output and "theta_o" in r.output
    assert not (tmp_path / "o.csv").exists()


def test_sample_command_adds_an_uncertainty_section(simulated, tmp_path):
    d, csv = simulated
    fit_json = tmp_path / "fit.json"
    assert run("fit", csv, "--lobes", 2, "--no-diffuse", "-o", fit_json).exit_code == 0
    out = tmp_path / "sampled.json"
    r = run("sample", fit_json, csv, "--steps", 150, "--walkers", 24, "--seed", 1, "-o", out)
    # 150 steps are too few for the walkers to mix: written, but not usable (status 1), with how long to run.
    doc = json.loads(out.read_text())
    need = doc["uncertainty"]["checks"]["mixing"]["steps_needed"]
    assert r.exit_code == SAMPLE_NOT_USABLE and doc["uncertainty"]["problems"][0].startswith("not mixed: "), r.output
    assert f"run longer: --steps {need} or more (with --backend FILE, a later --resume continues the chain)" in r.output
    unc = doc["uncertainty"]
    assert len(unc["lobes"]) == 2 and len(unc["F0"]) == len(doc["F0"])
    for entry in [unc["lobes"][0]["m"], unc["F0"][0], unc["n"][0]]:
        assert entry["p16"] <= entry["median"] <= entry["p84"]
    assert doc["fit"] == json.loads(fit_json.read_text())["fit"]  # the fit section is kept
    # --json prints exactly the document written (the library's serialisation).
    out2 = tmp_path / "sampled2.json"
    r = run("sample", fit_json, csv, "--steps", 150, "--walkers", 24, "--seed", 1, "-o", out2, "--json")
    assert r.exit_code == SAMPLE_NOT_USABLE, r.output
    assert json.loads(r.stdout) == json.loads(out2.read_text())
    # Same seed, same chain: the summaries are reproduced exactly.
    assert json.loads(out2.read_text())["uncertainty"]["lobes"] == unc["lobes"]
    # Without -o the fit JSON is never written: the result goes to fit.posterior.json beside it.
    before = fit_json.read_bytes()
    r = run("sample", fit_json, csv, "--steps", 150, "--walkers", 24, "--seed", 1, "--json")
    assert fit_json.read_bytes() == before and f"wrote {tmp_path / 'fit.posterior.json'}" in r.output
    assert json.loads((tmp_path / "fit.posterior.json").read_text())["uncertainty"]["lobes"] == unc["lobes"]


def test_sample_writes_progress_lines_into_a_log_and_none_when_quiet(simulated, tmp_path, monkeypatch):
    """stderr that is no terminal (a log file, a pipe) gets a plain line every few seconds (here
    every step); -q writes none."""
    from ctfit._runtime import progress

    d, csv = simulated
    fit_json = tmp_path / "fit.json"
    assert run("fit", csv, "--lobes", 1, "--no-diffuse", "-o", fit_json).exit_code == 0
    monkeypatch.delenv("CTFIT_PROGRESS", raising=False)
    monkeypatch.setattr(progress, "LINE_EVERY_S", 0.0)
    r = run("sample", fit_json, csv, "--steps", 20, "--walkers", 24, "-o", tmp_path / "s.json")
    lines = [line for line in r.output.splitlines() if line.startswith("sampling: ")]
    assert len(lines) == 20 and lines[-1].startswith("sampling: 20 of 20 steps (100 %)"), r.output
    quiet = run("sample", fit_json, csv, "--steps", 20, "--walkers", 24, "-o", tmp_path / "s.json", "-q")
    assert "sampling: " not in quiet.output and quiet.exit_code == SAMPLE_NOT_USABLE


def test_resume_needs_a_backend(simulated, tmp_path):
    d, csv = simulated
    r = run("fit", csv, "--lobes", 1, "--sample", "--resume")
    assert r.exit_code == 2 and "--backend" in r.output


def test_the_color_table_rounds_and_names_srgb_once():
    """The table shows six significant digits (it printed white_XYZ's Y as 0.9999999999999999; the
    JSON keeps every digit) and one row of sRGB values: ``rgb`` in sRGB, and ``sRGB`` beside it only
    for another colourspace."""
    r = run("color", ROOT / "configs" / "gold.toml")
    assert r.exit_code == 0, r.output
    rows = dict(line.strip().split(": ", 1) for line in r.stdout.splitlines())
    assert rows["white_XYZ"] == "[0.950471, 1, 1.08883]" and "sRGB" not in rows and "rgb" in rows
    assert all(len(x.strip("[] ").split("e")[0].replace("-", "").replace(".", "").lstrip("0")) <= 6 for x in rows["XYZ"].split(","))
    other = dict(line.strip().split(": ", 1) for line in run("color", ROOT / "configs" / "gold.toml", "--colorspace", "Display P3").stdout.splitlines())
    assert other["sRGB"] == rows["rgb"] and other["rgb"] != rows["rgb"]
    doc = json.loads(run("color", ROOT / "configs" / "gold.toml", "--json").stdout)
    assert len(repr(doc["XYZ"][0])) > 8  # the JSON keeps every digit


def test_color_json_has_the_documented_keys():
    r = run("color", ROOT / "configs" / "gold.toml", "--json")
    assert r.exit_code == 0, r.output
    doc = json.loads(r.stdout)
    for key in ("XYZ", "xy", "sRGB", "dominant_wavelength_nm", "Lab", "hex"):
        assert key in doc
    assert 570 < doc["dominant_wavelength_nm"] < 590  # gold is yellow-orange
    assert 0 < doc["XYZ"][1] < 1
    r60 = json.loads(run("color", ROOT / "configs" / "gold.toml", "--json", "--angle", 80).stdout)
    assert r60["XYZ"][1] > doc["XYZ"][1]  # brighter towards grazing (Fresnel)


def test_structure_options_that_differ_from_the_materials_are_refused(simulated, tmp_path):
    """--material sets the structure: --lobes, --family or --diffuse that differ from it were
    dropped without a word (while --fresnel applied); they are refused, and the same values pass."""
    d, csv = simulated
    mat = ROOT / "configs" / "copper-vase.toml"  # two lobes, a metal, no diffuse part
    for option in (("--lobes", 1), ("--family", "plastic"), ("--diffuse", "F0/pi")):
        r = run("fit", csv, "--material", mat, *option, "-q", "-o", tmp_path / "x.json")
        assert r.exit_code == 2 and f"and {option[0]} {option[1]} differs" in r.output, r.output
    assert not (tmp_path / "x.json").exists()
    r = run("fit", csv, "--material", mat, "--lobes", 2, "--family", "metal", "--no-diffuse", "-q", "-o", tmp_path / "x.json")
    assert r.exit_code == 0, r.output


def test_every_option_of_every_command_is_documented():
    """simulate --max-theta and render --labels were in --help and nowhere in the docs (the README
    is the site's front page). ``--output`` is written ``-o`` throughout."""
    import re

    import typer.main

    text = "\n".join(p.read_text() for p in [*(ROOT / "docs").glob("*.md"), ROOT / "README.md"] if p.name != "changelog.md")
    missing = [(name, opt) for name, command in typer.main.get_command(app).commands.items() for param in command.params
               for opt in (*param.opts, *param.secondary_opts)
               if opt.startswith("--") and opt != "--output" and not re.search(re.escape(opt) + r"(?![\w-])", text)]
    assert missing == []


def test_sample_of_data_in_other_bands_than_the_materials_names_the_data_file(tmp_path):
    """``ctfit sample`` of a spectral fit and RGB data gave the library's message, naming no file;
    it names the data file, as ``eval`` does, before any sampling."""
    alta = ROOT / "measurements" / "brdf" / "pink-felt-1d.alta"
    r = run("sample", ROOT / "configs" / "copper.toml", alta, "-o", tmp_path / "s.json", "--steps", 50)
    assert r.exit_code == 2 and not (tmp_path / "s.json").exists(), r.output
    assert f"error: {alta}: its bands are the channels ['R', 'G', 'B'] and the material " in r.output, r.output
