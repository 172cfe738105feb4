"""``ctfit.evaluate_at``: the material at any directions (angles or unit vectors) and bands."""

import numpy as np
import pytest

import ctfit

GOLD = ctfit.Material(ctfit.Structure(lobes=1, diffuse="F0/pi"), ctfit.Params(s=np.asarray(0.8), m=np.array([0.2]), w=np.ones(1), f0=np.array([0.4, 0.9])),
                      wavelength_nm=np.array([450.0, 650.0]))


def test_angles_match_evaluate_on_a_measurement():
    rng = np.random.default_rng(0)
    ti, to = rng.uniform(0, 85, 50), rng.uniform(0, 85, 50)
    pi, po = rng.uniform(0, 360, 50), rng.uniform(0, 360, 50)
    got = ctfit.evaluate_at(GOLD, theta_i=ti, phi_i=pi, theta_o=to, phi_o=po)
    rep = lambda a: np.repeat(a, 2)
    m = ctfit.Measurement(theta_i=rep(ti), phi_i=rep(pi), theta_o=rep(to), phi_o=rep(po), band=np.tile([0, 1], 50), wavelength_nm=GOLD.wavelength_nm)
    np.testing.assert_allclose(got.reshape(-1), ctfit.evaluate(GOLD, m), rtol=1e-12)


def test_unit_vectors_equal_angles_and_broadcasting_works():
    t = np.deg2rad(np.array([10.0, 40.0, 70.0]))
    l = np.stack([np.sin(np.deg2rad(30)) * np.ones(3), np.zeros(3), np.cos(np.deg2rad(30)) * np.ones(3)], -1)
    v = np.stack([-np.sin(t), np.zeros(3), np.cos(t)], -1)  # φ_o = 180°
    by_vectors = ctfit.evaluate_at(GOLD, l=l, v=v)
    by_angles = ctfit.evaluate_at(GOLD, theta_i=30.0, theta_o=[10.0, 40.0, 70.0], phi_o=180.0)
    assert by_angles.shape == (3, 2)
    np.testing.assert_allclose(by_vectors, by_angles, rtol=1e-10)
    grid = ctfit.evaluate_at(GOLD, theta_i=np.array([0.0, 45.0])[:, None], theta_o=np.linspace(0, 80, 5)[None, :], phi_o=180.0)
    assert grid.shape == (2, 5, 2)


def test_other_wavelengths_are_interpolated_and_the_horizon_gives_zero():
    at = ctfit.evaluate_at(GOLD, theta_i=20.0, theta_o=20.0, phi_o=180.0, wavelength_nm=[450.0, 550.0, 650.0])
    own = ctfit.evaluate_at(GOLD, theta_i=20.0, theta_o=20.0, phi_o=180.0)
    np.testing.assert_allclose(at[[0, 2]], own, rtol=1e-12)
    assert own[0] < at[1] < own[1]
    assert np.all(ctfit.evaluate_at(GOLD, theta_i=20.0, theta_o=95.0) == 0)


@pytest.mark.parametrize("kwargs", [{}, {"theta_i": 10.0}, {"theta_i": 10.0, "theta_o": 10.0, "l": [0, 0, 1]}, {"l": [0, 0, 1]}])
def test_directions_must_be_given_one_way(kwargs):
    with pytest.raises(ValueError, match="either as angles"):
        ctfit.evaluate_at(GOLD, **kwargs)
