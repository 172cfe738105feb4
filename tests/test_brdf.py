"""The assembled BRDF R = s R_s + d R_d (Cook & Torrance 1982, eqs. 1–2, 5) and its geometry.

Checked against an independent NumPy transcription (tests/helpers.py) for every structure;
reciprocity; the factor 4 between the two normalisations; the directional albedo with F = 1
(≤ 1, numerical quadrature over the outgoing hemisphere); horizon handling; the scattered
layout; and jit against the reference at batch sizes where XLA's CPU fusion once went wrong.
"""


import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import STRUCTURES, angle_grid, directions, gauss_legendre, make_params, reference_brdf, structure_id

import ctfit
from ctfit import Params, Structure

from conftest import load_script

DIFFUSE_ONLY = [Structure(lobes=0, fresnel=fr, diffuse=d) for fr in ("f0", "n", "conductor") for d in ("F0/pi", "spectrum", "constant")]
ALL = STRUCTURES + DIFFUSE_ONLY


def _pairs():
    ti, pi, to, po = angle_grid([0, 5, 20, 40, 60, 75, 85], [0, 30, 90, 150, 175, 180, 185, 300], phi_i=17.0)
    return directions(ti, pi), directions(to, po)


L, V = _pairs()


@pytest.mark.parametrize("st", ALL, ids=structure_id)
def test_against_reference_and_reciprocal(st):
    """ctfit equals the textbook transcription, and R(L, V) = R(V, L), for every structure (float64)."""
    p = make_params(st)
    got = np.asarray(ctfit.brdf(st, p, ctfit.geometry(jnp.asarray(L), jnp.asarray(V))))
    ref = reference_brdf(st, p, L, V)
    assert got.shape == ref.shape
    np.testing.assert_allclose(got, ref, rtol=1e-11, atol=1e-300)
    swapped = np.asarray(ctfit.brdf(st, p, ctfit.geometry(jnp.asarray(V), jnp.asarray(L))))
    np.testing.assert_allclose(swapped, got, rtol=1e-13, atol=0)


def test_reciprocity_float32():
    for st in (STRUCTURES[0], Structure(lobes=2, geometry="smith", fresnel="conductor", diffuse="spectrum")):
        p = make_params(st, np.float32)
        f = jax.jit(lambda l, v: ctfit.brdf(st, p, ctfit.geometry(l, v)))
        a = np.asarray(f(jnp.asarray(L, jnp.float32), jnp.asarray(V, jnp.float32)))
        b = np.asarray(f(jnp.asarray(V, jnp.float32), jnp.asarray(L, jnp.float32)))
        np.testing.assert_allclose(a, b, rtol=2e-6)


@pytest.mark.parametrize("geometry", ["v-cavity", "smith"])
@pytest.mark.parametrize("fresnel", ["f0", "conductor"])
def test_paper_normalisation_is_four_times_normalised(geometry, fresnel):
    """cook-torrance-1982 (F D̂ G/(π N·L N·V)) = 4 × normalized (F D̂ G/(4π N·L N·V)) for Beckmann."""
    a = Structure(lobes=2, geometry=geometry, fresnel=fresnel, normalization="normalized")
    b = Structure(lobes=2, geometry=geometry, fresnel=fresnel, normalization="cook-torrance-1982")
    p = make_params(a)
    g = ctfit.geometry(jnp.asarray(L), jnp.asarray(V))
    ra, rb = np.asarray(ctfit.brdf(a, p, g)), np.asarray(ctfit.brdf(b, p, g))
    np.testing.assert_allclose(rb, 4 * ra, rtol=1e-15)
    assert ctfit.specular_constant(b) == 4 * ctfit.specular_constant(a)


def test_gaussian_normalisations_differ_by_four_times_two_j():
    """For the Gaussian the 1982 constant is 1/m², the normalised 1/(2 m² J(m)): ratio 4 · 2J(m)."""
    m = 0.3
    a = Structure(lobes=1, distribution="gaussian")
    b = Structure(lobes=1, distribution="gaussian", normalization="cook-torrance-1982")
    p = make_params(a, m=(m,))
    g = ctfit.geometry(jnp.asarray(L), jnp.asarray(V))
    j = float(ctfit._model.distribution.gaussian_norm_integral(jnp.asarray(m)))
    np.testing.assert_allclose(np.asarray(ctfit.brdf(b, p, g)), 8 * j * np.asarray(ctfit.brdf(a, p, g)), rtol=1e-13)


# --------------------------------------------------------------------------- albedo


