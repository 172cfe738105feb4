"""Hostile options and inputs of the ctfit command: one ``error:`` line and exit status 2, never a
traceback; ranges that say what they give; extreme but valid options that run."""

import numpy as np
import pytest
from typer.testing import CliRunner

import ctfit
from ctfit.cli import app

from conftest import ROOT

runner = CliRunner()
COPPER = ROOT / "configs" / "copper-vase.toml"


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


def refused(r, *words):
    """The command failed as input errors do: status 2, one ``error:`` line naming ``words``."""
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.output.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and "Traceback" not in r.output, r.output
    assert all(w in lines[0] for w in words), lines[0]
    return lines[0]


@pytest.mark.parametrize("text", ["-5", "0", "400,-3", "nan", "700:400:10", "400:700:0", "inf:700:1", ""])
def test_simulate_refuses_wavelengths_that_are_not_wavelengths(tmp_path, text):
    r = run("simulate", COPPER, "-o", tmp_path / "x.csv", "--samples", 3, f"--wavelengths={text}")
    refused(r, "--wavelengths")
    assert not (tmp_path / "x.csv").exists()


@pytest.mark.parametrize("text, item", [("500,,600", "item 2 of 3"), ("500,600,", "item 3 of 3"), (",500", "item 1 of 2"), ("500, ,600", "item 2 of 3")])
def test_an_empty_wavelength_item_is_refused_not_skipped(tmp_path, text, item):
    """--wavelengths "500,,600" simulated at 500 and 600 nm without a word about the empty item."""
    r = run("simulate", COPPER, "-o", tmp_path / "x.csv", "--samples", 3, f"--wavelengths={text}")
    refused(r, "--wavelengths", f"{item} is empty")
    assert not (tmp_path / "x.csv").exists()


def test_simulate_counts_one_band_in_the_singular(tmp_path):
    """'wrote 10 samples (10 direction pairs × 1 bands)': one band (pair, sample, lobe) is singular."""
    r = run("simulate", COPPER, "-o", tmp_path / "x.csv", "--samples", 1, "--wavelengths", "500")
    assert r.exit_code == 0 and "wrote 1 sample (1 direction pair × 1 band) to" in r.output, r.output
    r = run("simulate", COPPER, "-o", tmp_path / "y.csv", "--samples", 3, "--wavelengths", "500,600")
    assert "wrote 6 samples (3 direction pairs × 2 bands) to" in r.output, r.output
    two = ctfit.Material(ctfit.Structure(lobes=1), ctfit.Params(m=np.array([0.2, 0.3]), w=np.ones(2), f0=np.ones(2) / 2), wavelength_nm=np.array([550.0]))
    with pytest.raises(ValueError, match=r"m has 2 values; its structure has 1 lobe$"):
        two.check_shapes()


@pytest.mark.parametrize("args, option", [
    (("simulate", "{copper}", "-o", "-"), "-o"),
    (("eval", "{copper}", "{csv}", "-o", "-"), "-o"),
    (("fit", "{csv}", "-o", "-"), "-o"),
    (("fit", "{csv}", "--plot", "-"), "--plot"),
    (("fit", "{csv}", "--sample", "--backend", "-"), "--backend"),
    (("export", "{copper}", "--to", "gltf", "-o", "-"), "-o"),
    (("render", "{copper}", "-o", "-"), "-o"),
    (("sample", "{copper}", "{csv}", "-o", "-"), "-o"),
    (("sample", "{copper}", "{csv}", "--idata", "-"), "--idata"),
    (("sample", "{copper}", "{csv}", "--plot", "-"), "--plot"),
])
def test_a_dash_output_is_refused_not_written_as_a_file_named_dash(tmp_path, monkeypatch, args, option):
    """-o - wrote a file named '-'; the docs name /dev/stdout for standard output (docs/formats.md)."""
    csv = tmp_path / "d.csv"
    csv.write_text("theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n10,0,20,180,550,0.5\n")
    monkeypatch.chdir(tmp_path)
    r = run(*(str(a).format(copper=COPPER, csv=csv) for a in args))
    refused(r, f"{option} -: '-' is not standard output", f"give {option} /dev/stdout")
    assert not (tmp_path / "-").exists()


