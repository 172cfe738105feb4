"""Fresnel reflectance F (Cook & Torrance 1982, appendix; conductor form after Born & Wolf).

References for the external values (glass, n = 1.5): Fresnel's equations in the form
R_s = sin²(θ_i − θ_t)/sin²(θ_i + θ_t), R_p = tan²(θ_i − θ_t)/tan²(θ_i + θ_t), sin θ_t = sin θ_i/n
(Hecht, E., Optics, §4.6 "The Fresnel equations"; Born, M. and Wolf, E., Principles of Optics,
§1.5.2 "Fresnel formulae"): R = 0.04 at normal incidence; at 45° R_s = 0.0920, R_p = 0.0085,
unpolarised 0.0502; at Brewster's angle θ_B = arctan 1.5 = 56.31° R_p = 0, R_s = 0.1479.
"""

import jax
import jax.numpy as jnp
import mpmath
import numpy as np
import pytest
from helpers import mp_fresnel_conductor, mp_fresnel_dielectric, mp_fresnel_dielectric_f0

import ctfit
from ctfit import f0_from_n, f0_from_nk, n_from_f0

# Jitted once here: one compilation per input shape instead of one per primitive (eager mode).
fresnel_dielectric = jax.jit(ctfit.fresnel_dielectric)
fresnel_dielectric_f0 = jax.jit(ctfit.fresnel_dielectric_f0)
fresnel_conductor = jax.jit(ctfit.fresnel_conductor)

F0S = np.array([0.0, 1e-8, 1e-4, 0.04, 0.2, 0.5, 0.9, 0.98, 1 - 1e-7, 1.0])


