"""``fit_texels``: one goniometer geometry, many texels' values, fitted a chunk at a time."""

import jax.numpy as jnp
import numpy as np
import pytest

import ctfit

RGB = ("R", "G", "B")
ST = ctfit.Structure(lobes=1, diffuse="F0/pi")
N_TEXELS = 64


def texel_material(s, m, f0):
    return ctfit.Material(ST, ctfit.Params(s=np.asarray(s), m=np.array([m]), w=np.array([1.0]), f0=np.asarray(f0)), channels=RGB)


@pytest.fixture(scope="module")
def texels():
    """67 direction pairs × 3 channels (201 samples); 64 texels of known s, m, F0 with 1 % noise."""
    geometry = ctfit.simulate(texel_material(0.9, 0.2, (0.9, 0.7, 0.5)), 67, seed=1)
    rng = np.random.default_rng(7)
    truth = dict(s=rng.uniform(0.6, 0.95, N_TEXELS), m=rng.uniform(0.08, 0.5, N_TEXELS), f0=rng.uniform(0.2, 0.95, (N_TEXELS, 3)))
    values = np.stack([np.asarray(ctfit.evaluate(texel_material(truth["s"][t], truth["m"][t], truth["f0"][t]), geometry)) for t in range(N_TEXELS)])
    return geometry, values * (1 + 0.01 * rng.standard_normal(values.shape)), truth


def test_texels_recover_their_parameters_chunk_by_chunk(texels, tmp_path):
    geometry, values, truth = texels
    stored = np.lib.format.open_memmap(tmp_path / "values.npy", mode="w+", shape=values.shape)  # read a chunk at a time
    stored[:] = values
    res = ctfit.fit_texels(geometry, stored, ST, chunk=24)  # 3 chunks, the last one filled up
    assert len(res) == N_TEXELS and res.converged.all()
    assert res.params.m.shape == (N_TEXELS, 1) and res.params.f0.shape == (N_TEXELS, 3) and res.params.s.shape == (N_TEXELS,)
    np.testing.assert_allclose(res.params.m[:, 0], truth["m"], rtol=0.02)
    np.testing.assert_allclose(res.params.f0, truth["f0"], atol=0.03)
    np.testing.assert_allclose(res.params.s, truth["s"], atol=0.03)
    assert np.all(res.stats["rel_rmse"] < 0.015) and np.median(res.stats["rel_rmse"]) == pytest.approx(0.01, rel=0.2)  # the 1 % noise
    assert res.stats["texels_per_s"] > 0 and res.stats["dtype"] == "float64"
    np.testing.assert_allclose(res.params.n, np.asarray(ctfit.n_from_f0(res.params.f0)), rtol=1e-12)
    for t in (5, N_TEXELS - 1):  # one of the first chunk, the last texel (last chunk)
        alone = res.fit_result(t)
        assert alone.converged
        np.testing.assert_allclose(alone.material.params.m, res.params.m[t], rtol=1e-6)
        np.testing.assert_allclose(alone.material.params.f0, res.params.f0[t], rtol=1e-6)
        assert alone.stats["cost"] == pytest.approx(res.stats["cost"][t], rel=1e-8)
        assert alone.stats["rel_rmse"] == pytest.approx(res.stats["rel_rmse"][t], rel=1e-6)
        assert res.material(t).params.m == pytest.approx(res.params.m[t])


def test_fit_batch_with_values_is_the_texel_fit(texels):
    geometry, values, truth = texels
    res = ctfit.fit_batch([geometry], ST, values=values[:8], dtype=jnp.float32, width=8)  # all 8 side by side (vmapped)
    assert isinstance(res, ctfit.TexelFits) and len(res) == 8 and res.stats["dtype"] == "float32"
    assert res.params.m.dtype == np.float32
    np.testing.assert_allclose(res.params.m[:, 0], truth["m"][:8], rtol=0.03)
    np.testing.assert_allclose(res.params.f0, truth["f0"][:8], atol=0.03)


