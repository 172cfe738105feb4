"""Fresnel reflectance F: the paper's unpolarised dielectric formula and the conductor formula.

Conventions: ``c`` is the cosine of the angle between the viewer (or light) direction and the
microfacet normal H, ``c = V·H`` (Cook & Torrance 1982, eq. 10 and appendix); ``c`` lies in
[0, 1]. Every function broadcasts over any batch shape and keeps the input dtype.

The paper's formula (eq. in the appendix, "unpolarised, k = 0"):

    F = ½ (g − c)² / (g + c)² · {1 + [c (g + c) − 1]² / [c (g − c) + 1]²},   g² = n² + c² − 1.

It is evaluated here in terms of ``u = 1/n`` and ``r = (n − 1)/(n + 1) = √F0`` so that every
subtraction that could cancel is done analytically:

    1 − u² = 4 r / (1 + r)²,   G² = (g/n)² = c² + (1 − c²)(1 − u²),
    (g − c)/(g + c) = (1 − u²)/(G + c u)²,
    [c(g + c) − 1]/[c(g − c) + 1] = (c G − (1 − c²) u)/(c G + (1 − c²) u),

and F is written with a single division and a factor F0 that makes it exactly linear in F0 near
F0 = 0 (so its derivative stays finite there):

    F = 16 F0 (c² G² + (1 − c²)² u²) / ((1 + r)⁴ (G + c u)⁴ (c G + (1 − c²) u)²).

This stays finite for F0 in [0, 1] (n from 1 to ∞), at c = 0 (grazing) and c = 1 (normal).

References
----------
- Cook, R. L. and Torrance, K. E. (1982). A Reflectance Model for Computer Graphics.
  ACM Transactions on Graphics 1(1), 7–24. doi:10.1145/357290.357293
- Born, M. and Wolf, E. Principles of Optics, §13.4 (conductor Fresnel equations).
"""

from __future__ import annotations

import jax.numpy as jnp

__all__ = [
    "f0_from_n",
    "f0_from_nk",
    "n_from_f0",
    "fresnel_dielectric",
    "fresnel_dielectric_f0",
    "fresnel_conductor",
]

# Below this F0 the square root r = √F0 is taken of TINY_F0 instead (F stays exactly linear in
# F0 there, so neither the value nor the derivative notice).
_TINY_F0 = 1e-30


def f0_from_n(n):
    """Normal reflectance of a dielectric, F0 = ((n − 1)/(n + 1))² (paper, eq. in §4)."""
    n = jnp.asarray(n)
    r = (n - 1) / (n + 1)
    return r * r


def f0_from_nk(n, k):
    """Normal reflectance of a conductor, F0 = ((n − 1)² + k²)/((n + 1)² + k²)."""
    n, k = jnp.asarray(n), jnp.asarray(k)
    return ((n - 1) ** 2 + k * k) / ((n + 1) ** 2 + k * k)


def n_from_f0(f0):
    """The paper's effective index n = (1 + √F0)/(1 − √F0) (k = 0). Infinite at F0 = 1."""
    r = jnp.sqrt(jnp.asarray(f0))
    return (1 + r) / (1 - r)


def _dielectric(c, r, f0):
    """Unpolarised dielectric F from c = V·H, r = (n − 1)/(n + 1) and F0 = r² (see module doc).

    ``r`` may be negative (n < 1): then total internal reflection gives F = 1 where G² ≤ 0.
    """
    c = jnp.asarray(c)
    c2 = c * c
    s2 = 1 - c2
    one_plus_r = 1 + r
    u = (1 - r) / one_plus_r
    a = 4 * r / (one_plus_r * one_plus_r)  # 1 − u²
    g2 = c2 + s2 * a
    tir = g2 <= 0
    g = jnp.sqrt(jnp.where(tir, 1, g2))
    gcu = g + c * u
    p = c * g + s2 * u
    num = 16 * f0 * (c2 * g2 + s2 * s2 * u * u)
    den = (one_plus_r * one_plus_r * gcu * gcu) ** 2 * (p * p)
    # den = 0 only at grazing (c = 0) with F0 = 0 or F0 = 1: the limit there is 1 unless F0 = 0.
    bad = den <= 0
    f = num / jnp.where(bad, 1, den)
    f = jnp.where(bad, jnp.where(f0 > 0, 1, 0).astype(f.dtype), f)
    f = jnp.where(tir, 1, f)
    return jnp.clip(f, 0, 1)


def fresnel_dielectric_f0(c, f0):
    """Unpolarised Fresnel reflectance with the paper's effective index from F0 (k = 0).

    Equivalent to ``fresnel_dielectric(c, n_from_f0(f0))`` but finite and differentiable for
    every F0 in [0, 1], including F0 = 1 (n = ∞). F(c = 1) = F0 and F(c = 0) = 1 for F0 > 0.

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> float(fresnel_dielectric_f0(jnp.asarray(1.0), jnp.asarray(0.04)))  # doctest: +ELLIPSIS
    0.04...
    """
    f0 = jnp.asarray(f0)
    r = jnp.sqrt(jnp.maximum(f0, _TINY_F0))
    return _dielectric(c, r, f0)


def fresnel_dielectric(c, n):
    """The paper's unpolarised Fresnel reflectance for a real index n (k = 0).

    ``n`` is the ratio of refractive indices (material over the surrounding medium); n < 1
    gives total internal reflection (F = 1) beyond the critical angle.
    """
    n = jnp.asarray(n)
    r = (n - 1) / (n + 1)
    return _dielectric(c, r, r * r)


def fresnel_conductor(c, n, k):
    """Exact unpolarised Fresnel reflectance of a conductor with complex index n + i k.

    Born & Wolf's formulation (as in Mitsuba 3's ``fresnel_conductor``): with
    a² + b² = √((n² − k² − sin²θ)² + 4 n² k²) and a = √(½ (a² + b² + n² − k² − sin²θ)),

        R_s = (a² + b² + cos²θ − 2 a cosθ)/(a² + b² + cos²θ + 2 a cosθ),
        R_p = R_s (a² + b² cos²θ + sin⁴θ − 2 a cosθ sin²θ)/(… + 2 a cosθ sin²θ),
        F = ½ (R_s + R_p).

    With k = 0 and n ≥ 1 this equals :func:`fresnel_dielectric`.
    """
    c = jnp.asarray(c)
    n, k = jnp.asarray(n), jnp.asarray(k)
    c2 = c * c
    s2 = 1 - c2
    t1 = n * n - k * k - s2
    q = t1 * t1 + 4 * n * n * k * k
    qpos = q > 0
    a2b2 = jnp.sqrt(jnp.where(qpos, q, 1))
    a2b2 = jnp.where(qpos, a2b2, 0)
    h = 0.5 * (a2b2 + t1)
    hpos = h > 0
    a = jnp.where(hpos, jnp.sqrt(jnp.where(hpos, h, 1)), 0)
    term1 = a2b2 + c2
    term2 = 2 * c * a
    den_s = term1 + term2
    ok_s = den_s > 0
    rs = jnp.where(ok_s, (term1 - term2) / jnp.where(ok_s, den_s, 1), 1)
    term3 = a2b2 * c2 + s2 * s2
    term4 = term2 * s2
    den_p = term3 + term4
    ok_p = den_p > 0
    rp = rs * jnp.where(ok_p, (term3 - term4) / jnp.where(ok_p, den_p, 1), 1)
    return jnp.clip(0.5 * (rs + rp), 0, 1)
