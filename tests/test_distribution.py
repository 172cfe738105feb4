"""Facet-slope distributions D̂ (Cook & Torrance 1982, eqs. 3 and 4): values and normalisation."""

import jax
import jax.numpy as jnp
import mpmath
import numpy as np
import pytest
from helpers import gauss_legendre

import ctfit
from ctfit._model.distribution import gaussian_norm_integral

beckmann = jax.jit(ctfit.beckmann)
gaussian = jax.jit(ctfit.gaussian, static_argnames="normalized")

MS = [0.05, 0.2, 0.6, 1.0]


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
@pytest.mark.parametrize("m", [1e-4, 0.00935, 0.05, 0.2, 0.6, 1.0, 3.0])
def test_beckmann_at_the_peak_is_one_over_m2(m, dtype):
    """D̂(α = 0) = 1/m² (eq. 4 at tan α = 0, cos α = 1)."""
    d = beckmann(jnp.zeros((), dtype), jnp.asarray(m, dtype))
    assert d.dtype == dtype
    assert float(d) == pytest.approx(1 / float(jnp.asarray(m, dtype)) ** 2, rel=4 * float(np.finfo(dtype).eps))


@pytest.mark.parametrize("m", [0.05, 0.3, 1.0])
def test_gaussian_at_the_peak(m):
    """1982 convention: c = 1/m² (same peak as Beckmann); normalised: 1/(2 m² J(m)) → 1/m² as m → 0."""
    assert float(gaussian(jnp.asarray(0.0), jnp.asarray(m), normalized=False)) == pytest.approx(1 / m**2, rel=1e-15)
    j = float(gaussian_norm_integral(jnp.asarray(m)))
    assert float(gaussian(jnp.asarray(0.0), jnp.asarray(m), normalized=True)) == pytest.approx(1 / (2 * m**2 * j), rel=1e-14)


# Reference values computed with mpmath at 30 digits from eq. 4, D̂ = exp(−tan²α/m²)/(m² cos⁴α), and
# from eq. 3 with c = 1/m², D̂ = exp(−(α/m)²)/m²; checked by hand for (0.2, 10°):
# tan² 10° = 0.031091, exp(−0.77728) = 0.45966, cos⁴ 10° = 0.94060 → 0.45966/(0.04 · 0.94060) = 12.217.
KNOWN = [
    (0.2, 10.0, 12.217032047262722, 11.673627939436967),
    (0.2, 20.0, 1.1686244396159327, 1.1885114324539848),
    (0.5, 30.0, 1.8744685377118348, 1.3359887439445271),
    (0.5, 60.0, 0.00039322959061300542, 0.04977728697602039),
    (1.0, 45.0, 1.4715177646857693, 0.53964148581629718),
]


@pytest.mark.parametrize("m, alpha_deg, beck, gauss", KNOWN)
def test_known_values(m, alpha_deg, beck, gauss):
    tan2 = jnp.asarray(np.tan(np.deg2rad(alpha_deg)) ** 2)
    assert float(beckmann(tan2, jnp.asarray(m))) == pytest.approx(beck, rel=1e-13)
    assert float(gaussian(tan2, jnp.asarray(m), normalized=False)) == pytest.approx(gauss, rel=1e-13)
    tan2_32 = jnp.asarray(tan2, jnp.float32)
    assert float(beckmann(tan2_32, jnp.float32(m))) == pytest.approx(beck, rel=2e-5)


def _hemisphere_integral(d_hat, m):
    """∫ (D̂/π) cos θ_h dω_h = 2 ∫₀^{π/2} D̂(θ) cos θ sin θ dθ by composite Gauss–Legendre."""
    breaks = np.concatenate([np.linspace(0, np.pi / 2, 33), np.minimum(m * np.arange(0, 12, 0.25), np.pi / 2)])
    theta, w = gauss_legendre(breaks, order=24)
    tan2 = jnp.asarray(np.tan(theta) ** 2)
    d = np.asarray(d_hat(tan2, jnp.asarray(m)))
    return 2 * np.sum(w * d * np.cos(theta) * np.sin(theta))


@pytest.mark.parametrize("m", MS)
def test_beckmann_is_normalised(m):
    """∫ D cos θ_h dω_h = 1 with D = D̂/π (the "normalized" convention)."""
    assert _hemisphere_integral(beckmann, m) == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("m", MS)
def test_gaussian_is_normalised(m):
    assert _hemisphere_integral(lambda t, m: gaussian(t, m, normalized=True), m) == pytest.approx(1.0, abs=1e-12)


@pytest.mark.parametrize("m", MS)
def test_gaussian_1982_constant_is_the_papers(m):
    """With c = 1/m² the paper's Gaussian integrates to 2 J(m) (not 1): 2 J = 1 − O(m²)."""
    val = _hemisphere_integral(lambda t, m: gaussian(t, m, normalized=False), m)
    assert val == pytest.approx(2 * float(gaussian_norm_integral(jnp.asarray(m))), rel=1e-12)


