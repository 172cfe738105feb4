"""Fresnel reflectance F: the paper's unpolarised dielectric formula and the conductor formula.

Conventions: ``c`` is the cosine of the angle between the viewer (or light) direction and the
microfacet normal H, ``c = V·H`` (Cook & Torrance 1982, eq. 10 and appendix); ``c`` lies in
[0, 1]. Every function broadcasts over any batch shape and keeps the input dtype. The Fresnel
functions take ``xp``, the array module: ``jax.numpy`` (the default: traceable, differentiable)
or ``numpy`` (on the host, no program; the value alone, rounding clipped as in JAX).

The paper's formula (eq. in the appendix, "unpolarised, k = 0"):

    F = ½ (g − c)² / (g + c)² · {1 + [c (g + c) − 1]² / [c (g − c) + 1]²},   g² = n² + c² − 1.

It is evaluated here in terms of ``u = 1/n`` and ``r = (n − 1)/(n + 1) = √F0`` so that every
subtraction that could cancel is done analytically:

    1 − u² = 4 r / (1 + r)²,   G² = (g/n)² = c² + (1 − c²)(1 − u²),
    (g − c)/(g + c) = (1 − u²)/(G + c u)²,
    [c(g + c) − 1]/[c(g − c) + 1] = (c G − (1 − c²) u)/(c G + (1 − c²) u),

and F is written with a factor F0 that makes it exactly linear in F0 near F0 = 0 (so its
derivative stays finite there):

    F = 16 F0 (c² G² + (1 − c²)² u²) / ((1 + r)⁴ (G + c u)⁴ (c G + (1 − c²) u)²),

evaluated with one division by (G + c u)² (c G + (1 − c²) u) (see :func:`_dielectric`). On
the F0 path 1/n = (1 − F0)/(1 + r)², exact as F0 → 1. Against the formula at 50 digits this is
within 16 ulps in float64 (median 2) for n in [1.0001, 10⁶] and c in [10⁻⁶, 1].

This stays finite, with finite derivatives, for F0 in [0, 1] (n from 1 to ∞), at c = 0
(grazing, where F = 1 is set exactly) and c = 1 (normal, F = F0), in float32 and float64, for
every c a direction given in degrees yields (float32: c ≥ cos 89.99999° = 1.3·10⁻⁷). Smaller
c > 0 can still overflow an intermediate: at F0 → 1 below ~10⁻¹⁵ (float32) or 10⁻¹⁵⁰ (float64),
and in :func:`fresnel_conductor` at n = 1, k = 0 below ~10⁻¹⁰ or 10⁻¹⁰⁰.

References
----------
- Cook, R. L. and Torrance, K. E. (1982). A Reflectance Model for Computer Graphics.
  ACM Transactions on Graphics 1(1), 7–24. doi:10.1145/357290.357293
- Born, M. and Wolf, E. Principles of Optics, §1.5.2 (Fresnel formulae) and the chapter
  "Optics of metals" (the conductor form).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .numerics import array_module

__all__ = [
    "f0_from_n",
    "f0_from_nk",
    "n_from_f0",
    "fresnel_dielectric",
    "fresnel_dielectric_f0",
    "fresnel_conductor",
    "fresnel_diffuse_reflectance",
]

# Below this F0 the square root r = √F0 is taken of TINY_F0 instead (F stays exactly linear in
# F0 there, so neither the value nor the derivative notice).
_TINY_F0 = 1e-30


def f0_from_n(n: Float[ArrayLike, "*batch"]) -> Float[Array | np.ndarray, "*batch"]:
    """Normal reflectance of a dielectric, F0 = ((n − 1)/(n + 1))² (paper, eq. in §4).

    NumPy in, NumPy out (float64 kept); otherwise JAX (jit-able, differentiable).

    >>> import numpy as np
    >>> f0_from_n(np.array([1.5, 2.0]))  # glass: 4 %
    array([0.04      , 0.11111111])
    """
    xp = array_module(n)
    index = xp.asarray(n)
    r = (index - 1) / (index + 1)
    return r * r


def f0_from_nk(n: Float[ArrayLike, "*#batch"], k: Float[ArrayLike, "*#batch"]) -> Float[Array | np.ndarray, "*batch"]:
    """Normal reflectance of a conductor, F0 = ((n − 1)² + k²)/((n + 1)² + k²).

    NumPy in, NumPy out (float64 kept); otherwise JAX (jit-able, differentiable). Where n or k
    is so large that the squares overflow (beyond ~1e154 in float64), the same ratio is taken
    of n, k scaled down by the larger of |n| + 1 and |k|.

    >>> import numpy as np
    >>> f0 = f0_from_nk(np.array([0.49366]), np.array([2.962441]))  # copper at 600 nm (Cu table)
    >>> f0.dtype, round(float(f0[0]), 4)
    (dtype('float64'), 0.8206)
    """
    xp = array_module(n, k)
    n, k = xp.asarray(n), xp.asarray(k)
    with np.errstate(over="ignore", invalid="ignore"):  # NumPy's warnings; JAX has none
        f0 = ((n - 1) ** 2 + k * k) / ((n + 1) ** 2 + k * k)
        scale = xp.maximum(xp.abs(n) + 1, xp.abs(k))
        a, b, c = (n - 1) / scale, k / scale, (n + 1) / scale
        return xp.where(xp.isfinite(f0), f0, (a * a + b * b) / (c * c + b * b))


def n_from_f0(f0: Float[ArrayLike, "*batch"]) -> Float[Array | np.ndarray, "*batch"]:
    """The paper's effective index n = (1 + √F0)/(1 − √F0) (k = 0). Infinite at F0 = 1.

    NumPy in, NumPy out (float64 kept); otherwise JAX (jit-able, differentiable).

    >>> import numpy as np
    >>> n_from_f0(np.array([0.04, 1.0]))
    array([1.5, inf])
    """
    xp = array_module(f0)
    r = xp.sqrt(xp.asarray(f0))
    with np.errstate(divide="ignore"):
        return (1 + r) / (1 - r)


def _index_in_range(x: Any, xp: Any = jnp, *, low: bool = False) -> Any:
    """An index (n or k) held within what the formulas can raise to the fourth power without
    overflow: at most a quarter of the dtype's largest value's fourth root (3·10⁷⁶ in float64,
    3.4·10⁸ in float32), and with ``low``, at least its inverse. F of a larger index is then that
    of the bound, which is 1 (a perfect reflector) to within about 2/(n cos θ): in float64 never
    visible, in float32 below its rounding for cos θ > 0.05 and 0.6 % below 1 at cos θ = 10⁻⁶ (no
    material has such an index). Without the bound n = 10²⁰⁰ squared to ∞ and F was NaN. A
    select, not a clip: a clip's derivative multiplies the cotangent by a 0/1 mask (0 · ∞ = NaN)."""
    big = float(np.finfo(xp.result_type(x, 1.0)).max) ** 0.25 / 4
    lower = 1 / big if low else -big
    return xp.where(x > big, big, xp.where(x < lower, lower, x))


