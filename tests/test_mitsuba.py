"""Agreement with Mitsuba 3's ``roughconductor`` (Beckmann, ``sample_visible = false``).

ctfit's Structure(geometry="smith", fresnel="conductor", normalization="normalized") is the
same model as Mitsuba's rough conductor with a Beckmann distribution of α = m:

- D: Mitsuba's microfacet.h, D = exp(−tan²θ/α²)/(π α² cos⁴θ) — ctfit's D̂/π with α = m;
- F: Mitsuba's fresnel.h ``fresnel_conductor`` (the same Born & Wolf form) at cos = wi·H;
- f_r = F D G/(4 cosθ_i cosθ_o); ``bsdf.eval`` returns f_r cosθ_o;
- G = G1(wi) G1(wo) with Smith's Beckmann G1 — which Mitsuba evaluates through a rational
  approximation ("< 0.35 % rel. error", microfacet.h) set to exactly 1 for a = 1/(α tanθ) ≥ 1.6,
  where ctfit uses the exact erf form (there G1 = 0.9982 at a = 1.6).

What was found (scalar_rgb, float32; grid of 10 × 10 θ pairs × 24 azimuths, m ∈ {0.05, 0.2,
0.5}): with Mitsuba's own G divided out, everything else agrees to 1.4e-5; the full BRDF agrees
to 7e-6 where both exact G1 ≥ 0.99999, but only to 1.8e-3 where both G1 ≥ 0.999 (the clamp at
a ≥ 1.6 sits in that band) and to 0.54 % overall: the approximation's error reaches +0.31 % per
factor (at a ≈ 1.34) and the two factors add up. The tolerances below are these facts, not
looser conventions: D, F, α = m and the normalisation match to float32 precision.
"""

import numpy as np
import pytest

mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (pip install mitsuba)")

import jax.numpy as jnp  # noqa: E402

import ctfit  # noqa: E402
from ctfit import Params, Structure  # noqa: E402
from ctfit._model.shadowing import smith_rational_g1_reduced  # noqa: E402

pytestmark = pytest.mark.mitsuba

THETAS = np.array([0.0, 5.0, 15.0, 30.0, 45.0, 60.0, 70.0, 80.0, 85.0, 89.0])
PHIS = np.arange(0.0, 360.0, 15.0)
CASES = [(0.05, 0.2, 3.0), (0.2, 1.3, 4.2), (0.5, 2.5, 0.5)]  # (m, eta, k)
STRUCTURE = Structure(lobes=1, geometry="smith", fresnel="conductor", normalization="normalized")


@pytest.fixture(scope="module", autouse=True)
def _variant():
    mi.set_variant("scalar_rgb")


def _directions():
    ti, to, po = (x.ravel() for x in np.meshgrid(THETAS, THETAS, PHIS, indexing="ij"))
    d = lambda t, p: np.stack([np.sin(np.deg2rad(t)) * np.cos(np.deg2rad(p)), np.sin(np.deg2rad(t)) * np.sin(np.deg2rad(p)), np.cos(np.deg2rad(t))], -1)
    # Mitsuba works in float32: both sides get the same float32-rounded vectors.
    return d(ti, np.zeros_like(ti)).astype(np.float32).astype(np.float64), d(to, po).astype(np.float32).astype(np.float64)


def _mitsuba(m, eta, k, l, v):
    """f_r (eval / cosθ_o) and Mitsuba's G for every pair."""
    bsdf = mi.load_dict({"type": "roughconductor", "distribution": "beckmann", "alpha": m, "sample_visible": False, "eta": eta, "k": k})
    distr = mi.MicrofacetDistribution(mi.MicrofacetType.Beckmann, m, False)
    ctx = mi.BSDFContext()
    si = mi.SurfaceInteraction3f()
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    fr = np.zeros(len(l))
    g = np.zeros(len(l))
    for i in range(len(l)):
        si.wi = mi.Vector3f(*l[i])
        wo = mi.Vector3f(*v[i])
        fr[i] = bsdf.eval(ctx, si, wo)[0] / v[i, 2]
        h = l[i] + v[i]
        g[i] = distr.G(si.wi, wo, mi.Vector3f(*(h / np.linalg.norm(h))))
    return fr, g


