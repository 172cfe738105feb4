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
