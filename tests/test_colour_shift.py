"""The paper's colour-shift approximation (§4, Figure 5) against the exact spectral colours."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_colour import cu_f0, cu_nk

import ctfit
from ctfit._colour import XYZ_to_Lab, XYZ_to_RGB, delta_E_CIE2000, rgb_conversion, spectral_weights, spectrum_to_RGB, spectrum_to_XYZ
from ctfit._colour.colour_shift import (
    average_normal_reflectance,
    colour_shift_approximation,
    colour_shift_spectral,
    colour_shift_weight,
    fresnel_reflectance_spectrum,
)

WL = np.arange(360.0, 831.0, 5)
W = spectral_weights(WL)
N, K = cu_nk(WL)
F0 = cu_f0(WL)
COS = np.cos(np.radians(np.linspace(0, 90, 19)))
COS[-1] = 0.0

spectrum = jax.jit(fresnel_reflectance_spectrum)
weight = jax.jit(colour_shift_weight)
approximation = jax.jit(colour_shift_approximation)


def test_weight_ends_range_and_monotonic():
    for f0 in (0.04, 0.5, 0.9):
        w = np.asarray(weight(COS, f0))
        assert w[0] == pytest.approx(0, abs=1e-12) and w[-1] == pytest.approx(1, abs=1e-12)
        assert np.all((w >= 0) & (w <= 1))
        assert np.all(np.diff(w) >= -1e-12)
    # The paper's form: F with n = (1 + √F0)/(1 − √F0) through fresnel_dielectric.
    f0 = 0.3
    n = (1 + np.sqrt(f0)) / (1 - np.sqrt(f0))
    ref = (np.asarray(jax.jit(ctfit.fresnel_dielectric)(COS, n)) - f0) / (1 - f0)
    np.testing.assert_allclose(np.asarray(weight(COS, f0)), np.maximum(ref, 0), atol=1e-12)


def test_weight_degenerate_f0_and_gradients():
    assert np.all(np.asarray(weight(COS, 1.0)) == 0)
    assert np.all(np.asarray(weight(COS, 0.0)) == 0)
    g = jax.jit(jax.vmap(jax.grad(colour_shift_weight, argnums=(0, 1)), in_axes=(0, None)))
    for f0 in (0.0, 0.5, 1.0):
        gc, gf = g(jnp.asarray(COS), f0)
        assert np.all(np.isfinite(gc)) and np.all(np.isfinite(gf))


def test_approximation_ends_and_broadcasting():
    normal = jnp.asarray([0.9, 0.6, 0.5])
    light = jnp.ones(3)
    out = approximation(normal, light, 0.6, jnp.asarray(COS))
    assert out.shape == (COS.size, 3)
    np.testing.assert_allclose(out[0], normal, atol=1e-12)
    np.testing.assert_allclose(out[-1], light, atol=1e-12)
    batch = approximation(jnp.stack([normal, light]), light, jnp.asarray([0.6, 0.2]), jnp.asarray([0.5, 0.5]))
    assert batch.shape == (2, 3)
    np.testing.assert_allclose(batch[1], light)


def test_spectra_at_normal_and_grazing_incidence():
    f_f0 = np.asarray(spectrum(COS, f0=F0))
    f_nk = np.asarray(spectrum(COS, n=N, k=K))
    assert f_f0.shape == f_nk.shape == (COS.size, WL.size)
    np.testing.assert_allclose(f_f0[0], F0, atol=1e-12)
    np.testing.assert_allclose(f_nk[0], F0, atol=1e-12)
    np.testing.assert_allclose(f_f0[-1], 1, atol=1e-12)
    np.testing.assert_allclose(f_nk[-1], 1, atol=1e-12)
    n_only = np.asarray(spectrum(0.5, n=N))
    np.testing.assert_allclose(n_only, np.asarray(jax.jit(ctfit.fresnel_dielectric)(0.5, N)))
    with pytest.raises(ValueError, match="either"):
        fresnel_reflectance_spectrum(0.5, f0=F0, n=N)
    with pytest.raises(ValueError, match="give"):
        fresnel_reflectance_spectrum(0.5)


def test_average_normal_reflectance():
    assert float(average_normal_reflectance(F0)) == pytest.approx(F0.mean())
    y = float(jax.jit(average_normal_reflectance)(F0, W))
    assert y == pytest.approx(float(spectrum_to_XYZ(F0, W)[1]))
    assert 0.5 < y < 0.8  # copper


@jax.jit
def _figure5(cos, weights, conv):
    xyz_f0 = colour_shift_spectral(cos, weights, f0=F0)
    xyz_nk = colour_shift_spectral(cos, weights, n=N, k=K)
    f0_mean = average_normal_reflectance(F0, weights)
    approx = colour_shift_approximation(xyz_f0[0], weights.white_XYZ, f0_mean, cos)
    rgb = colour_shift_approximation(XYZ_to_RGB(xyz_f0[0], conv), jnp.ones(3), f0_mean, cos)
    f_avg = ctfit.fresnel_dielectric_f0(cos, f0_mean)
    lab = lambda x: XYZ_to_Lab(x, weights.white_XYZ)
    de_approx = delta_E_CIE2000(lab(approx), lab(xyz_f0))
    de_nk = delta_E_CIE2000(lab(xyz_nk), lab(xyz_f0))
    return xyz_f0, xyz_nk, f0_mean, approx, XYZ_to_RGB(approx, conv), rgb, f_avg, de_approx, de_nk


def test_copper_exact_and_approximation():
    """Figure 5: exact (effective index and n, k) and approximate colours of copper by angle."""
    conv = rgb_conversion("sRGB", W.white_XYZ)
    out = [np.asarray(a) for a in _figure5(COS, W, conv)]
    xyz_f0, xyz_nk, f0_mean, approx, approx_rgb, rgb, f_avg, de_approx, de_nk = out
    np.testing.assert_allclose(xyz_f0[0], xyz_nk[0], atol=1e-12)
    np.testing.assert_allclose(xyz_f0[-1], W.white_XYZ, atol=1e-12)
    np.testing.assert_allclose(xyz_nk[-1], W.white_XYZ, atol=1e-12)
    np.testing.assert_allclose(approx[0], xyz_f0[0], atol=1e-12)
    # With the luminance-weighted F0_avg, the approximation's luminance is max(F_avg(θ), F0_avg)
    # exactly (the dielectric F of a high index dips below F0 before it rises: max(0, ·)).
    assert f_avg.min() < float(f0_mean)
    np.testing.assert_allclose(approx[:, 1], np.maximum(f_avg, float(f0_mean)), atol=1e-12)
    # Interpolating in XYZ or in linear RGB is the same (both linear).
    np.testing.assert_allclose(rgb, approx_rgb, atol=1e-12)
    # All three agree at 0° and 90°; up to 45° within ΔE00 0.5; near grazing they part (the
    # effective-index spectra darken and saturate before turning white, the conductor whitens
    # early, the approximation stays at the normal colour until F_avg climbs above F0_avg).
    theta = np.degrees(np.arccos(COS))
    for de in (de_approx, de_nk):
        assert de[0] == pytest.approx(0, abs=1e-9) and de[-1] == pytest.approx(0, abs=1e-9)
        assert np.all(de[theta <= 45] < 0.5)
        assert de.max() < 20


def test_gradient_through_spectral_shift():
    conv = rgb_conversion("sRGB", W.white_XYZ)

    @jax.jit
    @jax.grad
    def g(f0):
        return jnp.sum(spectrum_to_RGB(fresnel_reflectance_spectrum(jnp.asarray(COS), f0=f0), W, conv))

    assert np.all(np.isfinite(g(jnp.asarray(F0))))
    assert np.all(np.isfinite(g(jnp.zeros(WL.size))))
    assert np.all(np.isfinite(g(jnp.ones(WL.size))))