def _ctfit(m, eta, k, l, v):
    p = Params(m=jnp.asarray([m]), w=jnp.asarray([1.0]), n=jnp.asarray([eta]), k=jnp.asarray([k]))
    r = np.asarray(ctfit.brdf(STRUCTURE, p, ctfit.geometry(jnp.asarray(l), jnp.asarray(v))))[:, 0]
    g1 = lambda d: np.asarray(ctfit.smith_g1_reduced(jnp.asarray(d[:, 2]), jnp.asarray(np.hypot(d[:, 0], d[:, 1])), m)) * d[:, 2]
    return r, g1(l), g1(v)


@pytest.fixture(scope="module")
def comparison():
    l, v = _directions()
    out = []
    for m, eta, k in CASES:
        fr, g_mi = _mitsuba(m, eta, k, l, v)
        r, g1l, g1v = _ctfit(m, eta, k, l, v)
        # Compare where Mitsuba returns a value (it zeroes D·cos < 1e-20, far in the tail).
        ok = fr > 1e-12 * fr.max()
        out.append(dict(m=m, fr=fr[ok], g_mi=g_mi[ok], r=r[ok], g1l=g1l[ok], g1v=g1v[ok], zero_r=r[~ok], peak=fr.max()))
    return out


def test_d_f_and_normalisation_agree_to_float32_precision(comparison):
    """With each side's own G divided out, Mitsuba and ctfit agree to 1e-4 everywhere."""
    for c in comparison:
        ours = c["r"] / (c["g1l"] * c["g1v"])
        theirs = c["fr"] / c["g_mi"]
        rel = np.abs(ours / theirs - 1)
        assert rel.max() < 1e-4, (c["m"], rel.max())


def test_full_brdf_where_both_g1_are_one(comparison):
    """Where both exact G1 ≥ 1 − 1e-5 (Mitsuba's G1 is exactly 1 there), the BRDFs agree to 1e-4."""
    n = 0
    for c in comparison:
        sel = (c["g1l"] >= 1 - 1e-5) & (c["g1v"] >= 1 - 1e-5)
        n += sel.sum()
        rel = np.abs(c["r"][sel] / c["fr"][sel] - 1)
        assert rel.max() < 1e-4, (c["m"], rel.max())
    assert n > 1000


def test_full_brdf_where_both_g1_exceed_0999(comparison):
    """Where both G1 ≥ 0.999 the difference is Mitsuba's clamp G1 = 1 for a ≥ 1.6 (exact: ≥ 0.9982).

    So it is bounded by 2 × 0.18 %, and after Mitsuba's G is divided out it vanishes (test above).
    """
    for c in comparison:
        sel = (c["g1l"] >= 0.999) & (c["g1v"] >= 0.999)
        rel = np.abs(c["r"][sel] / c["fr"][sel] - 1)
        g_err = np.abs(c["g_mi"][sel] / (c["g1l"][sel] * c["g1v"][sel]) - 1)
        assert rel.max() < 2 * 0.0018 + 1e-4, (c["m"], rel.max())
        np.testing.assert_allclose(rel, g_err, atol=1e-4)


def test_full_brdf_everywhere_within_the_g1_approximation_error(comparison):
    """Everywhere within (1 + 0.0032)² − 1 = 0.64 %: Mitsuba's G1 errs by up to +0.31 % per factor.

    (The 0.5 % asked for does not hold: measured 0.54 % for m = 0.2 and 0.5, both directions near
    a ≈ 1.34 where the rational approximation is furthest off.)
    """
    worst = 0.0
    for c in comparison:
        rel = np.abs(c["r"] / c["fr"] - 1)
        worst = max(worst, rel.max())
        assert rel.max() < 0.0064, (c["m"], rel.max())
        # And where Mitsuba returns 0 (the far tail) ctfit is negligible too.
        assert np.all(c["zero_r"] <= 1e-12 * c["peak"] * 1.0001)
    assert worst > 0.003  # the approximation's error is really there (else the test is moot)


