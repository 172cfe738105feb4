"""The fit-quality figure where the data gives each sample's uncertainty σ: a value below its σ
is judged by |f − y|/σ, not |f − y|/y (a Beckmann tail at 10⁻¹³⁷ sr⁻¹ is known only as 0 ± σ)."""

import numpy as np

import ctfit
from ctfit._fitting.structure_selection import model_median_error

from conftest import ROOT


def _copper_data():
    return ctfit.simulate(ctfit.load_material(ROOT / "configs" / "copper.toml"), 200, noise=0.02, seed=0)


def test_values_below_their_uncertainty_are_judged_by_it():
    copper = ctfit.load_material(ROOT / "configs" / "copper.toml")
    data = _copper_data()
    y, sigma = np.asarray(data.brdf), np.asarray(data.sigma)
    assert np.mean(y < 1e-10) > 0.1 and np.all(sigma >= 1e-6)  # a tail far below the σ floor
    q = ctfit.fit_quality(copper, data)  # the truth: every sample within its noise
    assert q["below_sigma"] == int(np.sum(y < sigma))
    assert q["median_relative_error"] < 0.03 and q["p90_relative_error"] < 0.1, q
    plain = ctfit.fit_quality(copper, data.replace(sigma=None))  # no σ: the raw ratio, and no count
    assert "below_sigma" not in plain


def test_a_fit_of_data_with_a_deep_tail_is_not_called_unrepresented():
    """Before: the data-chosen fit of a simulated copper read "a tenth of the samples are off by
    98803562% or more" and "the Cook–Torrance model does not represent this material"."""
    res = ctfit.fit(_copper_data())
    assert res.converged
    assert not [w for w in res.warnings if w.kind == "not_represented"], res.warnings
    q = res.stats["quality"]
    # 2 % noise, and the F0 Fresnel against the conductor's data: 4 %
    assert q["below_sigma"] > 0 and q["median_relative_error"] < 0.05 and q["p90_relative_error"] < 0.2, q
    for row in res.stats["structure_choice"]:
        if row["structure"].startswith("metal") and row["heldout_median_relative_error"] is not None:
            assert row["heldout_median_relative_error"] < 0.045, row


def test_the_choice_s_held_out_error_is_floored_too():
    copper = ctfit.load_material(ROOT / "configs" / "copper.toml")
    data = _copper_data()
    res = ctfit.fit(data, ctfit.Structure(lobes=1, diffuse=None))
    with_sigma = model_median_error(res, data)
    without = model_median_error(res, data.replace(sigma=None))
    assert with_sigma < 0.045 < without, (with_sigma, without)  # 3.8 % against 5.6 %
    assert copper.structure.lobes == 1