@pytest.mark.parametrize("text, last, count", [("400:700:7", 694.0, 43), ("380:779.9:1", 779.0, 400), ("400:700:50", 700.0, 7), ("400:700:0.1", 700.0, 3001)])
def test_a_wavelength_range_never_passes_stop(tmp_path, text, last, count):
    from ctfit._cli.inputs import parse_wavelengths

    wl = parse_wavelengths(text)
    assert len(wl) == count and wl[-1] == pytest.approx(last) and wl[-1] <= float(text.split(":")[1])
    out = tmp_path / "x.csv"
    r = run("simulate", COPPER, "-o", out, "--samples", 2, "--wavelengths", text)
    assert r.exit_code == 0, r.output
    data = ctfit.read_csv(out)
    assert data.n_bands == count and data.wavelength_nm.max() == pytest.approx(last)


def test_a_material_of_unknown_band_is_simulated_in_its_one_band_not_31(tmp_path):
    """The CSV says '# band: unknown' (as eval's does) and reads back so; it was refused ('a measurement
    CSV gives every sample a wavelength or a channel'), and before that simulated into 31 bands."""
    mat = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([0.3]), w=np.ones(1), f0=np.array([0.5])),
                         wavelength_nm=np.array([550.0]), band_unknown=True, name="alta fit")
    ctfit.save_material_json(mat, tmp_path / "u.json")
    r = run("simulate", tmp_path / "u.json", "-o", tmp_path / "u.csv", "--samples", 3)
    assert r.exit_code == 0, r.output
    back = ctfit.read_csv(tmp_path / "u.csv")
    assert back.band_unknown and back.band_labels == ["unknown band"] and len(back) == 3
    np.testing.assert_allclose(back.brdf, ctfit.evaluate(mat, back), rtol=1e-12)
    refused(run("simulate", tmp_path / "u.json", "-o", tmp_path / "w.csv", "--samples", 3, "--wavelengths", "500"), "unknown wavelength", "--wavelengths")
    assert not (tmp_path / "w.csv").exists()
    data = ctfit.simulate(mat, 4)  # in memory: the one band, still unknown
    assert data.band_unknown and data.band_labels == ["unknown band"] and len(data) == 4
    with pytest.raises(ValueError, match="wavelength_nm"):
        ctfit.simulate(mat, 4, wavelength_nm=[500.0])
    with pytest.raises(ValueError, match="wavelength_nm"):
        ctfit.simulate(ctfit.load_material(COPPER), 4, wavelength_nm=[-5.0])


@pytest.mark.parametrize("step, why", [(1000, "coarser steps misplace colours"), (400, "coarser steps misplace colours"), (0.5, "finer"), (0, "not a step")])
def test_render_step_outside_its_range_says_what_is_allowed(tmp_path, step, why):
    """Steps past 20 nm misplace colours (400 nm, 380 and 780 nm alone, drew gold red): refused."""
    r = run("render", ROOT / "configs" / "gold.toml", "-o", tmp_path / "r.png", "--size", 16, "--supersample", 1, "--step", step)
    refused(r, "--step", "[1, 20] nm", why)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    d = tmp_path_factory.mktemp("limits")
    assert run("simulate", COPPER, "-o", d / "cu.csv", "--samples", 60, "--wavelengths", "400:700:150", "--noise", 0.01).exit_code == 0
    r = run("fit", d / "cu.csv", "--material", COPPER, "-o", d / "cu.json", "--starts", 1)  # its own structure: the default would compile nine
    assert r.exit_code in (0, 1), r.output
    return d


@pytest.mark.parametrize("args, words", [
    (("sample", "{d}/cu.json", "{d}/cu.csv", "-o", "{d}/s.json", "--steps", 5, "--thin", 10), "--thin must be at most steps (5)"),
    (("fit", "{d}/cu.csv", "--sample", "--steps", 3, "--thin", 5), "--thin must be at most --steps (3)"),
    (("fit", "{d}/cu.csv", "--param-out", "x"), "--param-out must be one of"),
    (("eval", COPPER, "{d}/cu.csv", "-o", "{d}/e.csv", "--param-out", "x"), "--param-out must be one of"),
    (("simulate", COPPER, "-o", "{d}/n.csv", "--samples", 3, "--noise", 1e308), "--noise=1e+308 is too large"),
    (("simulate", COPPER, "-o", "{d}/m.csv", "--samples", 999_999_999_999_999), "not enough memory"),  # was a 64-line traceback
    (("render", COPPER, "-o", "{d}/r.png", "--size", 16, "--ambient", "inf"), "--ambient must be a finite fraction"),
    (("render", COPPER, "-o", "{d}/r.png", "--size", 16, "--ambient", 1e300), "--ambient must be a finite fraction in [0, 1e+06]"),  # was a black sphere
    (("color", COPPER, "--angle", 95), "--angle must be in [0, 90]"),
])
def test_extreme_options_are_one_error_line_naming_the_option(fitted, args, words):
    refused(run(*(str(a).format(d=fitted) for a in args)), words)


