"""``ctfit sample`` on the three real measurements, run as a new user would (issue 12).

Before: the grey tape crashed ("Eigenvalues did not converge"); the 3M yellow sheet gave F0 = 1,
s = 0.005, m = 0.03 against the fit's 0.44, 0.06, 0.15 without a word; the pink felt's m had a
mean of 7e9. Now each run ends with a table that says whether the posterior is usable and, if
not, why (one line per failed check), the JSON says the same, and the exit status is 1.
"""

import json

import numpy as np
import pytest
from typer.testing import CliRunner

import ctfit
from ctfit._cli.messages import cli_message
from ctfit._model.parameters import M_MAX
from ctfit.cli import SAMPLE_NOT_USABLE, app

from conftest import MEASURED

runner = CliRunner()
# The ALTA reader's note on the 86 samples at the horizon (the CLI prints it as one line).
pytestmark = pytest.mark.filterwarnings("ignore::ctfit._io.errors.DataWarning")
GRAY = ("retro-gray-tape.dat", ["--param-out", "INV_STERADIAN_COSINE_FACTOR"])
JAUNE = ("retro-3M-jaune.dat", [])
PINK = ("pink-felt-1d.alta", [])
PAPERS_METAL = ["--family", "metal", "--diffuse", "F0/pi", "--lobes", "1"]  # the structure these verdicts are stated for


def _fit_and_sample(tmp_path, name, extra, *sample_args):
    data = str(MEASURED / name)
    fit_json = tmp_path / "x.fit.json"
    fitted = runner.invoke(app, ["fit", data, "-o", str(fit_json), "-q", *PAPERS_METAL, *extra])
    assert fitted.exit_code == 0, fitted.output
    before = fit_json.read_bytes()
    out = runner.invoke(app, ["sample", str(fit_json), data, "--steps", "300", "-q", *extra, *sample_args])
    assert fit_json.read_bytes() == before  # the input is never written; the result goes beside it
    return out, json.loads((tmp_path / "x.fit.posterior.json").read_text())


@pytest.mark.parametrize("name, extra", [GRAY, JAUNE, PINK], ids=["gray-tape", "3M-yellow", "pink-felt"])
def test_real_files_end_with_a_verdict_not_a_crash(tmp_path, name, extra):
    out, doc = _fit_and_sample(tmp_path, name, extra)
    assert "error:" not in out.output and (out.exception is None or isinstance(out.exception, SystemExit)), out.output
    u = doc["uncertainty"]
    assert out.exit_code == (0 if u["usable"] else SAMPLE_NOT_USABLE)
    assert ("posterior: usable" in out.output) == u["usable"]
    for line in u["problems"]:  # the JSON keeps the library's words, the table shows the options (--loss for loss=)
        assert f"problem: {cli_message(line)}" in out.output and "\n" not in line
    # Every summary is finite and inside its prior's range (no m of 7e9, no 240,000 on an axis).
    for lobe in u["lobes"]:
        assert all(np.isfinite(v) and 0 < v <= M_MAX for v in lobe["m"].values())
    assert all(0 <= e["p2.5"] <= e["p97.5"] <= 1 for e in u["F0"])


def test_yellow_sheet_says_the_posterior_left_the_fit(tmp_path):
    """Retro-reflection the model cannot represent: under the relative likelihood the posterior
    (s 0.0065, m 0.025) is far from the least-squares fit (s 0.060, m 0.148), further than either's
    uncertainty; the result says so instead of reporting it as the answer."""
    out, doc = _fit_and_sample(tmp_path, *JAUNE)
    u = doc["uncertainty"]
    assert out.exit_code == SAMPLE_NOT_USABLE and u["usable"] is False and "NOT usable" in out.output
    assert any(p.startswith("left the fit") for p in u["problems"]), u["problems"]
    left = u["checks"]["left_fit"]
    assert left["draws_denser_than_optimum"] > 0.99 and left["distance2"] > 10 * left["distance2_limit"]


def test_grey_tape_says_what_the_data_cannot_constrain(tmp_path):
    """The grey tape (the crash "Eigenvalues did not converge" before): the posterior spreads over
    s and m up to their prior bounds; the result names them."""
    out, doc = _fit_and_sample(tmp_path, *GRAY)
    u = doc["uncertainty"]
    assert out.exit_code == SAMPLE_NOT_USABLE and u["usable"] is False
    assert {"s", "m[0]"} <= set(u["checks"]["not_constrained"]), u["checks"]
    assert any(b.startswith("s runs to 0") for b in u["checks"]["at_bound"])


