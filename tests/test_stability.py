"""Numerical stability of the model over its whole domain, in float32 and float64.

Values finite and ≥ 0 (exactly 0 on or below the horizon), F in [0, 1], and the gradient with
respect to every parameter (m, w, s, f0, n, k, rd) finite — on a fixed grid of hard cases
(m from 1e-4 to 3, θ from 0 to 90° including 1e-6° and 89.9°, the exact mirror and
retro-reflection directions, V = −L, F0 from 0 to 1, n up to 1e6, k up to 20), on a float32
grid up to θ = 90° − 1e-5° (derivatives in reverse and in forward mode) and on a hypothesis
sweep of the same space. Each check is one compiled, vmapped evaluation of a whole batch.
"""

import functools
import itertools
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as hs
from hypothesis.extra import numpy as hnp

import ctfit
from ctfit import Params, Structure

DTYPES = [jnp.float32, jnp.float64]
THETAS = [0.0, 1e-6, 30.0, 60.0, 85.0, 89.9, 90.0]
MS = [1e-4, 1e-3, 0.00935, 0.05, 0.2, 0.6, 1.0, 3.0]
F0S = [0.0, 1e-8, 0.04, 0.5, 0.98, 1 - 1e-7, 1.0]
N_REAL = [1.0, 1.0001, 1.5, 4.0, 1e3, 1e6]
N_COND = [0.05, 0.2, 1.0, 1.0, 1.5, 3.0, 1e3, 1e6, 1e6]
K_COND = [0.0, 3.0, 0.0, 1e-3, 20.0, 0.5, 20.0, 20.0, 0.0]

# Every pair of (distribution, geometry, Fresnel form) options occurs in some structure (a
# pairwise covering design: 6 structures instead of 12, each one compiled program per dtype).
PAIRWISE = [
    ("beckmann", "v-cavity", "f0"),
    ("gaussian", "smith", "f0"),
    ("beckmann", "smith", "n"),
    ("gaussian", "v-cavity", "n"),
    ("beckmann", "v-cavity", "conductor"),
    ("gaussian", "smith", "conductor"),
]
assert {(d, g) for d, g, _ in PAIRWISE} == set(itertools.product(("beckmann", "gaussian"), ("v-cavity", "smith")))
assert {(d, f) for d, _, f in PAIRWISE} == set(itertools.product(("beckmann", "gaussian"), ("f0", "n", "conductor")))
assert {(g, f) for _, g, f in PAIRWISE} == set(itertools.product(("v-cavity", "smith"), ("f0", "n", "conductor")))
STRUCTURES = [Structure(lobes=1, distribution=d, geometry=g, fresnel=f, diffuse="spectrum") for d, g, f in PAIRWISE]


def _sid(st):
    return f"{st.distribution}-{st.geometry}-{st.fresnel}-{st.diffuse}-{st.normalization}"


def _band_params(st, dtype):
    """Per-band Fresnel parameters: every hard F0 / n / (n, k) value is one band."""
    a = lambda x: jnp.asarray(np.asarray(x, np.float64), dtype)
    if st.fresnel == "f0":
        bands = dict(f0=a(F0S))
    elif st.fresnel == "n":
        bands = dict(n=a(N_REAL))
    else:
        bands = dict(n=a(N_COND), k=a(K_COND))
    nb = len(next(iter(bands.values())))
    if st.diffuse == "spectrum":
        bands["rd"] = a(np.linspace(0, 1 / np.pi, nb))
    if st.has_s:
        bands["s"] = a(0.7)
    return bands


def _directions(dtype, thetas=THETAS):
    """All (θ_i, θ_o) in ``thetas``² at φ_o − φ_i ∈ {180 (mirror plane), 0 (retro plane), 90}, plus V = −L.

    θ_o = θ_i with φ_o = φ_i + 180 is the exact mirror direction, with φ_o = φ_i the exact
    retro-reflection (V = L).
    """
    ti, to, dp = (x.ravel() for x in np.meshgrid(thetas, thetas, [180.0, 0.0, 90.0], indexing="ij"))
    pi = np.full_like(ti, 33.0)
    d = lambda t, p: ctfit.direction_from_angles_deg(jnp.asarray(t, dtype), jnp.asarray(p, dtype))
    l, v = d(ti, pi), d(to, pi + dp)
    lm = d(np.asarray(thetas), np.full(len(thetas), 33.0))
    horizon = (ti >= 90) | (to >= 90)
    return jnp.concatenate([l, lm]), jnp.concatenate([v, -lm]), np.concatenate([horizon, np.ones(len(thetas), bool)])