def _inverse_scale(x: Any, xp: Any = jnp) -> Any:
    """1/S for the size ``x`` of an index: S = 1 for x < 2¹⁰ (every material: the formulas as
    written), else the power of two S = 2^e > x (frexp: x = μ 2^e, ½ ≤ μ < 1); a constant for
    the derivative. Dividing by S is exact, so a formula of degree 0 in the quantities divided
    gives the same value bit for bit, while none of its intermediates (or their derivatives)
    grows with x."""
    if xp is jnp:
        x = jax.lax.stop_gradient(x)
    return xp.where(x < 2.0**10, 1, xp.ldexp(xp.ones_like(x), -xp.frexp(x)[1]))


def _clip_cos(c: ArrayLike, xp: Any = jnp) -> tuple[Array, Array]:
    """c clipped to [0, 1] (V·H from rounded vectors can exceed 1 by an ulp) and 1 − c²."""
    clipped = xp.clip(xp.asarray(c), 0, 1)
    return clipped, (1 - clipped) * (1 + clipped)


def _unit_interval(f: Array, xp: Any = jnp) -> Array:
    """A reflectance held in [0, 1], which the formulas leave by an ulp at most (F0 = 1: F = 1
    for every c). The rounding is clipped from the value only, so the derivative stays the
    formula's: a clip's derivative is ½ or 0 on its bound, and F0 = 1 and F0 = 0, bounds of the
    fit, would look flat there."""
    if xp is not jnp:
        return xp.clip(f, 0, 1)
    return f + jax.lax.stop_gradient(jnp.clip(f, 0, 1) - f)