def test_mitsuba_g1_is_a_rational_approximation_of_the_exact_form():
    """Mitsuba's smith_g1 against ctfit's exact erf form: within 0.32 %, and 1 for a ≥ 1.6."""
    m = 0.3
    distr = mi.MicrofacetDistribution(mi.MicrofacetType.Beckmann, m, False)
    theta = np.linspace(0.5, 89.5, 179)
    v = np.stack([np.sin(np.deg2rad(theta)), np.zeros_like(theta), np.cos(np.deg2rad(theta))], -1).astype(np.float32).astype(np.float64)
    ours = np.asarray(ctfit.smith_g1_reduced(jnp.asarray(v[:, 2]), jnp.asarray(v[:, 0]), m)) * v[:, 2]
    theirs = np.array([distr.smith_g1(mi.Vector3f(*d), mi.Vector3f(0, 0, 1)) for d in v])
    a = v[:, 2] / (m * v[:, 0])
    rel = theirs / ours - 1
    assert np.abs(rel).max() < 0.0032
    assert np.all(theirs[a >= 1.6] == 1.0)
    assert np.abs(rel).max() > 0.002


@pytest.mark.parametrize("eta, k", [(0.2, 3.0), (1.3, 4.2), (2.5, 0.5), (1.5, 0.0)])
def test_fresnel_conductor_agrees(eta, k):
    c = np.linspace(0.0, 1.0, 41).astype(np.float32)
    theirs = np.array([mi.fresnel_conductor(float(x), mi.Complex2f(eta, k)) for x in c])
    ours = np.asarray(ctfit.fresnel_conductor(jnp.asarray(c, jnp.float64), eta, k))
    np.testing.assert_allclose(theirs, ours, rtol=2e-5, atol=1e-6)


def test_rational_g1_is_mitsuba_s_smith_g1():
    """``geometry="smith-rational"`` evaluates Mitsuba's own G1 (Walter et al. 2007, eq. 27):
    equal to float32 precision at every angle and m, including the switch to 1 at a = 1.6."""
    theta = np.linspace(0.5, 89.5, 179)
    v = np.stack([np.sin(np.deg2rad(theta)), np.zeros_like(theta), np.cos(np.deg2rad(theta))], -1).astype(np.float32).astype(np.float64)
    for m in (0.02, 0.15, 0.3, 0.8):
        distr = mi.MicrofacetDistribution(mi.MicrofacetType.Beckmann, m, False)
        ours = np.asarray(smith_rational_g1_reduced(jnp.asarray(v[:, 2]), jnp.asarray(v[:, 0]), m)) * v[:, 2]
        theirs = np.array([distr.smith_g1(mi.Vector3f(*d), mi.Vector3f(0, 0, 1)) for d in v])
        np.testing.assert_allclose(ours, theirs, rtol=2e-6, err_msg=f"m = {m}")


def test_smith_rational_brdf_is_mitsuba_s_everywhere(comparison):
    """With the rational G1 the whole BRDF agrees with Mitsuba's roughconductor to float32
    precision everywhere (the exact G1's 0.54 % model difference is gone)."""
    l, v = _directions()
    st = Structure(lobes=1, geometry="smith-rational", fresnel="conductor", normalization="normalized")
    for (m, eta, k), _ in zip(CASES, comparison):
        p = Params(m=jnp.asarray([m]), w=jnp.asarray([1.0]), n=jnp.asarray([eta]), k=jnp.asarray([k]))
        r = np.asarray(ctfit.brdf(st, p, ctfit.geometry(jnp.asarray(l), jnp.asarray(v))))[:, 0]
        fr, _ = _mitsuba(m, eta, k, l, v)
        ok = fr > 1e-12 * fr.max()
        assert np.abs(r[ok] / fr[ok] - 1).max() < 1e-4, m
