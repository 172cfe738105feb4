"""One set of compiled programs per structure, whatever the data's size (ctfit/_fitting/chunked_fit.py):
a fit of a new sample count compiles nothing, the fit on chunks gives the one-program fit's
result, and a program store copied to another folder still serves its programs."""

from __future__ import annotations

import dataclasses
import shutil

import equinox as eqx
import jax
import numpy as np
import pytest

import ctfit
from ctfit._fitting import chunked_fit
from ctfit._fitting.least_squares import fit_core, prepare_fit
from ctfit._runtime import stored_programs


def _scattered(n: int, seed: int, bands: int = 1) -> ctfit.Measurement:
    """``n`` samples, each its own direction pair, values drawn in NumPy (cheap at 2·10⁶)."""
    rng = np.random.default_rng(seed)
    ti, to = rng.uniform(0, 70, n), rng.uniform(0, 70, n)
    po = 180 + rng.uniform(-40, 40, n)
    wl = np.linspace(450.0, 650.0, bands)
    return ctfit.Measurement(theta_i=ti, phi_i=np.zeros(n), theta_o=to, phi_o=po, band=rng.integers(0, bands, n), wavelength_nm=wl,
                             brdf=rng.uniform(0.05, 1.0, n), source=f"<{n} samples>")


@pytest.mark.slow
def test_no_compilation_for_a_new_sample_count_from_500_to_two_million(compilations):
    st = ctfit.Structure(lobes=1, diffuse=None)
    sizes = (500, 3_000, 41_000, 2_000_000)
    data = {n: _scattered(n, n) for n in sizes}
    counts = []
    for n in sizes:
        compilations.clear()
        res = ctfit.fit(data[n], st, starts=3, max_steps=3)
        assert res.stats["n_samples"] == n and np.isfinite(res.stats["cost"])
        assert ("race_samples" in res.stats) == (n > 40_000)  # a large file's seeds raced on a sample: the same programs
        counts.append(len(compilations))
    assert counts[0] <= 20, f"{counts[0]} XLA compilations for the first fit of a structure"
    assert counts[1:] == [0, 0, 0], f"compilations per later size: {counts[1:]}"


def test_a_grid_of_another_size_compiles_nothing(compilations):
    gold = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([0.25]), w=np.ones(1), f0=np.array([0.5, 0.8, 0.9])),
                          wavelength_nm=np.array([450.0, 550.0, 650.0]))
    first = ctfit.fit(ctfit.simulate(gold, n_pairs=400, noise=0.01, seed=1), gold.structure)
    assert first.converged
    compilations.clear()
    data = ctfit.simulate(gold, n_pairs=3000, noise=0.01, seed=2)
    compilations.clear()  # simulating compiles its own programs
    second = ctfit.fit(data, gold.structure)
    assert second.converged and compilations == []
    np.testing.assert_allclose(second.material.params.m, [0.25], rtol=5e-3)


