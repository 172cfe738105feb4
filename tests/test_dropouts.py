"""Values not measured, written as 0 (dropouts): the seeds are scored on the values measured, a
diffuse part of its own starts at its best amplitude, and the default loss (``robust-relative``)
then finds the material under a share of zeros that made the fit explain nothing, or end in a
band of R_d ≈ 0, before."""

import numpy as np
import pytest

import ctfit

from conftest import ROOT


def _holed(data, every: int):
    """``data`` with every ``every``-th value set to exactly 0."""
    y = np.asarray(data.brdf).copy()
    y[::every] = 0
    return data.replace(brdf=y)


def _metal() -> ctfit.Material:
    return ctfit.Material(ctfit.Structure(lobes=1), ctfit.Params(m=np.array([0.3]), w=np.ones(1), f0=np.full(3, 0.05)),
                          wavelength_nm=np.array([450.0, 550.0, 650.0]))


def test_the_seeds_are_scored_on_the_values_measured():
    """A value exactly 0 has no weight in the seeds' scores: the seeds of data with zeros are
    those of the same data without those samples. (Scored, a zero weighed as a sample at the
    floor where the model is bright: every seed of a metal with 2 % zeros was a lobe too faint
    to see, F0 = 0.005, and the fit explained nothing.)"""
    data = ctfit.simulate(_metal(), 800, seed=4)
    holed = _holed(data, 20)
    kept = np.asarray(holed.brdf) != 0
    without = holed.replace(**{k: getattr(holed, k)[kept] for k in ("theta_i", "phi_i", "theta_o", "phi_o", "band", "brdf")})
    for got, want in zip(ctfit.seed_params(holed, _metal().structure, loss="robust-relative"),
                         ctfit.seed_params(without, _metal().structure, loss="robust-relative")):
        np.testing.assert_allclose(got.m, want.m, rtol=1e-12)
        np.testing.assert_allclose(got.f0, want.f0, rtol=1e-9)
    best = ctfit.seed_params(holed, _metal().structure, loss="robust-relative")[0]
    assert 0.2 < best.m[0] < 0.45 and np.all(np.abs(best.f0 - 0.05) < 0.03), best


@pytest.mark.parametrize("every", [50, 20, 10])
def test_a_metal_with_values_not_measured_is_fitted(every):
    """2 %, 5 % and 10 % of a metal's values 0: its own structure, the default loss and starts
    find it (5 % and 10 % explained nothing before, at F0 ≈ 10⁻⁶; so did 2 % drawn at random)."""
    res = ctfit.fit(_holed(ctfit.simulate(_metal(), 2000, seed=1), every), _metal().structure, loss="robust-relative")
    assert res.converged, res.warnings
    np.testing.assert_allclose(res.material.params.m, [0.3], rtol=1e-3)
    np.testing.assert_allclose(res.material.params.f0, 0.05, rtol=2e-3)


def test_a_seed_s_own_diffuse_part_starts_at_its_best_amplitude():
    """A rubber's seeds (a plastic with R_d of its own, 0.019 sr⁻¹) start R_d at the diffuse
    part's best amplitude of their grid point, not at the start's 0.05."""
    rubber = ctfit.load_material(ROOT / "configs" / "rubber.toml")
    seeds = ctfit.seed_params(ctfit.simulate(rubber, 300, noise=0.02, seed=1), rubber.structure, loss="robust-relative")
    for seed in seeds:
        np.testing.assert_allclose(seed.rd, rubber.params.rd, rtol=0.5)


@pytest.mark.parametrize("every", [10, 5, 4])
def test_a_rubber_with_values_not_measured_is_fitted(every):
    """A tenth, a fifth and a quarter of a rubber's values 0 (``configs/rubber.toml``, 2 % noise):
    the fit from its seeds ends where the fit from the truth does. Before, a fifth explained
    nothing and a quarter ended at m = 0.005 (converged); seeds scored without the zeros but at
    the start's R_d ended, for a tenth, with one band's R_d at 4·10⁻⁴ (converged, at 1.4× the cost)."""
    rubber = ctfit.load_material(ROOT / "configs" / "rubber.toml")
    data = _holed(ctfit.simulate(rubber, 300, noise=0.02, seed=1), every)
    res = ctfit.fit(data, rubber.structure, loss="robust-relative")
    truth = ctfit.fit(data, rubber.structure, loss="robust-relative", start=rubber.params, starts=1)
    assert res.converged, res.warnings
    assert res.stats["cost"] == pytest.approx(truth.stats["cost"], rel=1e-9)
    np.testing.assert_allclose(res.material.params.rd, rubber.params.rd, rtol=0.02)
    np.testing.assert_allclose(res.material.params.m, [0.3], rtol=0.01)
    assert [w.region for w in res.warnings if w.kind == "systematic_residuals"] == ["samples exactly 0"]