def _dielectric(c: Array, a: Array, u: Array, scale: Array, *, tir_possible: bool = True, gcu_min: float = 0.0, inv_s: Any = 1.0,
                xp: Any = jnp) -> Array:
    """Unpolarised dielectric F from c = V·H, a = 1 − u², u = 1/n and ``scale`` = a², or from
    u/S, a/S², scale/S⁴ with ``inv_s`` = 1/S (then G² = c²/S² + (1 − c²) a/S²: F's factors are
    of degree 0 in (u, G) and unchanged; :func:`fresnel_dielectric` takes S ~ 1/n for n < 1).

    ``scale`` is passed separately so the F0 path can write it as 16 F0/(1 + r)⁴, exactly linear
    in F0. ``a`` may be negative (n < 1): then total internal reflection gives F = 1 where
    G² ≤ 0. Every quantity is a sum of non-negative terms except G² for n < 1, so the formula
    loses no precision to cancellation (see the module docstring). It is evaluated as

        F = scale · [1/((G + c u)² (c G + (1 − c²) u))]² · (c² G² + (1 − c²)² u²):

    one division, by a quantity of degree 3 rather than the whole degree-6 denominator, whose
    square (which the derivative of a division needs) would underflow in float32 near grazing;
    written x · (1/y), so the small numerator multiplies the cotangent before 1/y² does.
    ``gcu_min``: G + c u held at least this (see :func:`fresnel_dielectric_f0`).
    """
    c, s2 = _clip_cos(c, xp)
    # At grazing (c = 0) F = 1 for any interface (F0 > 0). It is set exactly; the formula is
    # evaluated at a stand-in c = 1 there (the double-where pattern: no 0/0 in the derivative).
    grazing = c == 0
    c = xp.where(grazing, 1, c)
    s2 = xp.where(grazing, 0, s2)
    c2 = c * c
    g2 = c2 * (inv_s * inv_s) + s2 * a
    if tir_possible:
        tir = g2 <= 0
        g = xp.sqrt(xp.where(tir, 1, g2))
    else:  # a ≥ 0 (n ≥ 1), c > 0 here: g² ≥ c² > 0
        g = xp.sqrt(g2)
    gcu = g + c * u
    if gcu_min > 0:  # a select, not maximum (whose derivative's 0/1 mask meets the cotangent)
        gcu = xp.where(gcu > gcu_min, gcu, gcu_min)
    p = c * g + s2 * u
    inv = 1 / (gcu * gcu * p)
    f = scale * (inv * inv) * (c2 * g2 + s2 * s2 * u * u)
    f = xp.where(grazing, xp.where(scale > 0, 1, 0).astype(f.dtype), f)
    if tir_possible:
        f = xp.where(tir, 1, f)
    return _unit_interval(f, xp)


