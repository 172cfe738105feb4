"""``fit_batch``: many measurements in one vmapped program, each result what ``fit`` gives alone;
``ctfit fit DIR`` fits a folder that way."""

import json
from pathlib import Path

import jax
import jax.monitoring
import numpy as np
import pytest
from helpers import patch_module
from typer.testing import CliRunner

import ctfit
from ctfit._fitting import batch as _fit_batch
from ctfit._fitting.batch import batch_size
from ctfit._runtime import stored_programs as _aot
from ctfit.cli import app

WL = np.array([450.0, 650.0])
ST = ctfit.Structure(lobes=1)
BACKEND_COMPILE = "/jax/core/compile/backend_compile_duration"


def material(m, f0=(0.6, 0.9), wavelengths=WL):
    return ctfit.Material(ST, ctfit.Params(m=np.array([m]), w=np.array([1.0]), f0=np.asarray(f0)), wavelength_nm=wavelengths)


def same_geometry(ms, n_pairs=100, seed=0):
    """Measurements of one goniometer geometry (grid layout, two bands), one per slope in ``ms``."""
    base = ctfit.simulate(material(0.2), n_pairs, seed=seed)
    rng = np.random.default_rng(seed)
    return [base.replace(brdf=np.asarray(ctfit.evaluate(material(m), base)) * (1 + 0.01 * rng.standard_normal(len(base))), source=f"<m={m}>")
            for m in ms]


def scattered(n, seed, m=0.25):
    """``n`` samples, each its own direction pair, one band (pairs layout)."""
    rng = np.random.default_rng(seed)
    base = ctfit.Measurement(theta_i=rng.uniform(0, 70, n), phi_i=np.zeros(n), theta_o=rng.uniform(0, 70, n), phi_o=180 + rng.uniform(-40, 40, n),
                             band=np.zeros(n, int), wavelength_nm=np.array([550.0]), source=f"<{n} scattered>")
    values = np.asarray(ctfit.evaluate(material(m, (0.6,), np.array([550.0])), base)) * (1 + 0.01 * rng.standard_normal(n))
    return base.replace(brdf=values)


def assert_same_fit(batch, alone):
    """Same parameters (1e-8 relative), convergence, steps, cost, standard errors and warnings."""
    pa, pb = alone.material.params, batch.material.params
    for name in ("s", "m", "w", "f0", "n", "rd"):
        if getattr(pa, name) is not None:
            np.testing.assert_allclose(np.asarray(getattr(pb, name)), np.asarray(getattr(pa, name)), rtol=1e-8, err_msg=name)
    assert batch.converged == alone.converged and batch.stats["steps"] == alone.stats["steps"]
    assert batch.stats["cost"] == pytest.approx(alone.stats["cost"], rel=1e-8)
    assert batch.stats["n_samples"] == alone.stats["n_samples"]
    assert batch.warnings == alone.warnings
    for k, v in alone.stderr.items():
        np.testing.assert_allclose(batch.stderr[k], v, rtol=1e-6, err_msg=k)


def test_batch_equals_fitting_each_alone_in_input_order():
    grid = same_geometry([0.12, 0.25, 0.4])
    other = same_geometry([0.3], n_pairs=200, seed=1)[0]  # another geometry and size, the same layout
    pairs = [scattered(300, 2), scattered(600, 3, m=0.15)]  # another layout, another size bucket: padded 363 → 724 samples
    data = [grid[0], pairs[0], grid[1], other, pairs[1], grid[2]]
    batch = ctfit.fit_batch(data, ST, width=2)  # side by side (vmapped): 4 fits two at a time, 2 fits at once
    assert len(batch) == len(data)
    for d, b in zip(data, batch):
        assert b.material.name == f"fit of {d.source}"
        assert_same_fit(b, ctfit.fit(d, ST))


