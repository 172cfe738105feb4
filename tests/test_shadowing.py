"""Geometric attenuation G: the paper's V-cavity term (eq. 8) and Smith's Beckmann G1, reduced."""

import jax
import jax.numpy as jnp
import mpmath
import numpy as np
import pytest
from helpers import angle_grid, directions, gauss_legendre

import ctfit

geometry = jax.jit(ctfit.geometry)
v_cavity_reduced = jax.jit(ctfit.v_cavity_reduced)
smith_g1_reduced = jax.jit(ctfit.smith_g1_reduced)


def _grid():
    ti, pi, to, po = angle_grid([0, 1e-6, 10, 30, 50, 70, 85, 89.9], [0, 45, 90, 135, 170, 180, 190, 270])
    return directions(ti, pi), directions(to, po)


def test_v_cavity_against_eq8():
    """G/((N·L)(N·V)) with G = min{1, 2(N·H)(N·V)/(V·H), 2(N·H)(N·L)/(V·H)} from the vectors."""
    l, v = _grid()
    h = (l + v) / np.linalg.norm(l + v, axis=1, keepdims=True)
    nl, nv, nh, vh = l[:, 2], v[:, 2], h[:, 2], np.sum(v * h, axis=1)
    g = np.minimum(1, np.minimum(2 * nh * nv / vh, 2 * nh * nl / vh))
    geom = geometry(jnp.asarray(l), jnp.asarray(v))
    got = np.asarray(v_cavity_reduced(geom.cos_l, geom.cos_v, geom.cos_h, geom.cos_vh))
    np.testing.assert_allclose(got * nl * nv, g, rtol=1e-13)
    assert np.all(got * nl * nv <= 1 + 1e-15) and np.all(got > 0)


def test_v_cavity_is_one_near_normal_and_reciprocal():
    l, v = _grid()
    gl = geometry(jnp.asarray(l), jnp.asarray(v))
    gv = geometry(jnp.asarray(v), jnp.asarray(l))
    a = np.asarray(v_cavity_reduced(gl.cos_l, gl.cos_v, gl.cos_h, gl.cos_vh))
    b = np.asarray(v_cavity_reduced(gv.cos_l, gv.cos_v, gv.cos_h, gv.cos_vh))
    np.testing.assert_allclose(a, b, rtol=1e-15)
    small = (l[:, 2] > np.cos(np.deg2rad(31))) & (v[:, 2] > np.cos(np.deg2rad(31)))
    np.testing.assert_allclose(a[small] * l[small, 2] * v[small, 2], 1.0, rtol=1e-15)


def _g1_mp(cos_t, sin_t, m):
    """Smith G1 = 1/(1 + Λ), Λ(a) = (erf a − 1)/2 + exp(−a²)/(2 a √π), a = 1/(m tan θ) (Walter et al. 2007, eq. 27).

    cos θ and sin θ are taken as exact inputs (as ctfit receives them).
    """
    with mpmath.workdps(40):
        a = mpmath.mpf(float(cos_t)) / (mpmath.mpf(float(m)) * mpmath.mpf(float(sin_t)))
        lam = (mpmath.erf(a) - 1) / 2 + mpmath.exp(-a * a) / (2 * a * mpmath.sqrt(mpmath.pi))
        return 1 / (1 + lam)