def fresnel_dielectric_f0(c: Float[ArrayLike, "*#batch"], f0: Float[ArrayLike, "*#batch"], *, xp: Any = jnp) -> Float[Array, "*batch"]:
    """Unpolarised Fresnel reflectance with the paper's effective index from F0 (k = 0).

    Equivalent to ``fresnel_dielectric(c, n_from_f0(f0))`` but finite and differentiable for
    every F0 in [0, 1], including F0 = 1 (n = ∞). F(c = 1) = F0 and F(c = 0) = 1 for F0 > 0.
    1/n = (1 − √F0)/(1 + √F0) is computed as (1 − F0)/(1 + √F0)², which keeps full relative
    precision as F0 → 1 (1 − F0 is exact there).

    Examples
    --------
    >>> import jax.numpy as jnp, numpy as np
    >>> round(float(fresnel_dielectric_f0(jnp.asarray(1.0), jnp.asarray(0.04))), 6)  # F(c = 1) = F0
    0.04
    >>> fresnel_dielectric_f0(np.array([1.0, 0.0]), np.array(0.04), xp=np)  # on the host: NumPy, float64
    array([0.04, 1.  ])
    """
    f0_a: Any = xp.asarray(f0)
    c_a: Any = xp.asarray(c)
    # A select, not jnp.maximum: maximum's derivative multiplies by a 0/1 mask, which turns an
    # infinite cotangent into NaN.
    r = xp.sqrt(xp.where(f0_a > _TINY_F0, f0_a, _TINY_F0))
    one_plus_r2 = (1 + r) * (1 + r)
    u = (1 - f0_a) / one_plus_r2
    a = 4 * r / one_plus_r2
    scale = 16 * f0_a / (one_plus_r2 * one_plus_r2)
    return _dielectric(c_a, a, u, scale, tir_possible=False, gcu_min=_gcu_min(xp.result_type(c_a, f0_a, 1.0)), xp=xp)


def _gcu_min(dtype: Any) -> float:
    """The least G + c u that F's bracket is evaluated with on the F0 path: √ε of ``dtype`` in
    float32, none (0) in float64.

    Near F0 = 0 the appendix formula, F = 16 F0 (c²G² + (1 − c²)² u²)/((1 + r)⁴ (G + c u)⁴
    (c G + (1 − c²) u)²), is linear in F0 with a slope that grows as 1/(G + c u)⁴ → 1/(2c)⁴ at
    grazing (G → c as F0 → 0). R_s multiplies it by G/((N·L)(N·V)) ~ 1/c² (eq. 2), which
    overflowed float32: dR/dF0 = ∞ at F0 = 0, θ = 89.99999° in the mirror direction (a float32
    fit failed there). With G + c u ≥ √ε the slope is at most 16/ε² (1.1·10¹⁵ in float32). G² =
    c² + (1 − c²) a ≥ a = 4r/(1 + r)², so G + c u ≥ √ε already for F0 ≥ (ε/4)²: only F0 below
    that (8.9·10⁻¹⁶, an index n ≈ 1 + 2√F0 that float32 cannot tell from 1) within ~√ε of grazing
    (c < 3.5·10⁻⁴, the last 0.02°) is evaluated otherwise. In float64 the floor r ≥ √_TINY_F0
    already bounds the slope by ~1/_TINY_F0, which R_s's 1/c² (c ≥ 10⁻¹⁷ from angles) leaves
    finite: nothing is held there."""
    eps = float(np.finfo(dtype).eps)
    return float(np.sqrt(eps)) if eps > 4 * np.sqrt(_TINY_F0) else 0.0


def fresnel_dielectric(c: Float[ArrayLike, "*#batch"], n: Float[ArrayLike, "*#batch"], *, xp: Any = jnp) -> Float[Array, "*batch"]:
    """The paper's unpolarised Fresnel reflectance for a real index n (k = 0).

    ``n`` is the ratio of refractive indices (material over the surrounding medium); n < 1
    gives total internal reflection (F = 1) beyond the critical angle.

    >>> import numpy as np
    >>> c = np.cos(np.radians([0.0, 45.0, 90.0]))
    >>> [round(float(v), 4) for v in fresnel_dielectric(c, 1.5)]  # glass: 4 %, 5 % at 45°, 1 at grazing
    [0.04, 0.0502, 1.0]
    """
    index: Any = _index_in_range(xp.asarray(n), xp, low=True)
    # For n < 2⁻¹⁰, u = 1/n and a = 1 − u² are taken divided by S > u and S² (exact: S a power
    # of two); unscaled, a² ~ n⁻⁴ and its derivative overflowed (NaN in dR/dn: float32 n = 10⁻⁸,
    # float64 n = 10⁻¹⁰⁰, held at 3·10⁻⁷⁷).
    inv_s = _inverse_scale(1 / index, xp)
    u = inv_s / index
    a = (index - 1) * (index + 1) * (u * u)
    # n = 1 (no interface, a = 0): F = a² · (…) = 0 and dF/dn = 2a a′ (…) = 0 (appendix formula:
    # (g − c)² = 0 with g = c). The bracket, evaluated at g = c, has a derivative ∝ 1/c⁶ near
    # grazing that overflowed float32 and met the factor a² = 0 in forward mode: NaN in dF/dn at
    # θ = 89.99999°. Double-where: the bracket takes the stand-in a = 1 there (finite with its
    # derivative), and the factor a² = 0 selects F = 0 and dF/dn = 0, the values of n = 1.
    return _dielectric(xp.asarray(c), xp.where(a == 0, 1, a), u, a * a, inv_s=inv_s, xp=xp)