def test_groups_pad_to_the_largest_member_and_keep_layouts_apart():
    three = ctfit.simulate(material(0.2, (0.5, 0.6, 0.7), np.array([450.0, 550.0, 650.0])), 100, seed=4)  # three bands
    data = [*same_geometry([0.2, 0.3]), same_geometry([0.3], n_pairs=300)[0], scattered(300, 1), three]
    preps = {i: ctfit._fitting.least_squares.prepare_fit(d, ST, start=None, fixed=(), loss="auto", dtype=np.float64, starts=3) for i, d in enumerate(data)}
    groups = _fit_batch._groups(preps, "lm", 256)
    assert sorted(groups) == [[0, 1, 2], [3], [4]]
    assert {preps[i].problem.y.shape for i in (0, 1, 2)} == {(ctfit._fitting.chunks.bucket(300), 2)}
    assert float(preps[0].problem.mask.sum()) == 200
    with pytest.raises(ValueError, match=r"pad_to=\(10, 10\) is smaller than the data \(100 direction pairs, 200 samples\)"):
        preps[0].padded((10, 10))


def test_a_measurement_that_cannot_be_fitted_is_returned_as_its_error():
    good = same_geometry([0.2, 0.3])
    zero = good[0].replace(brdf=np.zeros(len(good[0])), source="zeros.csv")
    got = ctfit.fit_batch([zero, good[0]], ST, return_errors=True)
    assert isinstance(got[0], ValueError) and "zeros.csv" in str(got[0]) and "every brdf is 0" in str(got[0])
    assert isinstance(got[1], ctfit.FitResult) and got[1].converged
    with pytest.raises(ValueError, match="every brdf is 0"):
        ctfit.fit_batch([good[0], zero], ST)
    with pytest.raises(ValueError, match="2 starting values for 3 measurements"):
        ctfit.fit_batch([good[0], zero, good[1]], ST, start=[None, None])


def test_batch_sizes_grow_by_root_two():
    assert [batch_size(n) for n in (1, 2, 3, 4, 5, 6, 7, 9, 13, 17, 200)] == [1, 2, 3, 4, 6, 6, 8, 12, 16, 23, 256]


@pytest.fixture
def compiled(monkeypatch):
    """Names of the programs XLA compiles while the test runs (the compiled-program memory emptied,
    and no on-disk store: an earlier CLI test in this process may have enabled one, whose programs
    would load instead of compiling)."""
    monkeypatch.setattr(_aot, "_memory", {})
    monkeypatch.setattr(_aot, "_store", lambda: None)
    seen = []

    def listener(event, duration, **kw):
        if event == BACKEND_COMPILE:
            seen.append(kw.get("fun_name"))

    jax.monitoring.register_event_duration_secs_listener(listener)
    yield seen
    jax.monitoring.unregister_event_duration_listener(listener)


def test_one_compiled_program_solves_the_batch(compiled):
    first = same_geometry([0.1, 0.15, 0.2, 0.3, 0.45], n_pairs=90, seed=5)
    assert all(r.converged for r in ctfit.fit_batch(first, ST, width=2))
    programs = [name for name in compiled if name in ("jit(ctfit_fit)", "jit(ctfit_fit_batch)")]  # the fit programs of _aot.cached_call
    assert len(programs) == 1, compiled
    compiled.clear()
    again = same_geometry([0.12, 0.18, 0.22, 0.28, 0.33, 0.5], n_pairs=90, seed=6)  # 6 fits: the batch size of 5
    assert all(r.converged for r in ctfit.fit_batch(again, ST, width=2))
    assert compiled == []


def test_one_after_the_other_the_batch_shares_the_structure_s_programs(compiled, monkeypatch):
    from ctfit._fitting import chunked_fit, shared_geometry

    monkeypatch.setattr(chunked_fit, "_programs", {})
    monkeypatch.setattr(shared_geometry, "SHARED_MIN", 10**9)  # files of one geometry, each on chunks (not fitted together)
    first = same_geometry([0.1, 0.2, 0.3], n_pairs=90, seed=5)
    assert all(r.converged for r in ctfit.fit_batch(first, ST, width=1))
    programs = [name for name in compiled if name.startswith("jit(ctfit_")]
    assert len(programs) == len(set(programs)) and "jit(ctfit_fit_ne)" in programs, programs  # each of the fit's programs once
    again = same_geometry([0.12, 0.18, 0.22, 0.28, 0.33, 0.5], n_pairs=150, seed=6)  # more fits, other sizes
    compiled.clear()  # simulating compiles its own programs
    assert all(r.converged for r in ctfit.fit_batch(again, ST, width=1))
    assert compiled == []