@functools.partial(jax.jit, static_argnums=0)
def _evaluate(st, m1, bands, l, v):
    """Values (P, B), F (P, B) and gradients w.r.t. every parameter, for one lobe of slope m1."""
    params = Params(m=m1[None], w=jnp.ones(1, m1.dtype), **bands)
    geom = ctfit.geometry(l, v)
    f = ctfit.fresnel(st, params, geom.cos_vh[:, None])

    # The gradient of the sum over every direction and band: a non-finite derivative of any
    # single value makes it non-finite (inf and NaN propagate through the sum).
    def total(p):
        r = ctfit.brdf(st, p, geom)
        return jnp.sum(r), r

    (_, values), grads = jax.value_and_grad(total, has_aux=True)(params)
    return values, f, grads


def _check(values, f, grads, horizon, what):
    values, f = np.asarray(values), np.asarray(f)
    assert np.all(np.isfinite(values)), f"{what}: non-finite values at {np.argwhere(~np.isfinite(values))[:5].tolist()}"
    assert np.all(values >= 0), f"{what}: negative values"
    assert np.all(values[horizon] == 0), f"{what}: non-zero on or below the horizon"
    assert np.all(np.isfinite(f)) and np.all((f >= 0) & (f <= 1)), f"{what}: F outside [0, 1]"
    for name in ("s", "m", "w", "f0", "n", "k", "rd"):
        g = getattr(grads, name)
        if g is not None:
            g = np.asarray(g)
            bad = ~np.isfinite(g)
            assert not bad.any(), f"{what}: d/d{name} not finite at {np.argwhere(bad)[:5].tolist()}"


@pytest.mark.parametrize("dtype", DTYPES, ids=["float32", "float64"])
@pytest.mark.parametrize("st", STRUCTURES, ids=_sid)
def test_hard_grid(st, dtype):
    l, v, horizon = _directions(dtype)
    bands = _band_params(st, dtype)
    for m in MS:
        vals, f, grads = _evaluate(st, jnp.asarray(m, dtype), bands, l, v)
        _check(vals, f, grads, horizon, f"{_sid(st)} {jnp.dtype(dtype).name} m={m}")


# --------------------------------------------------------------------------- float32 at grazing

# θ up to the last float32 below 90° (89.99999°: cos θ = 1.3e-7) and 90° itself, where an
# intermediate of the model's derivative reaches float32's range.
GRAZING_THETAS = [0.0, 45.0, 89.0, 89.99, 89.999, 89.9999, 90 - 1e-5, 90.0]
GRAZING_MS = [1e-4, 1e-3, 1e-2, 0.2, 1.0]
GRAZING_BANDS = {
    "f0": dict(f0=[0.0, 1e-12, 1.0, 1 - 1e-7]),
    "n": dict(n=[1.0, 1 + 1e-7, 1e6]),
    "conductor": dict(n=[1.0, 1 + 1e-7, 1e6, 0.5], k=[0.0, 1e-7, 0.0, 0.0]),
}
GRAZING_STRUCTURES = [
    Structure(lobes=1, geometry="v-cavity", fresnel="f0", diffuse="F0/pi"),
    Structure(lobes=1, geometry="smith", fresnel="f0"),
    Structure(lobes=1, distribution="gaussian", geometry="v-cavity", fresnel="n", diffuse="spectrum"),
    Structure(lobes=1, geometry="smith-rational", fresnel="conductor"),
    Structure(lobes=1, family="plastic", diffuse="transmitted", geometry="smith"),
]


