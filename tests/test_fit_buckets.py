"""The solvers other than the default Levenberg–Marquardt (which compiles nothing per size:
tests/test_fit_programs.py) compile one fit program per structure and size bucket: a
measurement of another size in the same bucket reuses it (no XLA compilation), and padding
changes no result."""

import numpy as np

import ctfit
from ctfit._fitting.chunks import bucket
from ctfit._fitting.problem import make_problem


def _scattered(n, seed):
    """``n`` samples, each its own direction pair (no two rows share a geometry), one band."""
    rng = np.random.default_rng(seed)
    ti, to = rng.uniform(0, 70, n), rng.uniform(0, 70, n)
    po = 180 + rng.uniform(-40, 40, n)
    base = ctfit.Measurement(theta_i=ti, phi_i=np.zeros(n), theta_o=to, phi_o=po, band=np.zeros(n, int),
                             wavelength_nm=np.array([550.0]), source=f"<{n} samples>")
    truth = ctfit.Material(ctfit.Structure(lobes=1), ctfit.Params(m=np.array([0.25]), w=np.array([1.0]), f0=np.array([0.6])),
                           wavelength_nm=np.array([550.0]))
    values = np.asarray(ctfit.evaluate(truth, base)) * (1 + 0.01 * rng.standard_normal(n))
    return base.replace(brdf=values)


def test_bucket_sizes():
    assert bucket(1) == bucket(256) == 256
    assert bucket(257) == 363 and bucket(20_000) == bucket(23_171) == 23_171
    for n in (300, 5_000, 123_457, 4_500_000):
        b = bucket(n)
        assert n <= b < 1.42 * n + 1
        assert bucket(b) == b


def test_new_sample_count_in_a_bucket_compiles_nothing(store, compilations):
    """(A fresh store: the first fit compiles whatever other tests of this worker, or another
    worker through the shared cache, made before.)"""
    st = ctfit.Structure(lobes=1)
    a, b = _scattered(1900, 1), _scattered(2000, 2)  # same bucket (2048), two sample counts
    first = ctfit.fit(a, st, solver="gauss-newton")
    assert first.converged and len(compilations) > 0
    compilations.clear()
    second = ctfit.fit(b, st, solver="gauss-newton")
    assert second.converged
    assert compilations == [], f"{len(compilations)} XLA compilations for a new sample count in a compiled bucket"
    assert second.stats["n_samples"] == 2000


def test_padding_changes_no_result():
    data = _scattered(1500, 3)
    st = ctfit.Structure(lobes=1)
    padded = make_problem(st, data, fixed_params=ctfit.Params(m=np.array([0.2]), w=np.array([1.0]), f0=np.array([0.5])), pad=True)
    assert padded.y.shape[0] == bucket(1500) > 1500 and float(padded.mask.sum()) == 1500
    res = ctfit.fit(data, st)
    p = res.material.params
    np.testing.assert_allclose(p.m, [0.25], rtol=2e-3)
    np.testing.assert_allclose(p.f0, [0.6], rtol=2e-3)
    assert res.stats["n_samples"] == 1500