def test_pink_felt_slope_is_bounded_and_reported(tmp_path):
    """s → 0 leaves m free: m's posterior stops at the prior's bound M_MAX and the result says so."""
    out, doc = _fit_and_sample(tmp_path, *PINK, "--plot", str(tmp_path / "plots"), "--idata", str(tmp_path / "run.nc"))
    u = doc["uncertainty"]
    m = u["lobes"][0]["m"]
    assert m["mean"] < M_MAX and m["p97.5"] <= M_MAX
    assert any("m[0] runs to 4" in b for b in u["checks"]["at_bound"]), u["checks"]
    assert u["priors"]["parameters"]["m"]["range"] == "[1e-05, 4]"
    # The chain opens in ArviZ, one chain per walker, with the JSON's draws.
    from ctfit._sampling.arviz_export import arviz

    idata = arviz().from_netcdf(str(tmp_path / "run.nc"))
    post = idata.posterior
    assert post.sizes["chain"] == u["diagnostics"]["walkers"] and post.sizes["chain"] * post.sizes["draw"] == u["diagnostics"]["draws"]
    np.testing.assert_allclose(float(post["m"].median()), m["median"], rtol=1e-12)
    assert list(post["F0"].coords["band"].values) == ["R", "G", "B"]
    assert set(u["diagnostics"]["r_hat"]) >= {"s", "m[0]", "F0[0]"} and all(v > 0 for v in u["diagnostics"]["ess_bulk"].values())
    table = arviz().summary(idata, var_names=["s", "m"])  # ArviZ's own summary of the file
    np.testing.assert_allclose(table.loc["m[0]", "r_hat"], u["diagnostics"]["r_hat"]["m[0]"], atol=0.01)


def test_sample_loss_option_fits_again_and_refuses_unknown_losses(tmp_path):
    out, doc = _fit_and_sample(tmp_path, *PINK, "--loss", "log")
    u = doc["uncertainty"]
    assert out.exit_code in (0, SAMPLE_NOT_USABLE) and u["likelihood"]["loss"] == "log"
    assert any("fitted with loss 'log' first" in w for w in u["warnings"])
    bad = runner.invoke(app, ["sample", str(tmp_path / "x.fit.json"), str(MEASURED / PINK[0]), "--loss", "huber"])
    assert bad.exit_code == 2 and "--loss must be one of" in bad.output


def test_single_band_data_of_unknown_wavelength_is_labelled_so(tmp_path):
    """ALTA files without wavelengths: the table and the corner plot say "unknown band", never
    the placeholder wavelength (550 nm)."""
    from types import SimpleNamespace

    from ctfit._sampling.plots import _global_columns
    from ctfit._sampling.table import format_uncertainty_table

    material = ctfit.Material(ctfit.Structure(lobes=1), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.4])),
                              wavelength_nm=np.array([550.0]), band_unknown=True)  # as a fit of retro-3M-jaune.dat has it
    rng = np.random.default_rng(0)
    draws = {"m": rng.normal(0.2, 0.01, (50, 1)), "F0": rng.normal(0.4, 0.01, (50, 1))}
    result = SimpleNamespace(material=material, chain=draws, optimum={"m": [0.2], "F0": [0.4]})
    assert _global_columns(result)[1] == ["m", "$F_0$[unknown band]"]  # the corner plot's panels
    doc = {"band_unknown": True, "wavelength_nm": [550.0], "uncertainty": {"F0": [{"median": 0.3, "p16": 0.29, "p84": 0.31}]}}
    table = format_uncertainty_table(doc, "felt")
    assert "unknown band" in table and "550" not in table


def test_fit_with_sample_exits_1_when_the_posterior_is_not_usable(tmp_path):
    """``ctfit fit --sample`` says what ``ctfit sample`` says: a converged fit whose posterior
    is not usable (the yellow sheet: it left the fit) exits with status 1 and one error line.
    The fit is of the paper's metal structure, so no data-chosen structure is compiled."""
    out = runner.invoke(app, ["fit", str(MEASURED / JAUNE[0]), "-o", str(tmp_path / "y.json"), "--sample", "--steps", "300", "-q", *PAPERS_METAL])
    doc = json.loads((tmp_path / "y.json").read_text())
    assert doc["fit"]["converged"] and doc["uncertainty"]["usable"] is False
    assert out.exit_code == 1 and "error: the posterior is not usable" in out.output, out.output