def _albedo(st, m, theta_i):
    """∫ R(L, V) cos θ_o dω_o over the outgoing hemisphere, with F = 1 (f0 = 1).

    Integrated over the half vector H (dω_o = 4 (V·H) dω_h, V = 2 (L·H) H − L), where the
    specular lobe is a smooth bump of width ~m: composite Gauss–Legendre in θ_h with breakpoints
    scaled by m, and in φ_h.
    """
    th, wt = gauss_legendre(np.concatenate([np.linspace(0, np.pi / 2, 13), np.minimum(m * np.arange(0, 8, 0.5), np.pi / 2)]), 20)
    ph, wp = gauss_legendre(np.linspace(0, 2 * np.pi, 25), 16)
    T, P = np.meshgrid(th, ph, indexing="ij")
    w = (np.outer(wt, wp) * np.sin(T)).ravel()
    h = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    l = directions(theta_i, 0.0)
    lh = h @ l
    v = 2 * lh[:, None] * h - l
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    keep = lh > 0
    p = make_params(st, m=(m,), f0=(1.0,))
    r = np.asarray(_brdf_jit(st, p, jnp.asarray(np.broadcast_to(l, v.shape)), jnp.asarray(v)))[:, 0]
    return np.sum(np.where(keep, w * r * np.maximum(v[:, 2], 0) * 4 * np.abs(lh), 0))


_brdf_jit = jax.jit(lambda st, p, l, v: ctfit.brdf(st, p, ctfit.geometry(l, v)), static_argnums=0)


@pytest.mark.parametrize("distribution", ["beckmann", "gaussian"])
@pytest.mark.parametrize("geometry", ["v-cavity", "smith"])
@pytest.mark.parametrize("m", [0.05, 0.2, 0.6, 1.0])
def test_directional_albedo_at_most_one(distribution, geometry, m):
    """Energy: with F = 1 the normalised model reflects at most all incident light.

    Holds for Beckmann with either G and for the Gaussian with the V-cavity G. Smith's G1 here
    is Beckmann's (ctfit uses it for both distributions); paired with the Gaussian D it is not
    the matching masking function, and at grazing the albedo exceeds 1 slightly (measured:
    1.0005 at θ_i = 89°, 1.007 at 89.9°, m = 0.6), so that pair only gets a looser bound.
    """
    st = Structure(lobes=1, distribution=distribution, geometry=geometry)
    alb = np.array([_albedo(st, m, t) for t in (0.0, 30.0, 60.0, 80.0, 89.0)])
    # The quadrature is good to ~2e-5 at 89° (checked against a 3× finer rule); the V-cavity
    # albedo approaches 1 at grazing, so the bound allows 1e-4 for the quadrature alone.
    bound = 1.01 if (distribution, geometry) == ("gaussian", "smith") else 1 + 1e-4
    assert np.all(alb <= bound), alb
    assert np.all(alb > 0)
    if m == 0.05:
        # A nearly smooth mirror reflects nearly everything away from grazing (G ≈ 1): the
        # normalisation is not off by a factor (4 or 1/4 would show here).
        assert np.all(alb[:3] > 0.98), alb


def test_albedo_of_the_paper_normalisation_is_four_times():
    st = Structure(lobes=1, normalization="cook-torrance-1982")
    assert _albedo(st, 0.05, 0.0) == pytest.approx(4 * _albedo(Structure(lobes=1), 0.05, 0.0), rel=1e-12)


# --------------------------------------------------------------------------- layout, horizon, parts


def test_pairs_layout_equals_grid():
    st = Structure(lobes=2, geometry="smith", fresnel="conductor", diffuse="spectrum")
    p = make_params(st)
    g = ctfit.geometry(jnp.asarray(L), jnp.asarray(V))
    grid = np.asarray(ctfit.brdf(st, p, g))
    band = np.arange(len(L)) % 3
    pairs = np.asarray(ctfit.brdf_pairs(st, p, g, jnp.asarray(band)))
    np.testing.assert_array_equal(pairs, grid[np.arange(len(L)), band])


@pytest.mark.parametrize("st", [STRUCTURES[0], STRUCTURES[-1], DIFFUSE_ONLY[1]], ids=structure_id)
def test_zero_on_and_below_the_horizon(st):
    p = make_params(st)
    # ctfit's directions: θ = 90° is exactly on the horizon (NumPy's cos(π/2) = 6e-17 is not).
    l = ctfit.direction_from_angles_deg(jnp.asarray([90.0, 90.0, 30.0, 120.0, 30.0, 180.0]), 0.0)
    v = ctfit.direction_from_angles_deg(jnp.asarray([30.0, 90.0, 90.0, 30.0, 100.0, 0.0]), jnp.asarray([180.0, 180.0, 0.0, 0.0, 0.0, 0.0]))
    np.testing.assert_array_equal(np.asarray(_brdf_jit(st, p, l, v)), 0.0)
    np.testing.assert_array_equal(np.asarray(_brdf_jit(st, p, l, -l)), 0.0)  # V = −L