@pytest.mark.parametrize("m", [1e-4, 0.05, 0.2, 0.5, 1.0, 3.0])
def test_smith_g1_against_lambda_form(m):
    theta = np.array([1e-6, 1.0, 10.0, 30.0, 45.0, 60.0, 75.0, 85.0, 89.0, 89.9, 89.999])
    c, s = np.cos(np.deg2rad(theta)), np.sin(np.deg2rad(theta))
    ref = np.array([float(_g1_mp(ci, si, m)) for ci, si in zip(c, s)])
    got = np.asarray(smith_g1_reduced(jnp.asarray(c), jnp.asarray(s), jnp.asarray(m))) * c
    np.testing.assert_allclose(got, ref, rtol=1e-13)
    assert np.all(np.diff(got) <= 4e-16) and np.all((got > 0) & (got <= 1 + 4e-16))  # (G1/cos θ)·cos θ rounds


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_smith_limits(dtype):
    """G1/cos θ = 1/cos θ near normal (a ≥ 30), 2√π/m on the horizon (θ = 90°, cos θ = 0)."""
    m = jnp.asarray([1e-4, 0.2, 3.0], dtype)
    one = np.asarray(smith_g1_reduced(jnp.ones((), dtype), jnp.zeros((), dtype), m))
    np.testing.assert_array_equal(one, 1.0)
    hor = np.asarray(smith_g1_reduced(jnp.zeros((), dtype), jnp.ones((), dtype), m))
    np.testing.assert_allclose(hor, 2 * np.sqrt(np.pi) / np.asarray(m, np.float64), rtol=4 * float(np.finfo(dtype).eps))


@pytest.mark.parametrize("m", [0.1, 0.3, 0.8])
@pytest.mark.parametrize("theta_o", [0.0, 40.0, 70.0, 85.0])
def test_smith_g1_projected_area(m, theta_o):
    """Smith's G1 and Beckmann's D satisfy ∫ G1(o) ⟨o·h⟩⁺ D(h) dω_h = cos θ_o (Heitz 2014, eq. 8).

    A consistency check between ``smith_g1_reduced`` and ``beckmann`` (normalised D = D̂/π).
    """
    th, wt = gauss_legendre(np.concatenate([np.linspace(0, np.pi / 2, 17), np.minimum(m * np.arange(0, 10, 0.5), np.pi / 2)]), 24)
    ph, wp = gauss_legendre(np.linspace(0, 2 * np.pi, 17), 24)
    T, P = np.meshgrid(th, ph, indexing="ij")
    W = np.outer(wt, wp) * np.sin(T)
    h = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1)
    o = directions(theta_o, 0.0)
    oh = np.maximum(h @ o, 0)
    d = np.asarray(ctfit.beckmann(jnp.asarray(np.tan(T) ** 2), m)) / np.pi
    co, so = np.cos(np.deg2rad(theta_o)), np.sin(np.deg2rad(theta_o))
    g1 = float(smith_g1_reduced(jnp.asarray(co), jnp.asarray(so), jnp.asarray(m))) * co
    assert np.sum(W * g1 * oh * d) == pytest.approx(co, rel=1e-6, abs=1e-9)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_smith_derivative_in_m_finite(dtype):
    theta = np.array([0.0, 1e-6, 30.0, 60.0, 85.0, 89.9, 90.0])
    c = jnp.asarray(np.sin(np.deg2rad(90 - theta)), dtype)
    s = jnp.asarray(np.sin(np.deg2rad(theta)), dtype)
    ms = jnp.asarray([1e-4, 1e-3, 0.00935, 0.05, 0.2, 0.6, 1.0, 3.0], dtype)
    g = jax.jit(jax.vmap(jax.vmap(jax.grad(ctfit.smith_g1_reduced, argnums=2), in_axes=(0, 0, None)), in_axes=(None, None, 0)))(c, s, ms)
    assert np.all(np.isfinite(np.asarray(g)))
    v = np.asarray(jax.vmap(smith_g1_reduced, in_axes=(None, None, 0))(c, s, ms))
    assert np.all(np.isfinite(v)) and np.all(v > 0)