@functools.partial(jax.jit, static_argnums=0)
def _evaluate_both_modes(st, m1, bands, l, v):
    """Values and the derivatives of their sum with respect to every parameter, in reverse mode
    (``jax.grad``) and in forward mode (``jax.jacfwd``, as the fit's Jacobian is taken)."""
    params = Params(m=m1[None], w=jnp.ones(1, m1.dtype), **bands)
    geom = ctfit.geometry(l, v)
    f = ctfit.fresnel(st, params, geom.cos_vh[:, None]) if st.has_specular else None

    def total(p):
        return jnp.sum(ctfit.brdf(st, p, geom))

    return ctfit.brdf(st, params, geom), f, jax.grad(total)(params), jax.jacfwd(total)(params)


@pytest.mark.parametrize("st", GRAZING_STRUCTURES, ids=_sid)
def test_float32_grazing_values_and_derivatives_finite(st):
    """float32, θ up to 90° − 1e-5° and 90°, m from 1e-4, F0 ∈ {0, 1e-12, 1 − 1e-7, 1}, n ∈ {1,
    1 + 1e-7, 10⁶}: values, F and every derivative finite, in reverse and in forward mode.

    Caught (float32): dR/dF0 = ∞ at F0 = 0 in the mirror direction at 89.99999° (m ≥ 0.2, V-cavity:
    dF/dF0 ~ 1/cos⁴ times G/((N·L)(N·V)) ~ 1/cos²); dR/dm = NaN for m = 1e-4 with Smith's G at
    89.9999° (Beckmann's exp(−tan²α/m²) = 0 met an overflowed cotangent); dR/dn = NaN at n = 1 in
    forward mode (and in reverse mode with the V-cavity) at 89.99999°, for a plastic wherever
    θ_i or θ_o is 89.99999°.
    """
    dtype = jnp.float32
    l, v, horizon = _directions(dtype, GRAZING_THETAS)
    a = lambda x: jnp.asarray(np.asarray(x, np.float64), dtype)
    bands = {k: a(x) for k, x in GRAZING_BANDS[st.fresnel].items()}
    if st.shared_index:
        bands = dict(n=a([1.0]))  # a plastic's one index, at its limit 1
    nb = len(next(iter(GRAZING_BANDS[st.fresnel].values())))
    if st.diffuse in ("spectrum", "transmitted"):
        bands["rd"] = a(np.full(nb, 0.1))
    if st.has_s:
        bands["s"] = a(0.7)
    for m in GRAZING_MS:
        vals, f, grads, forward = _evaluate_both_modes(st, a(m), bands, l, v)
        _check(vals, f, grads, horizon, f"{_sid(st)} float32 m={m} reverse")
        _check(vals, f, forward, horizon, f"{_sid(st)} float32 m={m} forward")


# --------------------------------------------------------------------------- huge indices

# A conductor's n or k far beyond any material's (up to the dtype's largest), and a dielectric's n
# far below 1: per band, with every one of the other (0.05, 1, 3) in the other index.
HUGE = {"float32": [1e7, 1e9, 1e20, 3.4e38], "float64": [1e80, 1e155, 1e300, 1.7e308]}
TINY_N = {"float32": [1e-5, 1e-8, 1e-20, 1e-38], "float64": [1e-5, 1e-100, 1e-200, 1e-300]}
HUGE_THETAS = [0.0, 1e-6, 45.0, 89.9, 89.9999, 90 - 1e-5, 90.0]
HUGE_STRUCTURES = [
    Structure(lobes=1, geometry="smith", fresnel="conductor", diffuse="spectrum"),
    Structure(lobes=1, distribution="gaussian", geometry="v-cavity", fresnel="conductor"),
    Structure(lobes=1, geometry="smith", fresnel="n", diffuse="spectrum"),
]