def fresnel_conductor(c: Float[ArrayLike, "*#batch"], n: Float[ArrayLike, "*#batch"], k: Float[ArrayLike, "*#batch"], *, xp: Any = jnp
                      ) -> Float[Array, "*batch"]:
    """Exact unpolarised Fresnel reflectance of a conductor with complex index n + i k.

    Born & Wolf's formulation (as in Mitsuba 3's ``fresnel_conductor``): with
    (a + i b)² = n² − k² − sin²θ + 2 i n k (a, b ≥ 0, a² + b² = |n² − k² − sin²θ + 2 i n k|),

        R_s = ((a − cosθ)² + b²)/((a + cosθ)² + b²),
        R_p = R_s ((a cosθ − sin²θ)² + b² cos²θ)/((a cosθ + sin²θ)² + b² cos²θ),
        F = ½ (R_s + R_p).

    The sums of squares are the textbook numerators a² + b² + cos²θ − 2 a cosθ etc. written
    without cancellation; the smaller of a, b is taken from a b = n k, and near a = cosθ
    a − cosθ = (n² − k² − 1 + b²)/(a + cosθ). Divisions are written x · (1/y), so that in the
    derivative the small x multiplies the cotangent before 1/y² does (no overflow to inf·0 in
    float32 near grazing with n ≈ 1, k ≈ 0). With k = 0 and n ≥ 1 this equals
    :func:`fresnel_dielectric`; at grazing (cos θ = 0) F = 1 unless n = 1, k = 0.

    R_s and R_p are ratios of forms of equal degree in (a, b, cos θ) and in (a cos θ, b cos θ,
    sin²θ): from max(|n| + 1, |k|) = 2¹⁰ on they are evaluated with n, k, a, b divided by a
    power of two S above it (see :func:`_conductor_scaled`), exact, so F is unchanged bit for
    bit while no intermediate of F or of its derivative grows with n or k (before, n = 10⁷ in
    float32 or 10⁷⁶ in float64 overflowed R's reverse-mode derivative: NaN in dR/dn, dR/dk).

    >>> import numpy as np
    >>> c = np.cos(np.radians([0.0, 60.0, 90.0]))
    >>> [round(float(v), 4) for v in fresnel_conductor(c, 0.49366, 2.962441)]  # copper at 600 nm: F0 = 0.8206
    [0.8206, 0.8128, 1.0]
    """
    c, s2 = _clip_cos(c, xp)
    n_a: Any = _index_in_range(xp.asarray(n), xp)
    k_a: Any = _index_in_range(xp.asarray(k), xp)
    # Stand-in c = 1 at grazing (double-where pattern); F is set there at the end.
    grazing = c == 0
    c = xp.where(grazing, 1, c)
    s2 = xp.where(grazing, 0, s2)
    inv_s = _inverse_scale(xp.maximum(xp.abs(n_a) + 1, xp.abs(k_a)), xp)
    f = _conductor_scaled(c, s2, n_a * inv_s, k_a * inv_s, inv_s, xp)
    interface = (n_a != 1) | (k_a != 0)
    f = xp.where(grazing, interface.astype(f.dtype), f)
    return _unit_interval(f, xp)


