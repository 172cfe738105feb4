"""The seeds' sums (``ctfit/_fitting/starts.py``) from the model's linearity in S: the specular part
at a grid point is S there times ∂R/∂S, the diffuse part the model at S = 0 (Eq. 2). Checked
against the model's two parts evaluated whole at every grid point, for every kind of structure
and layout, and the seeds' scores formed for all grid points at once against one at a time."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ctfit
from ctfit._fitting import starts
from ctfit._fitting.chunked_fit import ROWS, chunk_problems
from ctfit._fitting.least_squares import prepare_fit
from ctfit._fitting.problem import band_sum, model_parts

STRUCTURES = [
    ctfit.Structure(lobes=2, diffuse="F0/pi"),
    ctfit.Structure(lobes=1),
    ctfit.Structure(lobes=1, fresnel="conductor"),
    ctfit.Structure(family="plastic", diffuse="transmitted"),
    ctfit.Structure(lobes=2, diffuse="spectrum"),
    ctfit.Structure(lobes=3, diffuse="constant", geometry="smith"),
]


def _whole_model_sums(part, u0: dict, grid):
    """The sums of :func:`~ctfit._fitting.starts.grid_sums` from the model's two parts evaluated
    whole at every grid point (:func:`~ctfit._fitting.problem.model_parts`)."""

    def one(log_m):
        a, b = model_parts(part, dict(u0, m=log_m))
        w, y = part.mask / jnp.maximum(jnp.abs(part.y), part.floor) ** 2, part.y
        sums = band_sum(part, jnp.stack([w * a * y, w * b * y, w * y * y, w * a * a, w * a * b, w * b * b], axis=-1))
        return sums[..., :3], sums[..., 3:]

    return jax.lax.map(one, grid)


def _data(layout: str) -> ctfit.Measurement:
    """Three bands of a two-lobe metal with a diffuse part: direction pairs × bands (the grid
    layout) or a third of those samples (each its own pair: the pairs layout)."""
    gold = ctfit.Material(ctfit.Structure(lobes=2, diffuse="F0/pi"),
                          ctfit.Params(s=np.asarray(0.7), m=np.array([0.1, 0.35]), w=np.array([0.6, 0.4]), f0=np.array([0.9, 0.6, 0.4])),
                          wavelength_nm=np.array([450.0, 550.0, 650.0]))
    data = ctfit.simulate(gold, n_pairs=900, noise=0.02, seed=7)
    if layout == "grid":
        return data
    keep = np.random.default_rng(8).permutation(len(data))[: len(data) // 3]
    return data.replace(sigma=None, **{c: np.asarray(getattr(data, c))[keep] for c in ("theta_i", "phi_i", "theta_o", "phi_o", "band", "brdf")})


@pytest.mark.parametrize("structure", STRUCTURES, ids=ctfit.structure_label)
@pytest.mark.parametrize("layout", ["grid", "pairs"])
def test_the_seeds_sums_are_those_of_the_model_s_two_parts(structure, layout):
    prep = prepare_fit(_data(layout), structure, start=None, fixed=(), loss="relative", dtype=jnp.float64, starts=3, chunk=ROWS)
    assert prep.problem.spec.grid == (layout == "grid") and prep.grid is not None
    (part,) = chunk_problems(prep.problem, limit=1)  # a chunk: the fit's kernel
    u0 = dict(prep.u0, s=jnp.asarray(0.6)) if "s" in prep.u0 else prep.u0  # s away from ½: the parts' weights differ
    got = eqx.filter_jit(starts.grid_sums)(part, u0, prep.grid)
    want = eqx.filter_jit(_whole_model_sums)(part, u0, prep.grid)
    for g, w in zip(got, want):
        assert g.shape == w.shape == (prep.grid.shape[0], part.fixed_bands, 3)
        np.testing.assert_allclose(g, w, rtol=1e-11, atol=1e-13 * float(np.max(np.abs(w))))
    assert float(np.max(np.asarray(got[1])[..., 0])) > 0  # a specular part that reaches the samples


@pytest.mark.parametrize("layout", ["grid", "pairs"])
def test_scores_for_all_grid_points_at_once_are_those_of_one_at_a_time(layout, monkeypatch):
    """Above :data:`~ctfit._fitting.starts.VECTOR_CELLS` the scores are formed one grid point at a
    time (memory of the data alone); both ways give the same scores, scales and amplitudes."""
    prep = prepare_fit(_data(layout), ctfit.Structure(lobes=2, diffuse="F0/pi"), start=None, fixed=(), loss="relative", dtype=jnp.float64, starts=3)
    at_once = eqx.filter_jit(starts._grid_scores)(prep.problem, prep.u0, prep.grid)
    monkeypatch.setattr(starts, "VECTOR_CELLS", 0)
    one_by_one = eqx.filter_jit(starts._grid_scores)(prep.problem, prep.u0, prep.grid)
    for a, b in zip(at_once, one_by_one):
        np.testing.assert_allclose(a, b, rtol=1e-11, atol=1e-13 * float(np.max(np.abs(b))))
    assert np.all(np.isfinite(np.asarray(at_once[0])))