@pytest.mark.parametrize("dtype", DTYPES, ids=["float32", "float64"])
@pytest.mark.parametrize("st", HUGE_STRUCTURES, ids=_sid)
def test_huge_indices_values_and_derivatives_finite(st, dtype):
    """n or k of a conductor up to the dtype's largest value, n of a dielectric down to its least,
    m down to 1e-6: values, F and every derivative finite, in reverse and in forward mode.

    Caught: dR/dn and dR/dk = NaN in reverse mode for a conductor's n or k ≥ 1e7 (float32, m =
    1e-6; ≥ 1e9 for m ≤ 1e-2) or ≥ 1e76 (float64, m ≤ 1e-3); dR/dn = NaN for a dielectric's n ≤
    1e-8 (float32, both modes) or ≤ 1e-100 (float64): F's intermediates grew as n⁴ (the squares of
    n² + k² in R's derivative overflowed), fixed by evaluating F with n, k scaled down."""
    name = jnp.dtype(dtype).name
    l, v, horizon = _directions(dtype, HUGE_THETAS)
    a = lambda x: jnp.asarray(np.asarray(x, np.float64), dtype)
    if st.fresnel == "conductor":
        pairs = [(h, o) for h in HUGE[name] for o in (0.0, 1.0, 3.0)] + [(o, h) for h in HUGE[name] for o in (0.05, 1.0, 3.0)]
        bands = dict(n=a([p[0] for p in pairs]), k=a([p[1] for p in pairs]))
    else:
        bands = dict(n=a(TINY_N[name] + HUGE[name]))
    nb = len(bands["n"])
    if st.diffuse == "spectrum":
        bands["rd"] = a(np.full(nb, 0.1))
    if st.has_s:
        bands["s"] = a(0.7)
    for m in [1e-2, 1e-4, 1e-6]:
        vals, f, grads, forward = _evaluate_both_modes(st, a(m), bands, l, v)
        _check(vals, f, grads, horizon, f"{_sid(st)} {name} m={m} reverse")
        _check(vals, f, forward, horizon, f"{_sid(st)} {name} m={m} forward")


# --------------------------------------------------------------------------- hypothesis sweep

HYP_STRUCTURES = [
    Structure(lobes=1, geometry="smith", fresnel="conductor", diffuse="spectrum"),
    Structure(lobes=1, distribution="gaussian", fresnel="f0", diffuse="F0/pi"),
]
BATCH = 64


@functools.partial(jax.jit, static_argnums=0)
def _evaluate_batch(st, ti, pi, to, po, m, f0, n, k, s, rd):
    """One full configuration per batch element (own directions and own parameters)."""

    def one(ti, pi, to, po, m, f0, n, k, s, rd):
        geom = ctfit.geometry_from_angles_deg(ti[None], pi, to[None], po)
        fres = {"f0": dict(f0=f0[None]), "n": dict(n=n[None]), "conductor": dict(n=n[None], k=k[None])}[st.fresnel]
        extra = dict(rd=rd[None]) if st.diffuse == "spectrum" else {}
        if st.has_s:
            extra["s"] = s

        def r(p):
            return ctfit.brdf(st, p, geom)[0, 0]

        p = Params(m=m[None], w=jnp.ones(1, m.dtype), **fres, **extra)
        return r(p), ctfit.fresnel(st, p, geom.cos_vh[:, None])[0, 0], jax.grad(r)(p)

    return jax.vmap(one)(ti, pi, to, po, m, f0, n, k, s, rd)


def _angles(lo, hi, special):
    return hs.one_of(hs.sampled_from(special), hs.floats(lo, hi, allow_nan=False, width=64))