def _third(data: ctfit.Measurement, seed: int) -> ctfit.Measurement:
    """A third of the samples at random: too sparse for the grid layout."""
    keep = np.random.default_rng(seed).permutation(len(data))[: len(data) // 3]
    cols = ("theta_i", "phi_i", "theta_o", "phi_o", "band", "brdf")
    return data.replace(sigma=None, **{c: np.asarray(getattr(data, c))[keep] for c in cols})


@pytest.mark.parametrize("loss, layout", [("relative", "grid"), ("absolute", "pairs"), ("log", "grid"), ("relative", "pairs")])
def test_the_fit_on_chunks_equals_the_one_program_fit(loss, layout):
    gold = ctfit.Material(ctfit.Structure(lobes=2), ctfit.Params(s=np.asarray(0.8), m=np.array([0.15, 0.4]), w=np.array([0.6, 0.4]),
                                                                  f0=np.array([0.6, 0.9])), wavelength_nm=np.array([450.0, 650.0]))
    data = ctfit.simulate(gold, n_pairs=2500 if layout == "grid" else 5000, noise=0.02, seed=3)  # more than one chunk
    data = data if layout == "grid" else _third(data, 4)
    options = dict(start=None, fixed=(), loss=loss, dtype=jax.numpy.float64, starts=3)
    chunked = prepare_fit(data, gold.structure, chunk=chunked_fit.ROWS, **options)
    assert len(chunked_fit.chunk_problems(chunked.problem)) > 1 and chunked.problem.spec.grid == (layout == "grid")
    got = chunked_fit.chunked_core(chunked.problem, chunked.u0, chunked.grid, chunked.k, 256, False)
    whole = prepare_fit(data, gold.structure, **options)
    want = jax.device_get(eqx.filter_jit(fit_core)(whole.problem, whole.u0, whole.grid, whole.k, "lm", 256, False))
    assert got["best"] == int(want["best"]) and list(got["steps"]) == list(want["steps"])
    np.testing.assert_allclose(got["costs"], want["costs"], rtol=1e-9)
    for k in want["u"]:
        np.testing.assert_allclose(got["u"][k], want["u"][k], rtol=1e-7, atol=1e-10)
    np.testing.assert_allclose(got["jtj"], want["jtj"], rtol=1e-8, atol=1e-12)
    for k in ("rmse", "rel_rmse", "zero_cost"):
        np.testing.assert_allclose(got[k], want[k], rtol=1e-9)
    rel = np.asarray(got["rel"]).reshape(-1)[: len(data)]
    np.testing.assert_allclose(rel, np.asarray(want["rel"]).reshape(-1)[: len(data)], rtol=1e-5, atol=1e-7)


def test_a_copied_program_store_still_serves_its_programs(tmp_path, monkeypatch, compilations):
    """The store's entries are named by what they compute, not by where the folder is."""
    from jax.experimental.compilation_cache import compilation_cache

    first, second = tmp_path / "a", tmp_path / "b"
    folder = jax.config.jax_compilation_cache_dir
    monkeypatch.setattr(stored_programs, "_memory", {})
    monkeypatch.setattr(stored_programs, "_stores", {})
    monkeypatch.setattr(stored_programs, "_jax_cache_hits", 0)
    monkeypatch.setattr(chunked_fit, "_programs", {})
    try:
        jax.config.update("jax_compilation_cache_dir", str(first))
        compilation_cache.reset_cache()
        data = _scattered(700, 5, bands=2)
        st = ctfit.Structure(lobes=1, diffuse="constant")
        want = ctfit.fit(data, st, starts=2, max_steps=20)
        shutil.move(first, second)
        jax.config.update("jax_compilation_cache_dir", str(second))
        compilation_cache.reset_cache()
        monkeypatch.setattr(stored_programs, "_memory", {})
        monkeypatch.setattr(stored_programs, "_stores", {})
        monkeypatch.setattr(chunked_fit, "_programs", {})
        compilations.clear()
        got = ctfit.fit(_scattered(900, 6, bands=2), st, starts=2, max_steps=20)
        assert [n for n in compilations] == [], f"{len(compilations)} compilations with the moved store"
        assert np.isfinite(got.stats["cost"]) and np.isfinite(want.stats["cost"])
        assert oct((second / "ctfit-aot").stat().st_mode & 0o777) == "0o700"
    finally:
        jax.config.update("jax_compilation_cache_dir", folder)
        compilation_cache.reset_cache()


@pytest.mark.parametrize("structure", [ctfit.Structure(lobes=2, diffuse="F0/pi"), ctfit.Structure(lobes=1, diffuse="spectrum", family="plastic")])
def test_a_fit_started_from_a_fit_takes_the_programs_of_a_fit_started_anywhere(structure):
    """A fitted F0 metal reports n beside F0 (and a plastic's start may carry an F0). A fit started
    from those parameters (the data-chosen default's final fit and every nested candidate) holds
    fixed only the fields its structure uses, so its problem has the shapes, and its programs the
    keys, of a fit from the default start: one ``fit_ne`` per structure (with that n held, the
    default compiled and loaded a second one for the structure it chose)."""
    copper = ctfit.Material(ctfit.Structure(lobes=2, diffuse="F0/pi"),
                            ctfit.Params(s=np.array(0.9), m=np.array([0.15, 0.4]), w=np.array([0.7, 0.3]), f0=np.array([0.95, 0.64, 0.55])),
                            wavelength_nm=np.array([650.0, 550.0, 450.0]))
    data = ctfit.simulate(copper, n_pairs=200, noise=0.01, seed=4)
    fitted = ctfit.fit(data, structure, max_steps=5)
    extra = fitted.material.params.n if structure.fresnel == "f0" else fitted.material.params.f0  # reported, not used
    start = dataclasses.replace(fitted.material.params, **{"n" if structure.fresnel == "f0" else "f0": np.ones(3) if extra is None else extra})

    def key(start):
        prep = prepare_fit(data, structure, start=start, fixed=(), loss="relative", dtype=np.float64, starts=3, chunk=chunked_fit.ROWS)
        return stored_programs._key("fit_ne", (chunked_fit._EFFORT["fit_ne"], prep.problem, prep.u0))

    assert key(start) == key(None)
