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
from ctfit._fitting.coordinates import weight_coordinates
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


def _whole_model_sums(part, u0: dict, values):
    """The sums of :func:`~ctfit._fitting.starts.grid_sums` from the model's two parts evaluated
    whole at every grid point (:func:`~ctfit._fitting.starts.m_combinations` of ``values``) and
    split of the lobes' weights (:func:`~ctfit._fitting.starts.splits_scored`; the start's alone
    where the weights are not free) (:func:`~ctfit._fitting.problem.model_parts`)."""
    grid = values[jnp.asarray(starts.m_combinations(values.shape[0], u0["m"].shape[0]))]
    splits = starts.splits_scored(u0)
    ws = [None] if splits is None else [weight_coordinates(jnp.asarray(w), part.spec.space) for w in splits]

    def one(log_m, w):
        a, b = model_parts(part, dict(u0, m=log_m) if w is None else dict(u0, m=log_m, w=w))
        wgt, y = part.mask / jnp.maximum(jnp.abs(part.y), part.floor) ** 2, part.y
        sums = band_sum(part, jnp.stack([wgt * a * y, wgt * b * y, wgt * y * y, wgt * a * a, wgt * a * b, wgt * b * b], axis=-1))
        return sums[..., :3], sums[..., 3:]

    per_split = [jax.lax.map(lambda log_m: one(log_m, w), grid) for w in ws]  # each (G, bands, 3)
    return tuple(jnp.stack([s[i] for s in per_split], axis=1) for i in range(2))


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
    splits = starts.splits_scored(u0)
    points = starts.m_combinations(prep.grid.shape[0], u0["m"].shape[0]).shape[0]
    assert (splits is not None) == (structure.lobes > 1)  # weights free in a fit of several lobes
    for g, w in zip(got, want):
        assert g.shape == w.shape == (points, 1 if splits is None else splits.shape[0], part.fixed_bands, 3)
        np.testing.assert_allclose(g, w, rtol=1e-11, atol=1e-13 * float(np.max(np.abs(w))))
    assert float(np.max(np.asarray(got[1])[..., 0])) > 0  # a specular part that reaches the samples


@pytest.mark.parametrize("layout", ["grid", "pairs"])
def test_scores_for_all_grid_points_at_once_are_those_of_one_at_a_time(layout, monkeypatch):
    """Above :data:`~ctfit._fitting.starts.VECTOR_CELLS` the scores are formed one grid point at a
    time (memory of the data alone); both ways give the same scores, scales and amplitudes."""
    prep = prepare_fit(_data(layout), ctfit.Structure(lobes=2, diffuse="F0/pi"), start=None, fixed=(), loss="relative", dtype=jnp.float64, starts=3)
    at_once = eqx.filter_jit(lambda p, u, g: starts._grid_scores(p, u, g))(prep.problem, prep.u0, prep.grid)
    monkeypatch.setattr(starts, "VECTOR_CELLS", 0)
    # A new function, traced again (the same one would be taken from the first call's cache).
    one_by_one = eqx.filter_jit(lambda p, u, g: starts._grid_scores(p, u, g))(prep.problem, prep.u0, prep.grid)
    for a, b in zip(at_once, one_by_one):
        np.testing.assert_allclose(a, b, rtol=1e-11, atol=1e-13 * float(np.max(np.abs(b))))
    assert np.all(np.isfinite(np.asarray(at_once[0])))


# --- the lobes' weights in the scores ------------------------------------------------------------


@pytest.mark.parametrize("space", ["box", "unconstrained"])
def test_weight_coordinates_invert_the_lobe_weights(space):
    from ctfit._fitting.coordinates import lobe_weights, stick_fractions

    rng = np.random.default_rng(0)
    for lobes in (2, 3, 5):
        w = rng.dirichlet(np.ones(lobes), size=4)
        u = weight_coordinates(jnp.asarray(w), space)
        back = np.stack([np.asarray(lobe_weights(row, space)) for row in u])
        np.testing.assert_allclose(back, w, rtol=1e-12, atol=1e-15)
        if space == "box":
            np.testing.assert_allclose(u, np.stack([stick_fractions(row) for row in w]), rtol=1e-12)


def test_the_splits_of_the_lobes_weights():
    from ctfit._model import MAX_LOBES

    for lobes in range(1, MAX_LOBES + 1):
        splits = starts.lobe_weight_grid(lobes)
        assert splits.shape[1] == lobes and np.all(splits > 0)
        np.testing.assert_allclose(splits.sum(axis=1), 1.0, rtol=1e-15)
        assert any(np.allclose(row, 1.0 / lobes) for row in splits)  # the start's equal split among them
        assert len({tuple(row) for row in splits}) == len(splits)
    assert starts.lobe_weight_grid(2).shape == (7, 2) and starts.lobe_weight_grid(3).shape == (10, 3)


