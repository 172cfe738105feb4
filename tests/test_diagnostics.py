"""Residual-structure warnings: real retro-reflective data is flagged, a good fit is not."""

import numpy as np
import pytest

import ctfit
from ctfit import DataWarning, residual_structure

from conftest import MEASURED


def test_retro_reflective_tape_is_flagged():
    with pytest.warns(DataWarning, match="dropped"):
        data = ctfit.read_measurement(MEASURED / "retro-gray-tape.dat", param_out="INV_STERADIAN_COSINE_FACTOR")
    # The best single-lobe Cook–Torrance surface for this tape (from `ctfit fit`): its residuals
    # near L = V are what the model cannot represent.
    mat = ctfit.Material(
        ctfit.Structure(lobes=1, diffuse="F0/pi"),
        ctfit.Params(s=np.asarray(0.484), m=np.array([0.161]), w=np.array([1.0]), f0=np.array([0.351])),
        wavelength_nm=data.wavelength_nm,
    )
    notes = residual_structure(data, ctfit.evaluate(mat, data))
    assert any("retro-reflection lobe" in n for n in notes), notes


def test_model_fitting_its_own_noisy_data_is_not_flagged():
    st = ctfit.Structure(lobes=2)
    mat = ctfit.Material(st, ctfit.Params(m=np.array([0.1, 0.3]), w=np.array([0.5, 0.5]), f0=np.full(4, 0.8)), wavelength_nm=np.linspace(400, 700, 4))
    data = ctfit.simulate(mat, 2000, noise=0.05, seed=1)
    assert residual_structure(data, ctfit.evaluate(mat, data)) == []


def test_systematic_offset_is_flagged_with_direction():
    st = ctfit.Structure(lobes=1)
    mat = ctfit.Material(st, ctfit.Params(m=np.array([0.2]), w=np.array([1.0]), f0=np.full(2, 0.5)), wavelength_nm=np.array([450.0, 650.0]))
    data = ctfit.simulate(mat, 1000, noise=0.01, seed=2)
    model = ctfit.evaluate(mat, data) * 1.3
    notes = residual_structure(data, model)
    assert notes and all("above the data" in n for n in notes)


def test_fit_of_the_retro_reflective_tape_warns_in_its_result():
    with pytest.warns(DataWarning, match="dropped"):
        data = ctfit.read_measurement(MEASURED / "retro-gray-tape.dat", param_out="INV_STERADIAN_COSINE_FACTOR")
    res = ctfit.fit(data, ctfit.Structure(lobes=1, diffuse="F0/pi"), starts=1)
    assert any("retro-reflection lobe" in w for w in res.warnings), res.warnings


def test_the_last_bin_is_labelled_with_its_real_end():
    """A bias near grazing is reported for "[85°, 90°]", not an internal bin edge (90.0001°)."""
    st = ctfit.Structure(lobes=1)
    mat = ctfit.Material(st, ctfit.Params(m=np.array([0.3]), w=np.array([1.0]), f0=np.full(2, 0.5)), wavelength_nm=np.array([450.0, 650.0]))
    data = ctfit.simulate(mat, 3000, noise=0.01, seed=3)
    model = np.asarray(ctfit.evaluate(mat, data)).copy()
    grazing = np.maximum(data.theta_i, data.theta_o) >= 85
    assert grazing.sum() >= 20
    model[grazing] *= 0.6
    notes = [n for n in residual_structure(data, model) if "max(θ_i, θ_o)" in n]
    assert notes and "[85°, 90°]" in notes[0] and "90.0001" not in notes[0]