# 20 examples of 64 configurations each keep the file fast; CTFIT_HYPOTHESIS_EXAMPLES=400 searches deeper.
@settings(
    max_examples=int(os.environ.get("CTFIT_HYPOTHESIS_EXAMPLES", "20")),
    deadline=None,
    database=None,
    derandomize=os.environ.get("CTFIT_HYPOTHESIS_EXAMPLES") is None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(
    data=hs.data(),
    st_index=hs.integers(0, len(HYP_STRUCTURES) - 1),
    dtype=hs.sampled_from(DTYPES),
)
def test_hypothesis_sweep(data, st_index, dtype):
    st = HYP_STRUCTURES[st_index]

    def arr(elements):
        return data.draw(hnp.arrays(np.float64, BATCH, elements=elements))

    ti = arr(_angles(0, 90, [0.0, 1e-6, 89.9, 90 - 1e-5, 90.0]))
    to = arr(_angles(0, 90, [0.0, 1e-6, 89.9, 90 - 1e-5, 90.0]))
    pi = arr(hs.floats(0, 360, allow_nan=False))
    # Relative azimuth: exact mirror (180), exact retro (0), or anything.
    dphi = arr(_angles(-360, 360, [0.0, 180.0, -180.0]))
    # Some elements get θ_o = θ_i: with dphi ∈ {0, 180} those are the exact retro / mirror pairs.
    same = data.draw(hnp.arrays(np.bool_, BATCH))
    to = np.where(same, ti, to)
    m = 10 ** arr(hs.one_of(hs.sampled_from([-4.0, np.log10(0.00935), np.log10(3.0)]), hs.floats(-4, np.log10(3.0))))
    f0 = arr(hs.one_of(hs.sampled_from(F0S), hs.floats(0, 1)))
    n = 10 ** arr(hs.floats(-1.3, 6)) if st.fresnel == "conductor" else 10 ** arr(hs.floats(0, 6))
    k = arr(hs.one_of(hs.sampled_from([0.0, 20.0]), hs.floats(0, 20)))
    s = arr(hs.floats(0, 1))
    rd = arr(hs.floats(0, 1 / np.pi))
    a = lambda x: jnp.asarray(x, dtype)
    vals, f, grads = _evaluate_batch(st, a(ti), a(pi), a(to), a(pi + dphi), a(m), a(f0), a(n), a(k), a(s), a(rd))
    horizon = (np.asarray(a(ti)) >= 90) | (np.asarray(a(to)) >= 90)
    _check(np.asarray(vals)[:, None], np.asarray(f), grads, horizon, f"{_sid(st)} {jnp.dtype(dtype).name}")


@settings(
    max_examples=int(os.environ.get("CTFIT_HYPOTHESIS_EXAMPLES", "10")),
    deadline=None,
    database=None,
    derandomize=os.environ.get("CTFIT_HYPOTHESIS_EXAMPLES") is None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(data=hs.data(), fresnel=hs.sampled_from(["conductor", "n"]), dtype=hs.sampled_from(DTYPES))
def test_hypothesis_huge_indices(data, fresnel, dtype):
    """The hypothesis sweep's space with a conductor's n and k up to the dtype's largest value (10³
    to 10³⁸ in float32, 10³⁰⁸ in float64) and a dielectric's n as far below 1, m down to 1e-6:
    reverse-mode derivatives finite (they were NaN from n = 1e7 in float32, 1e76 in float64)."""
    st = HYP_STRUCTURES[0] if fresnel == "conductor" else HUGE_STRUCTURES[2]
    top = 38.5 if dtype == jnp.float32 else 308.2

    def arr(elements):
        return data.draw(hnp.arrays(np.float64, BATCH, elements=elements))

    ti = arr(_angles(0, 90, [0.0, 1e-6, 89.9, 90 - 1e-5, 90.0]))
    to = np.where(data.draw(hnp.arrays(np.bool_, BATCH)), ti, arr(_angles(0, 90, [0.0, 89.9, 90 - 1e-5])))
    pi = arr(hs.floats(0, 360, allow_nan=False))
    dphi = arr(_angles(-360, 360, [0.0, 180.0]))
    m = 10 ** arr(hs.floats(-6, np.log10(3.0)))
    if fresnel == "conductor":
        n = 10 ** arr(hs.one_of(hs.floats(3, top), hs.floats(-1.3, 1)))
        k = 10 ** arr(hs.one_of(hs.floats(3, top), hs.floats(-3, 1.3)))
    else:
        n, k = 10 ** -arr(hs.floats(3, top)), np.zeros(BATCH)
    zero = np.zeros(BATCH)
    a = lambda x: jnp.asarray(x, dtype)
    vals, f, grads = _evaluate_batch(st, a(ti), a(pi), a(to), a(pi + dphi), a(m), a(zero), a(n), a(k), a(zero + 0.5), a(zero + 0.1))
    horizon = (np.asarray(a(ti)) >= 90) | (np.asarray(a(to)) >= 90)
    _check(np.asarray(vals)[:, None], np.asarray(f), grads, horizon, f"{_sid(st)} {jnp.dtype(dtype).name}")
