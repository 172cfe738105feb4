"""Fits to data rendered by Mitsuba 3 (roughconductor, Beckmann, Smith G, tabulated Cu and Au n, k)."""

import numpy as np
import pytest

import ctfit
from ctfit import fit

pytest.importorskip("mitsuba")
from mitsuba_render import render

pytestmark = pytest.mark.mitsuba

WL = np.linspace(420.0, 700.0, 8)
M = 0.2


def tables(metal):
    t = ctfit.read_optical_constants(metal)
    n = np.interp(WL, t["wavelength_nm"], t["n"])
    k = np.interp(WL, t["wavelength_nm"], t["k"])
    return n, k, np.asarray(ctfit.f0_from_nk(n, k))


@pytest.fixture(scope="module", params=["Cu", "Au"])
def metal(request):
    return request.param, tables(request.param)


def test_effective_index_fit_up_to_50_degrees(metal):
    name, (n, k, f0) = metal
    data = render(500, WL, n, k, M, max_theta=50.0, seed=1)
    res = fit(data, ctfit.Structure(lobes=1, geometry="smith"), loss="relative")
    assert res.converged
    np.testing.assert_allclose(res.material.params.m, [M], rtol=0.03)
    assert np.max(np.abs(res.material.params.f0 - f0)) < 0.01, name


def test_conductor_fit_up_to_85_degrees(metal):
    name, (n, k, f0) = metal
    data = render(700, WL, n, k, M, max_theta=85.0, seed=2)
    assert 0 < np.mean(data.brdf == 0) < 0.2  # exact zeros far from the peak, as in real data
    st = ctfit.Structure(lobes=1, geometry="smith", fresnel="conductor")
    res = fit(data, st, loss="relative")
    assert res.converged
    p = res.material.params
    assert np.max(np.abs(np.asarray(ctfit.f0_from_nk(p.n, p.k)) - f0)) < 0.01, name
    np.testing.assert_allclose(p.m, [M], rtol=0.01)
    # n and k are recovered close to the tables. They trade off against each other at fixed F0
    # and are pinned only by the grazing samples, where Mitsuba's Smith G1 (a rational
    # approximation, up to 0.5 % off) biases them: measured worst cases 12 % in n (where n is
    # only 0.13) and 6.4 % in k, both for Au at 700 nm.
    assert np.max(np.abs(p.n - n) / n) < 0.15 and np.max(np.abs(p.k - k) / k) < 0.10, (p.n, n, p.k, k)
    assert res.stats["rel_rmse"] < 0.01