@pytest.mark.parametrize("m", [1e-4, 0.01, 0.05, 0.3, 1.0, 3.0, 30.0])
def test_gaussian_norm_integral_against_quadrature(m):
    """J(m) = ∫₀^{π/2} exp(−α²/m²) cos α sin α dα / m², by mpmath's tanh-sinh quadrature at 30 digits."""
    with mpmath.workdps(30):
        mm = mpmath.mpf(m)
        pts = [mpmath.mpf(0)] + [x * mm for x in (1, 3, 10) if x * m < np.pi / 2] + [mpmath.pi / 2]
        ref = mpmath.quad(lambda a: mpmath.exp(-((a / mm) ** 2)) * mpmath.cos(a) * mpmath.sin(a), pts) / mm**2
    assert float(gaussian_norm_integral(jnp.asarray(m))) == pytest.approx(float(ref), rel=1e-13)


def test_gaussian_norm_integral_small_m_limit():
    assert float(gaussian_norm_integral(jnp.asarray(1e-6))) == pytest.approx(0.5, rel=1e-10)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_far_tail_and_odd_inputs(dtype):
    """Huge tan²α (H near the horizon): Beckmann → 0, Gaussian → its value at α = 90°; never NaN."""
    tan2 = jnp.asarray([0.0, 1e-30, 1.0, 1e6, 1e12, 1e30, np.inf], dtype)
    for m in (1e-4, 0.2, 3.0):
        b = np.asarray(beckmann(tan2, jnp.asarray(m, dtype)))
        assert b.dtype == dtype
        assert np.all(np.isfinite(b)) and np.all(b >= 0)
        assert b[-1] == 0 and b[-2] == 0
        for normalized in (True, False):
            g = np.asarray(gaussian(tan2, jnp.asarray(m, dtype), normalized=normalized), dtype=np.float64)
            assert np.all(np.isfinite(g)) and np.all(g >= 0)
            at_horizon = np.exp(-((np.pi / 2 / m) ** 2)) * g[0]
            np.testing.assert_allclose(g[-3:], at_horizon, rtol=5e-4, atol=1e-300)  # the clamp: α = 90° − 1e-6 rad
    out = beckmann(jnp.asarray([-1.0, np.nan, -np.inf]), jnp.asarray(0.2))
    assert out.shape == (3,)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_derivative_in_m_finite(dtype):
    tan2 = jnp.asarray([0.0, 1e-8, 0.01, 1.0, 1e4, 1e12], dtype)
    ms = jnp.asarray([1e-4, 1e-3, 0.00935, 0.05, 0.2, 0.6, 1.0, 3.0], dtype)
    for fn in (ctfit.beckmann, lambda t, m: ctfit.gaussian(t, m, normalized=True), lambda t, m: ctfit.gaussian(t, m, normalized=False)):
        g = jax.jit(jax.vmap(jax.vmap(jax.grad(fn, argnums=1), in_axes=(0, None)), in_axes=(None, 0)))(tan2, ms)
        assert np.all(np.isfinite(np.asarray(g)))


def test_float32_beckmann_derivative_in_m_finite_where_it_is_zero():
    """Far from a narrow lobe's peak (tan²α/m² beyond where exp underflows: m = 1e-4 with H near the
    horizon) D̂ = 0 and dD̂/dm = 0, also under a large cotangent (the shadowing term at grazing
    multiplies it by up to (2√π/m)² = 1.3e9 for m = 1e-4) and in forward mode. Caught in float32:
    NaN in reverse mode, the cotangent (1 + tan²α)²/m² ≈ 1e32 of exp(…) = 0 times 1e9 overflowing."""
    dtype = jnp.float32
    tan2 = jnp.asarray([0.0, 1e-8, 1.0, 1e4, 1e8, 1e12, 1e14, np.inf], dtype)
    big = jnp.asarray(1.3e9, dtype)
    for m in (1e-4, 1e-3, 1e-2, 0.2):
        m_ = jnp.asarray(m, dtype)
        d = np.asarray(beckmann(tan2, m_))
        assert np.all(np.isfinite(d))
        if m < 0.1:
            assert np.all(d[np.asarray(tan2) >= 1e8] == 0)
        rev = jax.vmap(jax.grad(lambda t, m: big * ctfit.beckmann(t, m), argnums=1), in_axes=(0, None))(tan2, m_)
        fwd = jax.vmap(jax.jacfwd(lambda t, m: big * ctfit.beckmann(t, m), argnums=1), in_axes=(0, None))(tan2, m_)
        assert np.all(np.isfinite(np.asarray(rev))) and np.all(np.isfinite(np.asarray(fwd))), (m, rev, fwd)


def test_beckmann_matches_gaussian_for_small_slopes():
    """Near the peak and for small m both shapes agree (the paper's remark in §2.2)."""
    m = 0.05
    alpha = np.linspace(0, 2 * m, 9)
    tan2 = jnp.asarray(np.tan(alpha) ** 2)
    b = np.asarray(beckmann(tan2, jnp.asarray(m)))
    g = np.asarray(gaussian(tan2, jnp.asarray(m), normalized=True))
    np.testing.assert_allclose(g, b, rtol=0.03)
