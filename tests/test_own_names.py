"""Names a run must not share, and names ctfit chooses itself: refused before any work where a
write would destroy a user's file (two options naming one file; a link or a user's file where
ctfit puts ``X.not-converged.json``, ``X.posterior.json`` or a plot in a folder); a rerun still
replaces its own results."""

from __future__ import annotations

import json
import os
from pathlib import Path

import matplotlib
import pytest
from test_outputs import no_work  # noqa: F401 — the fixture: a command that starts work before checking its outputs fails
from typer.testing import CliRunner

from ctfit._io import output_paths
from ctfit._io.output_paths import OutputError, check_distinct, check_rerun_plot, plot_metadata, png_software
from ctfit.cli import app

from conftest import ROOT

matplotlib.use("Agg")
import matplotlib.pyplot as plt

MATERIAL = ROOT / "configs" / "copper-vase.toml"
runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """data.csv, a fit result fit.json (converged) and a user's notes.txt in the current folder."""
    monkeypatch.chdir(tmp_path)
    Path("data.csv").write_text("theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n10,0,10,180,500,1\n20,0,20,180,500,0.5\n")
    doc = json.loads(json.dumps({"s": 1.0, "d": 0.0, "lobes": [{"m": 0.2, "weight": 1.0}], "F0": [0.9], "wavelength_nm": [500.0],
                                 "data": "data.csv", "fit": {"converged": True}}))
    Path("fit.json").write_text(json.dumps(doc))
    Path("notes.txt").write_text("precious\n")
    return tmp_path


def _refused(result, *phrases: str) -> None:
    assert result.exit_code == 2, result.output
    for phrase in phrases:
        assert phrase in result.output, result.output


def test_two_options_naming_one_file_are_refused_before_any_work(folder, no_work):
    _refused(run("fit", "data.csv", "-o", "res.png", "--plot", "res.png"), "--plot res.png: is also -o res.png")
    _refused(run("fit", "data.csv", "--sample", "--backend", "out.json", "-o", "out.json"), "--backend out.json: is also -o out.json")
    _refused(run("fit", "data.csv", "-o", "./a/../r.png", "--plot", "r.png"), "is also -o")  # one file, two spellings
    _refused(run("sample", "fit.json", "data.csv", "--backend", "chain.h5", "--idata", "chain.h5"), "--idata chain.h5: is also --backend chain.h5")
    _refused(run("sample", "fit.json", "data.csv", "-o", "o.json", "--idata", "o.json"), "--idata o.json: is also -o o.json")
    assert not any(Path(p).exists() for p in ("res.png", "out.json", "r.png", "chain.h5", "o.json"))


def test_check_distinct_lets_a_device_be_named_twice(tmp_path):
    check_distinct([("-o", Path(os.devnull)), ("--plot", Path(os.devnull)), ("--backend", None)])
    (tmp_path / "a").touch()
    os.link(tmp_path / "a", tmp_path / "b")  # a hard link: one file
    with pytest.raises(OutputError, match="is also -o"):
        check_distinct([("-o", tmp_path / "a"), ("--plot", tmp_path / "b")])


def test_a_link_or_a_users_file_where_an_unconverged_fit_would_go_is_refused_before_any_work(folder, no_work):
    os.symlink("notes.txt", "fit.not-converged.json")
    _refused(run("fit", "data.csv", "-o", "fit.json"), "fit.not-converged.json: is a symbolic link (to notes.txt)")
    os.unlink("fit.not-converged.json")
    Path("fit.not-converged.json").write_text("mine\n")
    _refused(run("fit", "data.csv", "-o", "fit.json"), "fit.not-converged.json: the file exists and is not a fit result of ctfit")
    assert Path("notes.txt").read_text() == "precious\n" and Path("fit.not-converged.json").read_text() == "mine\n"


def test_the_unconverged_name_takes_an_earlier_unconverged_fit(folder):
    Path("fit.not-converged.json").write_text(json.dumps({"fit": {"converged": False}}))
    beside, note = output_paths.unconverged_target("fit.json")
    assert beside == Path("fit.not-converged.json") and "is kept" in note


def test_a_link_or_a_users_file_where_the_posterior_would_go_is_refused_before_any_work(folder, no_work):
    os.symlink("notes.txt", "fit.posterior.json")
    _refused(run("sample", "fit.json", "data.csv", "--steps", 10), "fit.posterior.json: is a symbolic link (to notes.txt)")
    os.unlink("fit.posterior.json")
    Path("fit.posterior.json").write_text("mine\n")
    _refused(run("sample", "fit.json", "data.csv", "--steps", 10), "fit.posterior.json: the file exists and is not a posterior of ctfit")
    Path("fit.posterior.json").write_text(json.dumps({"uncertainty": {}}))  # its own: the checks pass, and the work starts
    started = run("sample", "fit.json", "data.csv", "--steps", 10)
    assert isinstance(started.exception, AssertionError) and "started its work" in str(started.exception)
    assert Path("notes.txt").read_text() == "precious\n"


def _png(path, metadata=None):
    fig = plt.figure(figsize=(1, 1))
    fig.savefig(path, format="png", metadata=metadata)
    plt.close(fig)


def test_a_plot_of_ctfit_is_known_by_its_software_text(tmp_path):
    _png(tmp_path / "ours.png", plot_metadata("png"))
    _png(tmp_path / "theirs.png")  # matplotlib's own text: a user's plot
    (tmp_path / "text.png").write_text("user file\n")
    assert png_software(tmp_path / "ours.png").startswith("ctfit ")
    assert png_software(tmp_path / "theirs.png").startswith("Matplotlib")
    assert png_software(tmp_path / "text.png") is None and png_software(tmp_path / "missing.png") is None
    assert plot_metadata("pdf") is None
    check_rerun_plot(tmp_path / "ours.png")
    check_rerun_plot(tmp_path / "missing.png")
    for name in ("theirs.png", "text.png"):
        with pytest.raises(OutputError, match="is not a plot of ctfit"):
            check_rerun_plot(tmp_path / name)


def test_a_users_file_where_a_plot_would_go_in_a_folder_is_refused_before_any_work(folder, no_work):
    Path("pl").mkdir()
    Path("pl/data.fit.png").write_text("user file\n")
    _refused(run("fit", "data.csv", "--plot", "pl/"), "pl/data.fit.png: the file exists and is not a plot of ctfit")
    Path("sp").mkdir()
    Path("sp/fit.posterior.corner.png").write_text("user file\n")
    _refused(run("sample", "fit.json", "data.csv", "--steps", 10, "--plot", "sp"), "sp/fit.posterior.corner.png: the file exists and is not a plot")
    assert Path("pl/data.fit.png").read_text() == Path("sp/fit.posterior.corner.png").read_text() == "user file\n"


def test_a_rerun_replaces_its_own_plot_in_a_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    made = run("simulate", MATERIAL, "-o", "data.csv", "--samples", 40, "--wavelengths", "450:650:100", "--seed", 1)
    assert made.exit_code == 0, made.output
    for _ in range(2):
        result = run("fit", "data.csv", "--lobes", 1, "--no-diffuse", "-q", "--plot", "pl/")
        assert result.exit_code == 0, result.output
        assert png_software(Path("pl/data.fit.png")).startswith("ctfit ")
