"""The quality section's median and 90th percentile (one partition) are NumPy's ``np.median`` and
``np.quantile(x, 0.9)`` to the last bit, for any size, ties and range of values."""

from __future__ import annotations

import hypothesis.strategies as st
import numpy as np
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