def test_diffuse_and_ambient_parts():
    """R_d = F0/π for the homogeneous material; R_a = π R_d (§2.1); a d-only material is R_d."""
    st = Structure(lobes=1, diffuse="F0/pi")
    p = make_params(st)
    np.testing.assert_allclose(np.asarray(ctfit.diffuse_reflectance(st, p)), np.asarray(p.f0) / np.pi, rtol=1e-15)
    np.testing.assert_allclose(np.asarray(ctfit.ambient_reflectance(st, p)), np.asarray(p.f0), rtol=1e-15)
    cond = Structure(lobes=1, fresnel="conductor")
    pc = make_params(cond)
    np.testing.assert_allclose(np.asarray(ctfit.ambient_reflectance(cond, pc)), np.asarray(ctfit.f0_from_nk(pc.n, pc.k)), rtol=1e-15)
    only = Structure(lobes=0, diffuse="spectrum")
    po = make_params(only)
    r = np.asarray(ctfit.brdf(only, po, ctfit.geometry(jnp.asarray(L), jnp.asarray(V))))
    np.testing.assert_allclose(r, np.broadcast_to(np.asarray(po.rd), r.shape), rtol=0)


def test_s_mixes_the_parts():
    st = Structure(lobes=1, diffuse="spectrum")
    g = ctfit.geometry(jnp.asarray(L), jnp.asarray(V))
    p1 = make_params(st, s=1.0)
    p0 = make_params(st, s=0.0)
    ph = make_params(st, s=0.25)
    r1, r0, rh = (np.asarray(ctfit.brdf(st, p, g)) for p in (p1, p0, ph))
    np.testing.assert_allclose(rh, 0.25 * r1 + 0.75 * r0, rtol=1e-14)
    np.testing.assert_allclose(r0, np.broadcast_to(np.asarray(p0.rd), r0.shape), rtol=0)


# --------------------------------------------------------------------------- geometry


def test_geometry_mirror_and_normal_incidence():
    g = ctfit.geometry_from_angles_deg(jnp.asarray([0.0, 30.0, 60.0, 89.9]), 10.0, jnp.asarray([0.0, 30.0, 60.0, 89.9]), 190.0)
    np.testing.assert_allclose(np.asarray(g.tan2_h), 0.0, atol=1e-25)  # α ≲ 1e-13 rad from rounding of φ + 180°
    np.testing.assert_allclose(np.asarray(g.cos_h), 1.0, rtol=1e-15)
    np.testing.assert_allclose(np.asarray(g.cos_vh), np.cos(np.deg2rad([0.0, 30.0, 60.0, 89.9])), rtol=1e-12)
    assert bool(jnp.all(g.valid))
    d = ctfit.direction_from_angles_deg(jnp.asarray([0.0, 90.0]), jnp.asarray([0.0, 370.0]))
    np.testing.assert_array_equal(np.asarray(d[0]), [0.0, 0.0, 1.0])
    assert float(d[1, 2]) == 0.0
    np.testing.assert_allclose(np.asarray(d[1]), [np.cos(np.deg2rad(10)), np.sin(np.deg2rad(10)), 0.0], atol=1e-16)