@pytest.mark.parametrize("args, option, allowed", [
    (("sample", "{d}/cu.json", "{d}/cu.csv", "-o", "{d}/s.json", "--steps", 10**20), "--steps", "1<=x<=1000000000"),
    (("sample", "{d}/cu.json", "{d}/cu.csv", "-o", "{d}/s.json", "--walkers", 10**20), "--walkers", "2<=x<=1000000"),
    (("fit", "{d}/cu.csv", "--sample", "--steps", 10**20), "--steps", "1<=x<=1000000000"),
    (("fit", "{d}/cu.csv", "--sample", "--walkers", 10**12), "--walkers", "2<=x<=1000000"),
    (("sample", "{d}/cu.json", "{d}/cu.csv", "-o", "{d}/s.json", "--seed", 2**32), "--seed", "0<=x<=4294967295"),
    (("fit", "{d}/cu.csv", "--sample", "--seed", 10**23), "--seed", "0<=x<=4294967295"),
])
def test_chain_lengths_past_any_run_are_refused_by_name_with_the_range(fitted, args, option, allowed):
    """``--steps 1e20`` (and ``--walkers``) stopped in emcee with NumPy's "Maximum allowed dimension
    exceeded", after the data was read and the posterior set up (``fit --sample``: after the fit);
    ``--seed 2**32`` with NumPy's "Seed must be between 0 and 2**32 - 1", naming no option."""
    r = run(*(str(a).format(d=fitted) for a in args))
    assert r.exit_code == 2 and f"Invalid value for '{option}'" in r.output and allowed in r.output, r.output
    assert "dimension" not in r.output and "Traceback" not in r.output and not (fitted / "s.json").exists()


def test_the_command_and_the_library_take_the_same_chain_lengths(fitted):
    from ctfit._cli import commands
    from ctfit._sampling import MAX_SEED, MAX_STEPS, MAX_WALKERS

    assert (commands.MAX_STEPS, commands.MAX_WALKERS, commands.MAX_SEED) == (MAX_STEPS, MAX_WALKERS, MAX_SEED) == (10**9, 10**6, 2**32 - 1)
    mat, data = ctfit.load_material(fitted / "cu.json"), ctfit.read_csv(fitted / "cu.csv")
    for options, words in [(dict(steps=10**20), "steps must be in [1, 1,000,000,000], got steps=100000000000000000000"),
                           (dict(walkers=10**20), "walkers must be in [2, 1,000,000] (and even), got walkers=100000000000000000000"),
                           (dict(steps=0), "steps must be in [1, 1,000,000,000], got steps=0"),
                           (dict(thin=0), "thin must be ≥ 1, got thin=0"),
                           (dict(seed=2**32), "seed must be in [0, 2**32 − 1 = 4294967295] (emcee's generator, NumPy's RandomState, takes no other), "
                                              "got seed=4294967296")]:
        with pytest.raises(ValueError) as caught:
            ctfit.sample(mat, data, **options)
        assert str(caught.value) == words


def test_negative_seeds_are_refused_by_name():
    mat = ctfit.load_material(COPPER)
    with pytest.raises(ValueError, match="seed must be ≥ 0"):
        ctfit.simulate(mat, 3, seed=-1)
    assert "--seed" in run("simulate", COPPER, "-o", "never.csv", "--seed", -1).output


def test_simulate_refuses_what_it_would_ignore_or_trip_on():
    """``channels`` for a spectral material and ``wavelength_nm`` for an RGB one were ignored without a
    word; a fractional ``n_pairs`` or ``seed`` stopped inside NumPy (IndexError, TypeError)."""
    spectral = ctfit.load_material(COPPER)
    rgb = ctfit.material_from_dict({"s": 0, "d": 1, "channels": ["R", "G", "B"], "Rd": [0.2, 0.1, 0.05]})
    for call, words in [
        (lambda: ctfit.simulate(spectral, 4, channels=["R", "G", "B"]), "is spectral; channels"),
        (lambda: ctfit.simulate(rgb, 4, wavelength_nm=[500.0]), "has RGB channels"),
        (lambda: ctfit.simulate(spectral, 1.5), "n_pairs must be a whole number"),
        (lambda: ctfit.simulate(spectral, 4, seed=1.5), "seed must be a whole number"),
    ]:
        with pytest.raises(ValueError, match=words):
            call()
    assert ctfit.simulate(spectral, np.int64(3)).directions()[0].shape[0] == 3  # a NumPy integer is a whole number