def test_texels_that_cannot_be_fitted_are_recorded_and_the_rest_fitted(texels):
    """A NaN, an inf, a negative value, all zeros or values out of float64's range: that texel's
    parameters are NaN, converged False and its status says why; every other texel is fitted as
    it would be alone."""
    from ctfit._fitting.texels import TEXEL_STATUS

    geometry, values, _ = texels
    with pytest.raises(ValueError, match=r"values must have shape \(texels, 201\)"):
        ctfit.fit_texels(geometry, values[:, :-1], ST)
    bad = values[:10].copy()
    bad[7, 3] = np.nan
    bad[1, 0] = np.inf
    bad[2, 5] = -1.0
    bad[9] = 0.0
    bad[4] = 1e300
    fits = ctfit.fit_texels(geometry, bad, ST, chunk=4)
    status = [TEXEL_STATUS[c] for c in fits.stats["status"]]
    assert status == ["fitted", "non_finite_values", "negative_values", "fitted", "out_of_range", "fitted", "fitted",
                      "non_finite_values", "fitted", "all_zero"]
    skipped = fits.stats["status"] != 0
    assert np.isnan(fits.params.m[skipped]).all() and np.isnan(fits.params.f0[skipped]).all() and np.isnan(fits.stats["cost"][skipped]).all()
    assert not fits.converged[skipped].any() and fits.converged[~skipped].all()
    alone = ctfit.fit_texels(geometry, values[:10][~skipped], ST, chunk=4)
    np.testing.assert_allclose(fits.params.m[~skipped], alone.params.m, rtol=1e-8)
    with pytest.raises(ValueError, match="loss 'sigma'"):
        ctfit.fit_texels(geometry, values, ST, loss="sigma")


def test_the_callers_values_are_never_written_and_a_read_only_map_is_fitted(texels, tmp_path):
    """A texel that cannot be fitted is solved as a copy of a good one in ctfit's own block: the
    caller's array, and through a writable memory map their .npy file, keep their values (they
    got the good texel's); a read-only map (``mmap_mode="r"``, the docs' example) is fitted (it
    raised "assignment destination is read-only")."""
    geometry, values, _ = texels
    bad = values[:6].copy()
    bad[1, 0] = np.nan
    np.save(tmp_path / "texels.npy", bad)
    writable = np.load(tmp_path / "texels.npy", mmap_mode="r+")
    ctfit.fit_texels(geometry, writable, ST, chunk=4)
    writable.flush()
    del writable
    np.testing.assert_array_equal(np.load(tmp_path / "texels.npy"), bad)
    in_memory = bad.copy()
    ctfit.fit_texels(geometry, in_memory, ST, chunk=4)
    np.testing.assert_array_equal(in_memory, bad)
    np.save(tmp_path / "good.npy", values[:6])
    fits = ctfit.fit_texels(geometry, np.load(tmp_path / "good.npy", mmap_mode="r"), ST, chunk=4)
    assert fits.converged.all()


def test_a_band_no_sample_has_is_refused(texels):
    """A geometry of R, G, B whose samples are all R or G: B's F0 is not determined, and every
    texel reported the start's F0 = 0.005 there, converged. Refused, naming the band (the single
    fit warns that the data does not determine F0)."""
    geometry, values, _ = texels
    rg = geometry.band < 2
    two = geometry.replace(theta_i=geometry.theta_i[rg], phi_i=geometry.phi_i[rg], theta_o=geometry.theta_o[rg], phi_o=geometry.phi_o[rg],
                           band=geometry.band[rg], brdf=geometry.brdf[rg])
    assert two.band_labels == ["R", "G", "B"]
    with pytest.raises(ValueError, match=r"no sample has band B: its parameters cannot be fitted"):
        ctfit.fit_texels(two, values[:4, rg], ST, dtype=jnp.float64)
    with pytest.raises(ValueError, match=r"no sample has band B"):
        ctfit.fit_batch(two, ST, values=values[:4, rg], dtype=jnp.float64)


def test_values_that_are_not_real_numbers_are_refused_and_a_list_is_taken(texels):
    """Complex values were fitted without their imaginary part, strings of numbers as numbers,
    and a list of rows refused as 'shape None'."""
    geometry, values, _ = texels
    for bad, name in ((values[:2] + 1j, "complex128"), (values[:2].astype(str), "str")):
        with pytest.raises(ValueError, match=f"values must be real numbers, got an array of {name}"):
            ctfit.fit_texels(geometry, bad, ST, dtype=jnp.float64)
    from_list = ctfit.fit_texels(geometry, values[:2].tolist(), ST, dtype=jnp.float64)
    np.testing.assert_array_equal(from_list.params.m, ctfit.fit_texels(geometry, values[:2], ST, dtype=jnp.float64).params.m)