def test_geometry_against_textbook_and_general_normal():
    g = ctfit.geometry(jnp.asarray(L), jnp.asarray(V))
    h = (L + V) / np.linalg.norm(L + V, axis=1, keepdims=True)
    np.testing.assert_allclose(np.asarray(g.cos_h), h[:, 2], rtol=1e-14)
    np.testing.assert_allclose(np.asarray(g.cos_vh), np.sum(V * h, axis=1), rtol=1e-13)
    tan2 = (1 - h[:, 2] ** 2) / h[:, 2] ** 2
    np.testing.assert_allclose(np.asarray(g.tan2_h), tan2, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(np.asarray(g.sin_l), np.sqrt(1 - L[:, 2] ** 2), rtol=1e-9, atol=1e-15)
    # Rotating L, V and N together changes nothing.
    rng = np.random.default_rng(3)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    gr = ctfit.geometry(jnp.asarray(L @ q.T), jnp.asarray(V @ q.T), jnp.asarray(q @ [0.0, 0.0, 1.0]))
    for f in ("cos_l", "cos_v", "cos_h", "cos_vh"):
        np.testing.assert_allclose(np.asarray(getattr(gr, f)), np.asarray(getattr(g, f)), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(np.asarray(gr.tan2_h), np.asarray(g.tan2_h), rtol=1e-9, atol=1e-13)
    np.testing.assert_array_equal(np.asarray(gr.valid), np.asarray(g.valid))
    g_explicit = ctfit.geometry(jnp.asarray(L), jnp.asarray(V), jnp.asarray([0.0, 0.0, 1.0]))
    for f in ("cos_l", "cos_v", "sin_l", "sin_v", "cos_h", "tan2_h", "cos_vh"):
        np.testing.assert_allclose(np.asarray(getattr(g_explicit, f)), np.asarray(getattr(g, f)), rtol=1e-15, atol=0)


# --------------------------------------------------------------------------- jit (XLA CPU)


@pytest.mark.parametrize(
    "st",
    [
        Structure(lobes=2, diffuse="spectrum"),
        Structure(lobes=3),
        Structure(lobes=2, geometry="smith", distribution="gaussian", fresnel="conductor"),
    ],
    ids=structure_id,
)
def test_jit_float32_matches_reference_at_batch_sizes(st):
    """Regression: XLA CPU (jaxlib 0.10.2) miscompiled a lobe sum jnp.sum(w * D, -1) whose result
    is broadcast over the bands (its experimental "ynn" fusion) for 2,000–20,000 direction pairs in
    float32 — 90 % of the values were wrong. The lobe sum is now unrolled; this keeps it honest.
    """
    rng = np.random.default_rng(0)
    for pairs in (2000, 8000):
        ti, to, po = rng.uniform(0, 85, pairs), rng.uniform(0, 85, pairs), rng.uniform(0, 360, pairs)
        l, v = directions(ti, np.zeros(pairs)), directions(to, po)
        p64 = make_params(st, m=(0.2, 0.45, 0.3))
        ref = reference_brdf(st, p64, l, v)
        got = np.asarray(_brdf_jit(st, make_params(st, np.float32, m=(0.2, 0.45, 0.3)), jnp.asarray(l, jnp.float32), jnp.asarray(v, jnp.float32)), np.float64)
        np.testing.assert_allclose(got, ref, rtol=2e-4, atol=1e-6 * np.max(ref))


# --------------------------------------------------------------------------- the benchmark's NumPy code


def test_benchmark_numpy_implementations_compute_the_same_model():
    """scripts/bench_eval.py compares ctfit with NumPy code; both must compute the same R."""
    bench = load_script("bench_eval")
    l, v, f0, rd = bench.make_problem(500, 7, np.float64, seed=2)
    m, w, s = np.array([0.2, 0.45]), np.array([0.7, 0.3]), 0.8
    st = Structure(lobes=2, diffuse="spectrum")
    p = Params(m=jnp.asarray(m), w=jnp.asarray(w), f0=jnp.asarray(f0), rd=jnp.asarray(rd), s=jnp.asarray(s))
    ours = np.asarray(ctfit.brdf(st, p, ctfit.geometry(jnp.asarray(l), jnp.asarray(v))))
    grid = bench.numpy_brdf_grid(l, v, f0, rd, s, m, w)
    band = np.tile(np.arange(7), 500)
    per_value = bench.numpy_brdf_per_value(np.repeat(l, 7, 0), np.repeat(v, 7, 0), f0[band], rd[band], s, m, w)
    np.testing.assert_allclose(grid, ours, rtol=1e-10)
    np.testing.assert_allclose(per_value.reshape(500, 7), ours, rtol=1e-10)


def test_angles_broadcast_like_arrays():
    """A scalar θ with an array of φ (and the other way round) is every pair, as NumPy broadcasts."""
    phi = np.array([0.0, 90.0, 180.0, 270.0])
    d = np.asarray(ctfit.direction_from_angles_deg(30.0, phi))
    np.testing.assert_allclose(d, np.asarray(ctfit.direction_from_angles_deg(np.full(4, 30.0), phi)), rtol=0, atol=0)
    np.testing.assert_allclose(d[:, 2], np.cos(np.radians(30.0)), rtol=1e-12)
    g = ctfit.geometry_from_angles_deg(45.0, 0.0, 45.0, np.array([180.0, 0.0]))
    np.testing.assert_allclose(np.asarray(g.tan2_h), [0.0, 1.0], atol=1e-12)
