"""The quality section's median and 90th percentile (one partition) are NumPy's ``np.median`` and
``np.quantile(x, 0.9)`` to the last bit, for any size, ties and range of values."""

from __future__ import annotations

import hypothesis.strategies as st
import numpy as np
import pytest
from hypothesis import given, settings

from ctfit._fitting.quality import _summary, quality_in_regions

finite = st.floats(min_value=0, max_value=1e300, allow_nan=False, allow_infinity=False, width=64)


@settings(max_examples=300, deadline=None)
@given(st.lists(finite | st.sampled_from([0.0, 0.5, 1.0]), min_size=1, max_size=300))
def test_summary_is_numpys_median_and_quantile(values):
    err = np.array(values)
    got = _summary(err.copy())
    assert got["samples"] == err.size
    assert got["median_relative_error"] == float(np.median(err))
    assert got["p90_relative_error"] == float(np.quantile(err, 0.9))


def test_summary_at_every_small_size_and_a_large_one():
    rng = np.random.default_rng(3)
    for n in [*range(1, 40), 2_000, 2_001, 65_537]:
        err = np.exp(rng.normal(0, 5, n))
        got = _summary(err.copy())
        assert (got["median_relative_error"], got["p90_relative_error"]) == (float(np.median(err)), float(np.quantile(err, 0.9))), n


def test_an_empty_region_has_no_figures_and_nan_is_left_out():
    err = np.array([0.1, np.nan, 0.3, 0.2])
    q = quality_in_regions(err, np.array([True, False, False, False]), np.zeros(4, bool), None)
    assert q["median_relative_error"] == 0.2 and q["samples"] == 3
    assert q["regions"]["peak"] == {"samples": 0, "median_relative_error": None, "p90_relative_error": None}
    assert q["regions"]["grazing"]["median_relative_error"] == 0.1


def test_a_fits_quality_is_that_of_its_material_even_far_below_the_floor():
    """Samples of 10⁻¹⁰³ (a narrow lobe far from its peak) have float32 relative residuals of 0:
    their errors come from the model, so the fit's quality is ``fit_quality`` of its material (it
    read 4.5 % where it is 4.8 %)."""
    import jax

    import ctfit

    with jax.enable_x64(True):
        metal = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.6, 0.7, 0.95])),
                               wavelength_nm=np.array([450.0, 550.0, 650.0]))
        data = ctfit.simulate(metal, n_pairs=300, noise=0.05, seed=3)
        assert np.min(data.brdf[data.brdf > 0]) < 1e-60  # residuals below float32's range
        res = ctfit.fit(data, metal.structure, loss="relative")
        want = ctfit.fit_quality(res.material, data)
    got = res.stats["quality"]
    for name in ("median_relative_error", "p90_relative_error"):
        assert got[name] == pytest.approx(want[name], rel=1e-6)
        for region in want["regions"]:
            assert got["regions"][region][name] == pytest.approx(want["regions"][region][name], rel=1e-6)