@pytest.mark.parametrize("geometry_form", ["smith", "smith-rational"])
def test_float32_smith_lobe_at_grazing_has_finite_derivative_in_m(geometry_form):
    """A lobe's D̂(α; m) G1(L) G1(V)/((N·L)(N·V)) in float32 for m ∈ {1e-4, 1e-3, 1e-2}, lit and seen at
    up to 89.99999° (cos θ = 1.3e-7) in the retro and the 90° planes (tan²α at its clamp 1e12):
    finite, with finite d/dm in reverse and forward mode. Caught: NaN in reverse mode at m = 1e-4,
    where Smith's G1/cos θ ≈ 2√π/m = 3.5e4 per direction made the cotangent of Beckmann's
    exp(−tan²α/m²) (= 0 there) overflow, ∞ · 0."""
    from ctfit._model.shadowing import smith_rational_g1_reduced

    g1 = ctfit.smith_g1_reduced if geometry_form == "smith" else smith_rational_g1_reduced
    theta = np.array([0.0, 60.0, 89.0, 89.99, 89.9999, 90 - 1e-5])
    ti, to, dphi = (x.ravel() for x in np.meshgrid(theta, theta, [0.0, 90.0, 180.0], indexing="ij"))
    f32 = lambda x: jnp.asarray(x, jnp.float32)
    g = ctfit.geometry_from_angles_deg(f32(ti), f32(20.0), f32(to), f32(20 + dphi))
    assert g.cos_l.dtype == jnp.float32

    def lobe(m):
        return ctfit.beckmann(g.tan2_h, m) * g1(g.cos_l, g.sin_l, m) * g1(g.cos_v, g.sin_v, m)

    for m in (1e-4, 1e-3, 1e-2):
        m32 = jnp.float32(m)
        assert np.all(np.isfinite(np.asarray(lobe(m32))))
        for mode, d in (("reverse", jax.grad(lambda m: jnp.sum(lobe(m)))(m32)), ("forward", jax.jacfwd(lambda m: jnp.sum(lobe(m)))(m32))):
            assert np.isfinite(float(d)), (geometry_form, m, mode, float(d))


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_rational_smith_is_finite_with_finite_derivatives_everywhere(dtype):
    """Walter et al.'s rational G1/cos θ: finite values and derivatives in m and θ from normal
    incidence to θ = 90° and m from 1e-4 to 3, and 3.535/m at θ = 90°."""
    from ctfit._model.shadowing import smith_rational_g1_reduced

    theta = np.array([0.0, 1e-6, 30.0, 60.0, 85.0, 89.9, 90.0])
    ms = jnp.asarray([1e-4, 1e-3, 0.05, 0.2, 0.6, 1.0, 3.0], dtype)

    def g(t, m):
        return smith_rational_g1_reduced(jnp.cos(t), jnp.sin(t), m)

    t = jnp.asarray(np.deg2rad(theta), dtype)
    for argnum in (0, 1):
        d = jax.vmap(jax.vmap(jax.grad(g, argnums=argnum), in_axes=(0, None)), in_axes=(None, 0))(t, ms)
        assert np.all(np.isfinite(np.asarray(d))), argnum
    v = np.asarray(jax.vmap(g, in_axes=(None, 0))(t, ms))
    assert np.all(np.isfinite(v)) and np.all(v > 0)
    at_90 = np.asarray(smith_rational_g1_reduced(jnp.zeros((), dtype), jnp.ones((), dtype), ms))  # cos θ = 0 exactly
    np.testing.assert_allclose(at_90 * np.asarray(ms), 3.535, rtol=1e-6)  # G1/cos θ → 3.535/(m sin θ)


def test_rational_smith_is_continuous_where_it_becomes_one():
    from ctfit._model.shadowing import smith_rational_g1_reduced

    m = 0.3
    for side in (1 - 1e-9, 1 + 1e-9):  # a = cos θ/(m sin θ) just below and above 1.6
        t = np.arctan(1 / (1.6 * side * m))
        g1 = float(smith_rational_g1_reduced(jnp.cos(t), jnp.sin(t), m)) * np.cos(t)
        assert abs(g1 - 1) < 6e-5  # the approximation reaches 1.000057 at a = 1.6
