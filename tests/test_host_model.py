"""The model on the host: ``brdf(..., xp=numpy)`` with the geometry of ``geometry(..., xp=numpy)``
equals the traced model (float64 and float32), is 0 on and below the horizon, keeps the dtype and
makes no program; the data-chosen default's median errors are computed with it."""

from __future__ import annotations

import dataclasses
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import STRUCTURES, make_params, structure_id

import ctfit
from ctfit._fitting import structure_selection
from ctfit._model import brdf, brdf_pairs, geometry_from_angles_deg

MORE = [ctfit.Structure(lobes=1, family="plastic", fresnel="n", diffuse="transmitted", geometry=g) for g in ("v-cavity", "smith", "smith-rational")]
MORE += [ctfit.Structure(lobes=3, geometry="smith-rational", fresnel="conductor", diffuse="spectrum"), ctfit.Structure(lobes=0, diffuse="spectrum")]


def _angles(dtype) -> np.ndarray:
    """Random pairs over and a little below the horizon, exact normal incidence and grazing ones."""
    rng = np.random.default_rng(3)
    a = np.stack([rng.uniform(0, 92, 500), rng.uniform(0, 360, 500), rng.uniform(0, 92, 500), rng.uniform(0, 360, 500)], axis=1)
    a[:4] = [[0, 0, 0, 0], [90, 0, 30, 180], [30, 0, 89.9999, 180], [89.99, 10, 89.99, 190]]
    return a.astype(dtype)


def _params(st: ctfit.Structure, dtype) -> ctfit.Params:
    p = make_params(st, dtype)
    return dataclasses.replace(p, rd=jnp.asarray([0.1, 0.2, 0.05], dtype)) if st.diffuse == "transmitted" else p


def _both(st: ctfit.Structure, dtype):
    a = _angles(dtype)
    host_params = jax.tree.map(lambda v: np.asarray(v, dtype), _params(st, dtype))
    with np.errstate(all="ignore"):
        host = brdf(st, host_params, geometry_from_angles_deg(a[:, 0], a[:, 1], a[:, 2], a[:, 3], xp=np), xp=np)
    traced = jax.jit(lambda p, a: brdf(st, p, geometry_from_angles_deg(a[:, 0], a[:, 1], a[:, 2], a[:, 3])))(_params(st, dtype), jnp.asarray(a))
    return a, host, np.asarray(traced)


@pytest.mark.parametrize("st", STRUCTURES[::3] + MORE, ids=structure_id)
def test_the_host_model_equals_the_traced_one_in_float64(st):
    a, host, traced = _both(st, np.float64)
    assert type(host) is np.ndarray and host.dtype == np.float64 and host.shape == traced.shape
    assert np.all(np.isfinite(host))
    below = (a[:, 0] >= 90) | (a[:, 2] >= 90)
    assert below.any() and np.all(host[below] == 0)
    # 1 − F near grazing (a transmitted diffuse part) cancels: relative to the peak, not per value
    np.testing.assert_allclose(host, traced, rtol=1e-12, atol=1e-12 * np.max(traced))


@pytest.mark.parametrize("st", [STRUCTURES[0], STRUCTURES[-1]] + MORE[:3], ids=structure_id)
def test_the_host_model_equals_the_traced_one_in_float32(st):
    a, host, traced = _both(st, np.float32)
    assert host.dtype == np.float32 and np.all(np.isfinite(host))
    np.testing.assert_allclose(host, traced, rtol=2e-5, atol=1e-5 * np.max(traced))


def test_the_pairs_layout_on_the_host_gathers_each_sample_s_band():
    st = STRUCTURES[5]
    a = _angles(np.float64)
    geom = geometry_from_angles_deg(a[:, 0], a[:, 1], a[:, 2], a[:, 3], xp=np)
    params = jax.tree.map(np.asarray, make_params(st))
    band = np.arange(len(a)) % 3
    with np.errstate(all="ignore"):
        grid, pairs = brdf(st, params, geom, xp=np), brdf_pairs(st, params, geom, band, xp=np)
    np.testing.assert_array_equal(pairs, grid[np.arange(len(a)), band])


def test_the_median_error_of_a_candidate_makes_no_program(compilations):
    """The data-chosen default judges every candidate by its median relative error on the screen
    and on held-out pairs; on the host, that costs no program per structure (each was 0.1–1 s of
    compiling on a first run), and it is the traced model's median."""
    st = ctfit.Structure(lobes=2, family="plastic", diffuse="transmitted", geometry="smith")
    truth = ctfit.Material(st, ctfit.Params(s=np.asarray(0.4), m=np.array([0.1, 0.3]), w=np.array([0.5, 0.5]), n=np.full(3, 1.5),
                                            rd=np.array([0.1, 0.2, 0.05])), channels=("R", "G", "B"))
    data = ctfit.simulate(truth, n_pairs=5000, noise=0.02, seed=4)  # more pairs than one block of HELDOUT_PAIRS
    res = types.SimpleNamespace(material=truth)  # what the error reads of a fit
    before = len(compilations)
    err = structure_selection.model_median_error(res, data)
    assert len(compilations) == before
    f = np.asarray(ctfit.evaluate(truth, data))
    y = np.asarray(data.brdf)
    expected = np.median(np.abs(f[y > 0] - y[y > 0]) / y[y > 0])
    assert err == pytest.approx(expected, rel=1e-9) and 0.005 < err < 0.05


def test_one_sample_near_zero_does_not_make_a_candidates_median_infinite():
    """One held-out brdf of 1e-310 where the model gives 53 sr⁻¹: its relative error overflows to
    ∞, and that made every candidate's median ∞, so the structure was chosen by the tie-break
    (copper, `ctfit simulate configs/copper.toml --samples 200` with one such value: one lobe, where
    the clean data chooses two). The median is the other samples'; a model that is not finite
    somewhere is still no candidate (∞)."""
    truth = ctfit.Material(ctfit.Structure(lobes=1), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.6, 0.9])),
                           wavelength_nm=np.array([450.0, 650.0]))
    data = ctfit.simulate(truth, n_pairs=400, noise=0.02, seed=1)
    y = np.array(data.brdf)
    clean = structure_selection.model_median_error(types.SimpleNamespace(material=truth), data)
    y[int(np.argmax(y))] = 1e-310
    stray = structure_selection.model_median_error(types.SimpleNamespace(material=truth), data.replace(brdf=y))
    assert np.isfinite(stray) and stray == pytest.approx(clean, rel=0.02)
    broken = dataclasses.replace(truth, params=dataclasses.replace(truth.params, f0=np.array([np.nan, 0.9])))
    assert structure_selection.model_median_error(types.SimpleNamespace(material=broken), data) == np.inf