def ulps(got, ref):
    got = np.asarray(got, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    return np.abs(got - ref) / np.spacing(np.abs(ref))


# --------------------------------------------------------------------------- closed forms


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_normal_incidence_is_f0(dtype):
    f0 = jnp.asarray(F0S, dtype)
    f = fresnel_dielectric_f0(jnp.ones((), dtype), f0)
    assert f.dtype == dtype
    rtol = 4 * np.finfo(dtype).eps
    np.testing.assert_allclose(np.asarray(f), np.asarray(f0), rtol=rtol, atol=0)
    n = jnp.asarray([1.0001, 1.5, 2.0, 4.0, 1e3, 1e6], dtype)
    np.testing.assert_allclose(np.asarray(fresnel_dielectric(jnp.ones((), dtype), n)), np.asarray(f0_from_n(n)), rtol=rtol)
    k = jnp.asarray([0.0, 0.5, 3.0, 20.0, 1.0, 0.1], dtype)
    np.testing.assert_allclose(np.asarray(fresnel_conductor(jnp.ones((), dtype), n, k)), np.asarray(f0_from_nk(n, k)), rtol=rtol)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_grazing_limit_is_one(dtype):
    """F → 1 as c → 0 for every F0 > 0 (and F = 0 for F0 = 0, no interface)."""
    f0 = jnp.asarray(F0S, dtype)
    f_zero = np.asarray(fresnel_dielectric_f0(jnp.zeros((), dtype), f0))
    np.testing.assert_array_equal(f_zero, np.where(F0S > 0, 1.0, 0.0))
    # Approaching grazing: for 1e-4 ≤ F0 ≤ 0.98 F is within 1 % of 1 at c = 1e-6 and 1 − F
    # decreases over the last decades of c. (For F0 → 1, n → ∞, the Brewster dip of R_p moves
    # to c ≈ 1/n and F comes back to 1 only below that.)
    c = jnp.asarray([1e-3, 1e-4, 1e-5, 1e-6], dtype)[:, None]
    f = np.asarray(fresnel_dielectric_f0(c, f0[(F0S >= 1e-4) & (F0S <= 0.98)]), dtype=np.float64)
    assert np.all(np.diff(1 - f, axis=0) <= 0)
    assert np.all(f[-1] > 0.99)
    # Conductor and real index: also 1 at grazing.
    n = jnp.asarray([1.5, 0.2, 3.0, 1e6], dtype)
    k = jnp.asarray([0.0, 3.0, 20.0, 0.0], dtype)
    np.testing.assert_allclose(np.asarray(fresnel_conductor(jnp.zeros((), dtype), n, k)), 1.0, rtol=4 * np.finfo(dtype).eps)
    np.testing.assert_allclose(np.asarray(fresnel_dielectric(jnp.zeros((), dtype), n[jnp.asarray([0, 2, 3])])), 1.0, rtol=4 * np.finfo(dtype).eps)


def test_glass_against_textbook_values():
    """n = 1.5 (Hecht §4.6; Born & Wolf §1.5.2): F0 = 0.04; 45°: (R_s + R_p)/2 = (0.0920 + 0.0085)/2."""
    # The textbook's sine/tangent form, independent of the paper's g-form used by ctfit.
    ti = np.pi / 4
    tt = np.arcsin(np.sin(ti) / 1.5)
    rs, rp = np.sin(ti - tt) ** 2 / np.sin(ti + tt) ** 2, np.tan(ti - tt) ** 2 / np.tan(ti + tt) ** 2
    assert (round(rs, 4), round(rp, 4)) == (0.0920, 0.0085)
    assert float(fresnel_dielectric(jnp.asarray(np.cos(ti)), 1.5)) == pytest.approx(0.5 * (rs + rp), rel=1e-14)
    for t in np.deg2rad([10.0, 30.0, 60.0, 80.0, 89.0]):
        tt = np.arcsin(np.sin(t) / 1.5)
        ref = 0.5 * (np.sin(t - tt) ** 2 / np.sin(t + tt) ** 2 + np.tan(t - tt) ** 2 / np.tan(t + tt) ** 2)
        assert float(fresnel_dielectric(jnp.asarray(np.cos(t)), 1.5)) == pytest.approx(ref, rel=1e-13)
    n = jnp.asarray(1.5)
    assert float(f0_from_n(n)) == pytest.approx(0.04, rel=1e-15)
    assert float(fresnel_dielectric(jnp.asarray(1.0), n)) == pytest.approx(0.04, rel=1e-15)
    c45 = jnp.asarray(np.cos(np.pi / 4))
    assert float(fresnel_dielectric(c45, n)) == pytest.approx(0.5 * (0.0920 + 0.0085), abs=5e-5)
    assert float(fresnel_dielectric(c45, n)) == pytest.approx(0.0502, abs=5e-5)
    assert float(fresnel_dielectric_f0(c45, jnp.asarray(0.04))) == pytest.approx(0.0502, abs=5e-5)
    assert float(fresnel_conductor(c45, n, 0.0)) == pytest.approx(0.0502, abs=5e-5)
    # Brewster's angle: R_p = 0, R_s = 0.1479 → F = 0.0740.
    cb = jnp.asarray(np.cos(np.arctan(1.5)))
    assert float(fresnel_dielectric(cb, n)) == pytest.approx(0.5 * 0.14793, abs=5e-5)


def test_effective_index_round_trip():
    f0 = jnp.asarray(F0S[1:-1])
    np.testing.assert_allclose(np.asarray(f0_from_n(n_from_f0(f0))), np.asarray(f0), rtol=1e-8)
    assert float(n_from_f0(jnp.asarray(0.04))) == pytest.approx(1.5, rel=1e-14)
    n = jnp.asarray([1.2, 1.5, 3.0])
    np.testing.assert_allclose(np.asarray(f0_from_nk(n, 0.0)), np.asarray(f0_from_n(n)), rtol=1e-15)


def test_numpy_float64_in_gives_the_float64_formulas_whatever_jax_x64():
    """NumPy float64 in, NumPy float64 out, the formulas' values to the last bit, with JAX in
    float32 (as the material files need); JAX input gives the same values in float64."""
    rng = np.random.default_rng(3)
    n = np.concatenate([rng.uniform(0.05, 10.0, 200), [0.0, 1.0, 1e200, 1e300]])
    k = np.concatenate([rng.uniform(0.0, 10.0, 200), [0.0, 0.0, 1e3, 1e300]])
    f0 = np.concatenate([rng.uniform(0.0, 1.0, 200), [0.0, 0.04, 1 - 1e-16, 1.0]])
    with jax.enable_x64(False):
        got = f0_from_n(n), f0_from_nk(n, k), n_from_f0(f0)
    assert all(isinstance(g, np.ndarray) and g.dtype == np.float64 for g in got)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        nk = ((n - 1) ** 2 + k * k) / ((n + 1) ** 2 + k * k)
        np.testing.assert_array_equal(got[0], ((n - 1) / (n + 1)) ** 2)
        np.testing.assert_array_equal(got[2], (1 + np.sqrt(f0)) / (1 - np.sqrt(f0)))  # ∞ at F0 = 1
    finite = np.isfinite(nk)
    np.testing.assert_array_equal(got[1][finite], nk[finite])
    # Where the squares overflow (n = 1e200, 1e300): the same ratio of the scaled values, ≈ 1 there.
    assert list(n[~finite]) == [1e200, 1e300]
    np.testing.assert_allclose(got[1][~finite], 1.0, rtol=1e-12)
    np.testing.assert_array_equal(np.asarray(f0_from_nk(jnp.asarray(n), jnp.asarray(k))), got[1])


# --------------------------------------------------------------------------- against mpmath

N_GRID = np.geomspace(1.0001, 1e6, 37)
C_GRID = np.concatenate([np.geomspace(1e-6, 1, 37), [np.cos(np.pi / 4), 0.5, 0.999, 1 - 1e-9]])


def test_dielectric_against_mpmath_to_a_few_ulps():
    """The paper's formula at 50 digits vs ctfit's cancellation-free rewrite, float64."""
    n, c = np.meshgrid(N_GRID, C_GRID, indexing="ij")
    ref = np.vectorize(lambda c_, n_: float(mp_fresnel_dielectric(c_, n_)))(c, n)
    got = np.asarray(fresnel_dielectric(jnp.asarray(c), jnp.asarray(n)))
    u = ulps(got, ref)
    # Measured: median 2 ulps, max 11 ulps (F near 1 at large n, and the 4th power of G + c/n).
    assert np.median(u) <= 3
    assert u.max() <= 16, (u.max(), n.ravel()[u.argmax()], c.ravel()[u.argmax()])


def test_dielectric_f0_against_mpmath_to_a_few_ulps():
    """F from F0 (effective index n = (1 + √F0)/(1 − √F0), computed at 50 digits from the F0 given)."""
    f0 = np.concatenate([np.asarray(f0_from_n(jnp.asarray(N_GRID))), [1e-12, 0.98, 1 - 1e-7]])
    f, c = np.meshgrid(f0, C_GRID, indexing="ij")
    ref = np.vectorize(lambda c_, f_: float(mp_fresnel_dielectric_f0(c_, f_)))(c, f)
    got = np.asarray(fresnel_dielectric_f0(jnp.asarray(c), jnp.asarray(f)))
    u = ulps(got, ref)
    assert np.median(u) <= 3
    assert u.max() <= 16, (u.max(), f.ravel()[u.argmax()], c.ravel()[u.argmax()])


@pytest.mark.parametrize("k", [0.0, 1e-3, 0.1, 1.0, 3.0, 20.0])
def test_conductor_against_mpmath_complex_formula(k):
    """Against |r_s|², |r_p|² from the complex amplitudes at 50 digits; n from 0.05 to 1e6."""
    ns = np.concatenate([np.geomspace(0.05, 0.99, 8), N_GRID[::3]])
    if k == 0.0:
        ns = ns[ns > 1]  # n < 1 with k = 0: total internal reflection, tested separately
    n, c = np.meshgrid(ns, C_GRID, indexing="ij")
    ref = np.vectorize(lambda c_, n_: float(mp_fresnel_conductor(c_, n_, k)))(c, n)
    got = np.asarray(fresnel_conductor(jnp.asarray(c), jnp.asarray(n), k))
    u = ulps(got, ref)
    assert u.max() <= 16, (u.max(), n.ravel()[u.argmax()], c.ravel()[u.argmax()])


def test_conductor_with_k_zero_equals_dielectric():
    n, c = np.meshgrid(N_GRID, C_GRID, indexing="ij")
    a = np.asarray(fresnel_conductor(jnp.asarray(c), jnp.asarray(n), 0.0))
    b = np.asarray(fresnel_dielectric(jnp.asarray(c), jnp.asarray(n)))
    assert ulps(a, b).max() <= 16


def test_total_internal_reflection_for_n_below_one():
    """n < 1 (light inside the denser medium): F = 1 beyond the critical angle, the formula before."""
    n = 1 / 1.5
    c_crit = np.sqrt(1 - n * n)
    c = np.array([0.0, 0.1, 0.5, c_crit * 0.999, c_crit * 1.001, 0.8, 0.95, 1.0])
    f = np.asarray(fresnel_dielectric(jnp.asarray(c), n))
    assert np.all(f[c < c_crit] == 1.0)
    above = c > c_crit
    ref = np.array([float(mp_fresnel_conductor(ci, n, 0.0)) for ci in c[above]])
    np.testing.assert_allclose(f[above], ref, rtol=1e-12)
    fc = np.asarray(fresnel_conductor(jnp.asarray(c), n, 0.0))
    np.testing.assert_allclose(fc, f, rtol=1e-12)


# --------------------------------------------------------------------------- dtypes, range, bad inputs


def test_float32_agrees_with_float64_and_stays_in_range():
    # Inputs rounded to float32 first, so both dtypes see the same numbers.
    c = np.concatenate([[0.0], np.geomspace(1e-6, 1, 60)]).astype(np.float32).astype(np.float64)
    cc, f0 = np.meshgrid(c, F0S.astype(np.float32).astype(np.float64), indexing="ij")
    f64 = np.asarray(fresnel_dielectric_f0(jnp.asarray(cc), jnp.asarray(f0)))
    f32 = fresnel_dielectric_f0(jnp.asarray(cc, jnp.float32), jnp.asarray(f0, jnp.float32))
    assert f32.dtype == jnp.float32
    f32 = np.asarray(f32, dtype=np.float64)
    assert np.all((f32 >= 0) & (f32 <= 1))
    np.testing.assert_allclose(f32, f64, rtol=2e-6, atol=1e-12)
    n = np.array([0.05, 0.3, 1.0, 1.5, 3.0, 1e3, 1e6])
    k = np.array([0.0, 1e-3, 1.0, 5.0, 20.0])
    cc, nn, kk = np.meshgrid(c, n, k, indexing="ij")
    g64 = np.asarray(fresnel_conductor(jnp.asarray(cc), jnp.asarray(nn), jnp.asarray(kk)))
    g32 = np.asarray(fresnel_conductor(jnp.asarray(cc, jnp.float32), jnp.asarray(nn, jnp.float32), jnp.asarray(kk, jnp.float32)), np.float64)
    assert np.all((g32 >= 0) & (g32 <= 1)) and np.all((g64 >= 0) & (g64 <= 1))
    np.testing.assert_allclose(g32, g64, rtol=2e-5, atol=1e-7)


def test_cosine_slightly_above_one_is_clipped():
    """V·H from rounded unit vectors can exceed 1 by an ulp; F must still be F0."""
    c = jnp.asarray(1 + 2e-16)
    assert float(fresnel_dielectric_f0(c, 0.04)) == pytest.approx(0.04, rel=1e-14)
    assert float(fresnel_conductor(c, 0.2, 3.0)) == pytest.approx(float(f0_from_nk(0.2, 3.0)), rel=1e-14)


@pytest.mark.parametrize("fn", [lambda x: fresnel_dielectric_f0(x, x), lambda x: fresnel_dielectric(x, x), lambda x: fresnel_conductor(x, x, x)])
def test_odd_inputs_do_not_raise(fn):
    x = jnp.asarray([-1.0, 0.0, 1.0, -np.inf, np.inf, np.nan])
    out = fn(x)
    assert out.shape == x.shape


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_gradients_finite_over_the_range(dtype):
    """dF/dF0, dF/dn, dF/dk finite for c ∈ [0, 1], F0 ∈ [0, 1], n up to 1e6, k up to 20.

    Caught: dF/dF0 = NaN at F0 = 0, c = 1e-7 in float32 (maximum's mask times an infinite
    cotangent), and dF/dn = NaN at n = 1, k = 0, c = 1e-7 in float32 (x/y with y² underflowing
    in the derivative); both fixed in ctfit/_model/fresnel_equations.py.
    """
    c = np.concatenate([[0.0, 1e-8, 1e-7, 1e-5], np.linspace(0.01, 1, 12)])
    n = np.array([0.05, 0.7, 1.0, 1.0001, 1.5, 4.0, 1e3, 1e6])
    k = np.array([0.0, 1e-3, 0.5, 3.0, 20.0])
    cc, f0 = (a.ravel() for a in np.meshgrid(c, F0S, indexing="ij"))
    g = jax.jit(jax.vmap(jax.grad(ctfit.fresnel_dielectric_f0, argnums=1)))
    d = np.asarray(g(jnp.asarray(cc, dtype), jnp.asarray(f0, dtype)))
    assert np.all(np.isfinite(d)), (cc[~np.isfinite(d)], f0[~np.isfinite(d)])
    cc, nn, kk = (a.ravel() for a in np.meshgrid(c, n, k, indexing="ij"))
    gc = jax.jit(jax.vmap(jax.grad(ctfit.fresnel_conductor, argnums=(1, 2))))
    dn, dk = (np.asarray(x) for x in gc(jnp.asarray(cc, dtype), jnp.asarray(nn, dtype), jnp.asarray(kk, dtype)))
    bad = ~(np.isfinite(dn) & np.isfinite(dk))
    assert not bad.any(), list(zip(cc[bad], nn[bad], kk[bad]))[:5]
    cc, nn = (a.ravel() for a in np.meshgrid(c, n, indexing="ij"))
    gd = jax.jit(jax.vmap(jax.grad(ctfit.fresnel_dielectric, argnums=1)))
    d = np.asarray(gd(jnp.asarray(cc, dtype), jnp.asarray(nn, dtype)))
    assert np.all(np.isfinite(d)), (cc[~np.isfinite(d)], nn[~np.isfinite(d)])


# cos 89.99999° as float32 computes it from the angle (the last float32 below 90°: 1.33e-7) and as float64 does (1.75e-7), then larger c.
GRAZING_C = [1.3315805e-07, 1.7453292e-07, 1e-6, 1e-4, 0.01]


def test_float32_grazing_derivatives_finite_in_both_modes():
    """float32, c down to cos 89.99999°: F and its derivatives in F0 (F0 ∈ {0, 1e-12, 1 − 1e-7,
    1}), n (n ∈ {1, 1 + 1e-7, 10⁶}) and n, k (k = 0) finite, by ``jax.grad`` and by
    ``jax.jacfwd`` (the fit's Jacobian is forward mode). Caught: dF/dn = NaN at n = 1 in forward
    mode (the factor a² = 0 of the formula times its bracket's overflowed derivative)."""
    c = np.array([0.0, *GRAZING_C, 1.0])
    cases = [(ctfit.fresnel_dielectric_f0, [0.0, 1e-12, 1 - 1e-7, 1.0]), (ctfit.fresnel_dielectric, [1.0, 1 + 1e-7, 1e6]),
             (lambda c, n: ctfit.fresnel_conductor(c, n, 0.0), [1.0, 1 + 1e-7, 1e6])]
    for fn, ps in cases:
        cc, pp = (jnp.asarray(x.ravel(), jnp.float32) for x in np.meshgrid(c, ps, indexing="ij"))
        value = np.asarray(jax.jit(jax.vmap(fn))(cc, pp))
        for mode, diff in (("reverse", jax.grad), ("forward", jax.jacfwd)):
            d = np.asarray(jax.jit(jax.vmap(diff(fn, argnums=1)))(cc, pp))
            bad = ~(np.isfinite(value) & np.isfinite(d))
            assert not bad.any(), (mode, list(zip(np.asarray(cc)[bad], np.asarray(pp)[bad], value[bad], d[bad])))


def test_float32_derivative_in_f0_is_bounded_at_grazing():
    """dF/dF0 at F0 → 0 grows as 1/c⁴ towards grazing; R_s multiplies it by G/((N·L)(N·V)) ~ 1/c²
    (eq. 2), which overflowed float32 at F0 = 0, θ = 89.99999° (dR/dF0 = ∞, a float32 fit failed).
    In float32 the bracket is evaluated with G + c u ≥ √ε (which changes F only for F0 < (ε/4)²,
    an index float32 cannot tell from 1, within 0.02° of grazing), so dF/dF0 ≤ 16/ε² = 1.1e15."""
    grad = jax.jit(jax.vmap(jax.grad(ctfit.fresnel_dielectric_f0, argnums=1)))
    c = np.array([*GRAZING_C, 1e-9, 1e-12])
    cc, f0 = (jnp.asarray(x.ravel(), jnp.float32) for x in np.meshgrid(c, [0.0, 1e-30, 1e-20, 1e-16, 1e-15, 1e-12], indexing="ij"))
    d = np.asarray(grad(cc, f0))
    assert np.all(np.isfinite(d))
    assert np.abs(d).max() <= 1.01 * 16 / np.finfo(np.float32).eps ** 2, list(zip(np.asarray(cc), np.asarray(f0), d))
    # …while F keeps its value: F0 = 0 gives 0, and c = 1 gives F0, whatever the floor.
    assert np.all(np.asarray(ctfit.fresnel_dielectric_f0(cc, jnp.zeros_like(f0))) == 0)
    np.testing.assert_allclose(np.asarray(ctfit.fresnel_dielectric_f0(jnp.ones_like(cc), f0)), np.asarray(f0), rtol=1e-6)


@pytest.mark.parametrize("c", [1.0, 0.7, 0.3, 0.05])
def test_derivative_in_f0_is_the_formula_s_up_to_f0_one(c):
    """dF/dF0 at F0 = 1 and F0 = 0 (bounds of the fit) is the one-sided limit of the formula:
    a clip of the value may not halve or zero it there (the fit sits on these bounds)."""
    grad = jax.grad(lambda f0: ctfit.fresnel_dielectric_f0(jnp.asarray(c), f0))
    for at, inside in ((1.0, 1.0 - 1e-9), (0.0, 1e-20)):
        assert float(grad(jnp.asarray(at))) == pytest.approx(float(grad(jnp.asarray(inside))), rel=1e-5), at


def _mp_log_derivatives(c, n, k, dps=160):
    """(n ∂F/∂n, k ∂F/∂k) of the complex-amplitude formula (as :func:`helpers.mp_fresnel_conductor`)
    by central differences at ``dps`` digits, for n, k up to ~10⁶⁰."""
    with mpmath.workdps(dps):
        c_ = mpmath.mpf(float(c))
        s2 = 1 - c_ * c_

        def f(n_, k_):
            eta = mpmath.mpc(n_, k_)
            eta_ct = mpmath.sqrt(eta * eta - s2)
            ct = eta_ct / eta
            return (abs((c_ - eta_ct) / (c_ + eta_ct)) ** 2 + abs((eta * c_ - ct) / (eta * c_ + ct)) ** 2) / 2

        n_, k_ = mpmath.mpf(float(n)), mpmath.mpf(float(k))
        h = mpmath.mpf(10) ** -40 * max(n_, k_, 1)
        return float(n_ * (f(n_ + h, k_) - f(n_ - h, k_)) / (2 * h)), float(k_ * (f(n_, k_ + h) - f(n_, k_ - h)) / (2 * h))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_derivatives_at_huge_indices_are_the_formula_s(dtype):
    """n ∂F/∂n and k ∂F/∂k of a conductor, in reverse and in forward mode, within 16 ε of the
    formula's for n, k from 10³ to 10⁸ (float32) or 10⁶⁰ (float64), c from 10⁻³ to 1. F is
    evaluated there with n, k scaled down by a power of two; before, float32 gave n ∂F/∂n ≈ 2
    at n = 10⁸ (the formula's: 4·10⁻⁸), its unscaled sums of n⁴-sized terms rounding it away, and
    a large cotangent (R's, for a narrow lobe) overflowed the derivative to NaN in both dtypes."""
    big = [1e3, 1e5, 1e7, 1e8] if dtype is np.float32 else [1e3, 1e5, 1e10, 1e20, 1e60]
    c = [1.0, 0.5, 0.1, 1e-3]
    n_big = np.meshgrid(c, big, [0.0, 1.0, 20.0, *big], indexing="ij")
    k_big = np.meshgrid(c, [0.05, 1.0, 3.0], big, indexing="ij")
    cc, nn, kk = (np.concatenate([a.ravel(), b.ravel()]).astype(dtype) for a, b in zip(n_big, k_big))
    ref = np.array([_mp_log_derivatives(*p) for p in zip(cc, nn, kk)])
    grad = {"reverse": jax.grad, "forward": jax.jacfwd}
    for mode, diff in grad.items():
        dn, dk = (np.asarray(x, np.float64) for x in jax.jit(jax.vmap(diff(ctfit.fresnel_conductor, argnums=(1, 2))))(cc, nn, kk))
        err = np.abs(np.stack([nn * dn, np.where(kk > 0, kk, 1) * dk], 1) - ref) / np.finfo(dtype).eps
        i = err.max(1).argmax()
        assert err.max() <= 16, (mode, err.max(), cc[i], nn[i], kk[i])


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("xp", [np, jnp], ids=["numpy", "jax"])
def test_indices_past_what_squares_hold_give_a_perfect_reflector(xp, dtype):
    """n or k so large (or n so small) that their squares overflow: F finite, 1 away from grazing (a
    perfect reflector, the limit), with finite derivatives; n = k = 0 at normal incidence is that
    limit too (R_p = R_s there: it was ½ from 0/0). Before, n = 10²⁰⁰ gave NaN."""
    c = np.array([1.0, 0.7, 0.3, 0.1, 0.0], dtype)
    big = np.finfo(dtype).max
    with np.errstate(over="ignore"):
        cases = [(ctfit.fresnel_conductor, (dtype(n), dtype(k))) for n, k in ((1e200, 0), (1, 1e200), (1e300, 1e300), (big, 0), (np.inf, np.inf), (0, 0))]
        cases += [(ctfit.fresnel_dielectric, (dtype(n),)) for n in (1e200, np.inf, 1e-300, 1e-40)]
    for fn, args in cases:
        f = np.asarray(fn(c, *args, xp=xp))
        assert np.all(np.isfinite(f)), (fn.__name__, args, f)
        np.testing.assert_allclose(f, 1, atol=5 * np.finfo(dtype).eps, err_msg=f"{fn.__name__}{args}")
    if xp is jnp and dtype is np.float64:
        for fn, args in cases:
            grads = jax.grad(lambda *a: jnp.sum(fn(jnp.asarray(c), *a)), argnums=tuple(range(len(args))))(*map(jnp.asarray, args))
            assert all(np.isfinite(np.asarray(g)) for g in grads), (fn.__name__, args, grads)