def _conductor_scaled(c: Any, s2: Any, n: Any, k: Any, inv_s: Any, xp: Any) -> Any:
    """F of :func:`fresnel_conductor` (0 < c ≤ 1, s2 = 1 − c²) from n/S, k/S and ``inv_s`` = 1/S.

    With (a + i b)/S the root of ((n² − k² − sin²θ) + 2 i n k)/S², every term below is that of
    the unscaled formula times 1/S² (R_s: ((a − c)² + b²)/S², with c/S; R_p: ((a c − s²)² + b²
    c²)/S², with s²/S), so the ratios are those of the formula; S a power of two makes each
    scaling exact. n, k here are at most 1 in size where S > 1 (below 2¹⁰ where S = 1).
    """
    c2 = c * c
    cs = c * inv_s
    nk = xp.abs(n * k)
    # t1 = n² − k² − sin²θ. Near n = 1 as (n − 1)(n + 1) + cos²θ ((n − 1) is exact there); for
    # n < cos θ ≤ 1 as n² − sin²θ, whose rounding error (∝ n² + sin²θ) is then the smaller one.
    n2m1 = (n - inv_s) * (n + inv_s)
    k2 = k * k
    t1 = xp.where(cs < n, n2m1 + cs * cs, n * n - s2 * (inv_s * inv_s)) - k2
    q = t1 * t1 + 4 * (nk * nk)
    q_ok = q > 0
    a2b2 = xp.where(q_ok, xp.sqrt(xp.where(q_ok, q, 1)), 0)
    # The larger of a², b² from (a² + b² ± t1)/2 without cancellation, the other from a b = n k.
    big2 = 0.5 * (a2b2 + xp.abs(t1))
    big_ok = big2 > 0
    big = xp.where(big_ok, xp.sqrt(xp.where(big_ok, big2, 1)), 0)
    small = xp.where(big_ok, nk * (1 / xp.where(big_ok, big, 1)), 0)
    pos = t1 >= 0
    a = xp.where(pos, big, small)
    b = xp.where(pos, small, big)
    b2 = b * b
    apc = a + cs  # > 0 (c > 0)
    inv_apc = 1 / apc
    near = (a < 2 * cs) & (cs < 2 * a)
    amc = xp.where(near, (n2m1 - k2 + b2) * inv_apc, a - cs)
    num_s = amc * amc + b2
    den_s = apc * apc + b2  # > 0
    ac = a * c
    sig = s2 * inv_s
    b2c2 = b2 * c2
    num_p = (ac - sig) ** 2 + b2c2
    den_p = (ac + sig) ** 2 + b2c2  # 0 only for n = k = 0 at normal incidence, where R_p = R_s (its limit): ratio 1
    num_p = xp.where(den_p > 0, num_p, 1)
    den_p = xp.where(den_p > 0, den_p, 1)
    # ½ R_s (1 + R_p/R_s) = ½ num_s (den_p + num_p)/(den_s den_p), with one division.
    return 0.5 * num_s * (den_p + num_p) * (1 / (den_s * den_p))


def fresnel_diffuse_reflectance(eta: Float[ArrayLike, "*batch"]) -> Float[Array | np.ndarray, "*batch"]:
    """F_dr(η): the fraction of uniform (diffuse) light that a smooth dielectric interface of
    relative index η reflects, by the fits Mitsuba 3 uses (``fresnel.h``): Egan & Hilgeman (1973)
    for η < 1 (light inside a denser medium), d'Eon & Irving (2011, a polynomial in 1/η) for
    η ≥ 1. Within 0.6 % of the integral 2 ∫ F(μ; η) μ dμ for 1 ≤ η ≤ 2.

    >>> import numpy as np
    >>> np.round(fresnel_diffuse_reflectance(np.array([1.5, 1 / 1.5])), 4)  # outside 9 %, inside 60 %
    array([0.0918, 0.5968])
    """
    xp = array_module(eta)
    e = xp.asarray(eta)
    inv = 1 / e
    inside = 0.0636 * inv + e * (e * -1.4399 + 0.7099) + 0.6681
    outside = 0.919317 + inv * (-3.4793 + inv * (6.75335 + inv * (-7.80989 + inv * (4.98554 + inv * -1.36881))))
    return xp.where(e < 1, inside, outside)
