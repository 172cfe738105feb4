"""A file name that is not UTF-8 (Latin-1 bytes): Python holds it as lone surrogates, which UTF-8
text, matplotlib and a strict terminal refuse. A measurement's source and a material's name hold
U+FFFD there (``ctfit/_model/names.py``); a fit of such a file reports, plots and writes."""

from __future__ import annotations

import os

import numpy as np

import ctfit
from ctfit._fitting.plots import plot_fit
from ctfit._model.names import valid_name

LATIN1 = os.fsdecode(b"caf\xe9.csv")


def test_valid_name_replaces_only_what_is_not_text():
    assert valid_name(LATIN1) == "caf\ufffd.csv"
    assert valid_name("café ✓.csv") == "café ✓.csv"
    assert valid_name("a\ud800b") == "a?b"  # a lone surrogate that no byte stands for


def test_a_measurement_and_a_material_hold_valid_names():
    m = ctfit.Measurement(theta_i=np.array([30.0]), phi_i=np.zeros(1), theta_o=np.array([30.0]), phi_o=np.array([180.0]),
                          band=np.zeros(1, int), wavelength_nm=np.array([550.0]), brdf=np.array([0.25]), source=LATIN1)
    assert m.source == "caf\ufffd.csv" and m.replace(brdf=np.array([0.5])).source == "caf\ufffd.csv"
    gold = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.9])),
                          wavelength_nm=np.array([550.0]), name=LATIN1)
    assert gold.name == "caf\ufffd.csv"


def test_a_fit_of_such_a_file_is_plotted_and_saved(tmp_path):
    """matplotlib refused the title naming the file (``set_text(): incompatible function arguments``)."""
    gold = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.4, 0.9])),
                          wavelength_nm=np.array([450.0, 650.0]))
    path = tmp_path / LATIN1
    ctfit.write_csv(ctfit.simulate(gold, n_pairs=200, noise=0.01, seed=1), path)
    data = ctfit.read_measurement(path)
    res = ctfit.fit(data, gold.structure)
    plot_fit(res, data, tmp_path / "fit.png")
    saved = ctfit.load_material(ctfit.save_material_json(res.material, tmp_path / "fit.json"))
    assert (tmp_path / "fit.png").stat().st_size > 0 and saved.name.endswith("caf\ufffd.csv")