def test_grid_and_per_sample_residuals_give_the_same_warnings():
    """The fit's route (relative residuals on its (pair, band) grid with a mask) and the
    per-sample route find the same bins, means and counts."""
    from ctfit._fitting.diagnostics import relative_residual_structure

    st = ctfit.Structure(lobes=1)
    mat = ctfit.Material(st, ctfit.Params(m=np.array([0.3]), w=np.array([1.0]), f0=np.full(3, 0.5)), wavelength_nm=np.array([450.0, 550.0, 650.0]))
    data = ctfit.simulate(mat, 3000, noise=0.01, seed=4)
    model = np.asarray(ctfit.evaluate(mat, data)).copy()
    model[np.maximum(data.theta_i, data.theta_o) >= 60] *= 1.4
    model[data.theta_i < 20] *= 0.8
    notes = residual_structure(data, model)
    assert len(notes) >= 2
    pairs, index = data.directions()
    rel = np.zeros((len(pairs) + 5, 3))  # padded rows, as the fit's layout has them
    mask = np.zeros(rel.shape, bool)
    floor = 1e-3 * data.brdf.max()
    rel[index, data.band] = (model - data.brdf) / np.maximum(data.brdf, floor)
    mask[index, data.band] = True
    missing = (index[:7], data.band[:7])  # a few cells not measured
    keep = np.ones(len(data), bool)
    keep[:7] = False
    rel[missing], mask[missing] = 99.0, False
    sub = data.replace(**{k: getattr(data, k)[keep] for k in ("theta_i", "phi_i", "theta_o", "phi_o", "band", "brdf", "sigma")})
    expected = residual_structure(sub, model[keep], floor=floor)
    assert relative_residual_structure(pairs, rel[: len(pairs)], mask=mask[: len(pairs)]) == expected


def _with_zeros(data, share: float, seed: int):
    """``data`` with ``share`` of its values set to exactly 0 (values not measured, written as 0)."""
    zero = np.random.default_rng(seed).random(len(data)) < share
    return data.replace(brdf=np.where(zero, 0.0, data.brdf)), zero


def _one_band_a_pair(data, seed: int):
    """One sample of each direction pair, of a band drawn at random: scattered samples (the fit's
    per-sample layout, not its grid of pairs × bands)."""
    _, index = data.directions()
    band = np.random.default_rng(seed).integers(0, data.n_bands, index.max() + 1)
    keep = data.band == band[index]
    return data.replace(**{k: getattr(data, k)[keep] for k in ("theta_i", "phi_i", "theta_o", "phi_o", "band", "brdf")})


@pytest.mark.parametrize("layout", ["grid", "samples"])
def test_values_not_measured_written_as_zero_are_one_warning_not_every_bin(layout):
    """A tenth of the values exactly 0 (not measured, written as 0), the rest from the model
    itself: the fit is the model's to 0.5 %, and says so. The zeros are one warning, with
    their count and the model's value there; they are left out of the angular bins, whose means
    they made read "the model is 1331 % above the data" (and 14780 %, 2605 %) for a perfect fit."""
    mat = ctfit.Material(ctfit.Structure(lobes=1), ctfit.Params(s=np.asarray(0.4), m=np.array([0.3]), w=np.ones(1), f0=np.full(3, 0.05)),
                         wavelength_nm=np.array([450.0, 550.0, 650.0]))
    data = ctfit.simulate(mat, 2000, seed=1)
    if layout == "samples":
        data = _one_band_a_pair(data, seed=2)
    holed, zero = _with_zeros(data, 0.1, seed=3)
    model = np.asarray(ctfit.evaluate(mat, data))
    notes = residual_structure(holed, model)
    assert len(notes) == 1 and notes[0].region == "samples exactly 0", notes
    share = f"{zero.sum():,} samples ({zero.mean():.0%})"
    assert notes[0].startswith(f"systematic residuals: {share} are exactly 0 where the model is not (median ")
    assert f"{np.median(model[zero]):.3g} sr⁻¹ there" in notes[0]
    res = ctfit.fit(holed, mat.structure, loss="robust-relative")  # the zeros pull a little: they are misses, if capped
    assert res.converged and res.stats["quality"]["median_relative_error"] < 0.005
    np.testing.assert_allclose(res.material.params.m, [0.3], rtol=1e-3)
    got = [w for w in res.warnings if w.kind == "systematic_residuals"]
    assert [w.region for w in got] == ["samples exactly 0"], res.warnings
    assert share in got[0]
    assert residual_structure(data, model) == []  # the same samples measured: nothing to say


def test_zero_values_where_the_model_is_zero_too_or_few_are_not_a_warning():
    """Values exactly 0 where the model is (about) 0 too, or fewer than one sample in twenty,
    say nothing."""
    from ctfit._fitting.diagnostics import ZEROS_HINT, zero_samples_warning

    assert zero_samples_warning(np.full(100, 0.05), 0.01, 1000) is None  # the model at 5 % of the floor there
    assert zero_samples_warning(np.full(49, 50.0), 0.01, 1000) is None  # 4.9 % of the samples
    assert ZEROS_HINT == 0.05 and zero_samples_warning(np.full(50, 50.0), 0.01, 1000).region == "samples exactly 0"
    assert zero_samples_warning(np.zeros(0), 0.01, 0) is None