def test_fit_dir_uses_one_batch_and_matches_fitting_each_file(tmp_path, monkeypatch):
    folder = tmp_path / "data"
    folder.mkdir()
    for i, d in enumerate([*same_geometry([0.15, 0.25, 0.35]), same_geometry([0.3], n_pairs=200, seed=2)[0]]):
        ctfit.write_csv(d, folder / f"m{i}.csv")
    (folder / "zeros.csv").write_text("theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n" + "".join(f"{t},0,{t},180,450,0\n" for t in (10, 20, 30, 40)))
    calls = []
    real = _fit_batch.fit_batch
    patch_module(monkeypatch, _fit_batch, "fit_batch", lambda ms, *a, **kw: calls.append(len(ms)) or real(ms, *a, **kw))
    runner = CliRunner()
    out = tmp_path / "fits"
    r = runner.invoke(app, ["fit", str(folder), "--no-diffuse", "--lobes", "1", "-o", str(out)])
    assert r.exit_code == 2, r.output
    assert calls == [5]
    assert "summary: 5 files: 4 converged, 0 did not converge, 1 failed" in r.stderr
    assert f"error: {folder / 'zeros.csv'}" in r.stderr and "every brdf is 0" in r.stderr
    for i in range(4):
        alone = tmp_path / f"m{i}.json"
        assert runner.invoke(app, ["fit", str(folder / f"m{i}.csv"), "--no-diffuse", "--lobes", "1", "-o", str(alone)]).exit_code == 0
        assert_same_numbers(folder_result(out / f"m{i}.fit.json"), json.loads(alone.read_text()))
    # Files are read and fitted a window at a time: the next file is read while fewer samples are held.
    calls.clear()
    patch_module(monkeypatch, _fit_batch, "SAMPLE_BUDGET", 300)  # files of 200, 200, 200, 400 and 4 samples
    windows = tmp_path / "windows"
    r = runner.invoke(app, ["fit", str(folder), "--no-diffuse", "--lobes", "1", "-o", str(windows)])
    assert r.exit_code == 2 and calls == [2, 2, 1]
    assert "summary: 5 files: 4 converged, 0 did not converge, 1 failed" in r.stderr
    for i in range(4):
        assert_same_numbers(json.loads((windows / f"m{i}.fit.json").read_text()), json.loads((out / f"m{i}.fit.json").read_text()))


def folder_result(path):
    """A result of a folder run without its ``input_sha256`` (docs/formats.md: the results in a
    folder carry the hash of their input; a result of one file named by ``-o`` does not)."""
    doc = json.loads(Path(path).read_text())
    assert len(doc.pop("input_sha256")) == 64
    return doc


def assert_same_numbers(a, b, where="doc"):
    """Equal JSON documents, numbers to 1e-8 relative (the stationarity measure to 1e-9 absolute); the fit's time aside."""
    if isinstance(b, dict):
        assert set(a) == set(b), where
        for k in b:
            if k != "time_s":
                assert_same_numbers(a[k], b[k], f"{where}.{k}")
    elif isinstance(b, list):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same_numbers(x, y, f"{where}[{i}]")
    elif isinstance(b, float):
        # The predicted decrease at a converged point is rounding (~1e-13): equal to 1e-9 absolute.
        tiny = 1e-9 if where.endswith("gauss_newton_decrease") else 1e-300
        assert a == pytest.approx(b, rel=1e-8, abs=tiny, nan_ok=True), where
    else:
        assert a == b, where


def test_exported():
    assert {"fit_batch", "fit_texels", "TexelFits"} <= set(ctfit.__all__)
    assert ctfit.fit_batch is _fit_batch.fit_batch