def test_with_the_weights_held_the_grid_is_scored_at_those_weights_alone():
    data = _data("pairs")
    structure = ctfit.Structure(lobes=2, diffuse="F0/pi")
    start = ctfit.Params(s=np.asarray(0.5), m=np.array([0.1, 0.3]), w=np.array([0.8, 0.2]), f0=np.full(3, 0.5))
    prep = prepare_fit(data, structure, start=start, fixed=("w",), loss="relative", dtype=jnp.float64, starts=3, chunk=ROWS)
    assert "w" not in prep.u0 and starts.splits_scored(prep.u0) is None
    (part,) = chunk_problems(prep.problem, limit=1)
    got = eqx.filter_jit(starts.grid_sums)(part, prep.u0, prep.grid)
    want = eqx.filter_jit(_whole_model_sums)(part, prep.u0, prep.grid)  # the model's own weights: the held ones
    for g, w in zip(got, want):
        assert g.shape[1] == 1
        np.testing.assert_allclose(g, w, rtol=1e-11, atol=1e-13 * float(np.max(np.abs(w))))


def test_no_seed_of_two_lobes_is_a_lobe_too_narrow_to_reach_the_samples():
    """Scored at the start's equal weights alone, a pair with a lobe too narrow to reach any
    sample scored as its other lobe alone and took most seeds here (m = 0.01 or 0.017 beside
    0.27); their solves then spent 15–31 steps dragging that lobe out. Scored at every split,
    the seeds are pairs that fit both lobes, each with its best split."""
    truth = ctfit.Material(ctfit.Structure(lobes=2, diffuse="F0/pi"),
                           ctfit.Params(s=np.asarray(0.9), m=np.array([0.2, 0.4]), w=np.array([0.6, 0.4]), f0=np.linspace(0.5, 0.95, 31)),
                           wavelength_nm=np.linspace(400.0, 700.0, 31))
    grid = ctfit.simulate(truth, n_pairs=400, noise=0.02, seed=0)
    keep = np.random.default_rng(1).choice(len(grid), 2000, replace=False)  # each sample its own pair and band
    data = grid.replace(sigma=None, **{c: np.asarray(getattr(grid, c))[keep] for c in ("theta_i", "phi_i", "theta_o", "phi_o", "band", "brdf")})
    seeds = ctfit.seed_params(data, truth.structure, starts=3, loss="relative")
    for p in seeds:
        assert np.min(p.m) > 0.05, p.m
        assert np.isclose(np.sum(p.w), 1.0)
    assert len({tuple(np.round(p.w, 6)) for p in seeds} | {(0.5, 0.5)}) > 1  # weights from the scores, not only the start's


def test_the_sums_over_many_bands_are_those_of_few(monkeypatch):
    """Above :data:`~ctfit._fitting.starts.PRODUCT_BANDS` bands the seeds' sums over each band's
    samples are a scatter instead of a product with the bands' indicators: the same sums."""
    prep = prepare_fit(_data("pairs"), ctfit.Structure(lobes=2, diffuse="F0/pi"), start=None, fixed=(), loss="relative", dtype=jnp.float64, starts=3)
    product = eqx.filter_jit(lambda p, u, g: starts.grid_sums(p, u, g))(prep.problem, prep.u0, prep.grid)
    monkeypatch.setattr(starts, "PRODUCT_BANDS", 0)
    scatter = eqx.filter_jit(lambda p, u, g: starts.grid_sums(p, u, g))(prep.problem, prep.u0, prep.grid)  # traced again
    for a, b in zip(product, scatter):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-14 * float(np.max(np.abs(b))))


@pytest.mark.parametrize("structure", STRUCTURES, ids=ctfit.structure_label)
@pytest.mark.parametrize("dtype", [jnp.float64, jnp.float32])
def test_the_seeds_chosen_on_the_host_are_those_chosen_in_a_program(structure, dtype):
    """The chunked fit chooses its seeds from the sums in NumPy (``chunked_fit._seed_choice``: no
    program to compile); the one-program fit in its program. Both give the same seeds, of the
    same dtype: points, weights, F0 or n and k, s."""
    from ctfit._fitting import chunked_fit
    from ctfit._fitting.seeded_solve import flat_bounds

    prep = prepare_fit(_data("grid"), structure, start=None, fixed=(), loss="relative", dtype=dtype, starts=3, chunk=ROWS)
    parts = chunk_problems(prep.problem)
    u0 = dict(prep.u0, s=jnp.asarray(0.6, dtype)) if "s" in prep.u0 else prep.u0
    sums = [eqx.filter_jit(starts.grid_sums)(part, u0, prep.grid) for part in parts]
    num, den = (sum(s[i] for s in sums) for i in (0, 1))

    def in_program(part, u, grid, num, den):
        costs, scales, amplitudes, split = starts.best_splits(num, den)
        return starts.seeds_from_scores(part, u, 3, grid, costs, scales, True, amplitudes, split)

    want = jax.device_get(eqx.filter_jit(in_program)(parts[0], u0, prep.grid, num, den))
    host_u0, host_grid = jax.device_get((u0, prep.grid))
    got = chunked_fit._seed_choice(parts[0], host_u0, 3, host_grid, *jax.device_get((num, den)), keep_start=True)
    flat = np.concatenate([np.reshape(want[k], (want[k].shape[0], -1)) for k in sorted(want)], axis=1)
    assert got["flat"].dtype == flat.dtype == np.dtype(dtype) and got["flat"].shape == flat.shape == (4, flat.shape[1])
    np.testing.assert_allclose(got["flat"], flat, rtol=1e-12 if dtype == jnp.float64 else 1e-5, atol=1e-6 if dtype == jnp.float32 else 0)
    lower, upper = jax.device_get(flat_bounds(parts[0], u0))
    np.testing.assert_array_equal(got["lower"], lower)
    np.testing.assert_array_equal(got["upper"], upper)
