"""Facet-slope distributions D (Cook & Torrance 1982, eqs. 3 and 4 and §2.2).

All functions take ``tan2`` = tan²α, α the angle between the surface normal N and the
microfacet normal H, and the rms slope ``m`` > 0. They return the distribution *without* its
factor 1/π, written D̂ here: the normalisation of ``../docs/conventions.md`` multiplies it in.

- Beckmann (eq. 4): D̂ = exp(−tan²α/m²) / (m² cos⁴α) = exp(−tan²α/m²) (1 + tan²α)² / m².
  The paper's literal D is D̂; the normalised D = D̂/π satisfies ∫ D cos α dω = 1.
- Gaussian (eq. 3): D = c exp(−(α/m)²). ctfit picks c so that D̂ has the same meaning as for
  Beckmann: c = 1/m² in the paper's convention ("cook-torrance-1982", the value of Beckmann's
  D̂ at α = 0) and c = 1/(2π I(m)) with I(m) = ∫₀^{π/2} exp(−α²/m²) cos α sin α dα in the
  normalised one, so that ∫ D cos α dω = 1 there too.

tan²α is computed from the half-vector's components (no 1 − cos² cancellation near the peak)
and clamped at 1e12 (α within 1e-6 rad of 90°): there Beckmann's D̂ is 0 to every precision for
m ≤ 10³ and the Gaussian's equals its value at α = 90° (exp(−(π/2m)²) times the peak).
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

__all__ = ["beckmann", "gaussian", "gaussian_norm_integral"]

_TAN2_MAX = 1e12
# Gauss–Legendre nodes on [0, 1] for the Gaussian normalisation integral.
_GL_X, _GL_W = np.polynomial.legendre.leggauss(64)
_GL_X = 0.5 * (_GL_X + 1.0)
_GL_W = 0.5 * _GL_W


def beckmann(tan2: Float[ArrayLike, "*#batch"], m: Float[ArrayLike, "*#batch"], *, xp: Any = jnp) -> Float[Array, "*batch"]:
    """Beckmann D̂(α; m) = exp(−tan²α/m²)(1 + tan²α)²/m² (paper eq. 4, without 1/π). ``xp``: the
    array module, ``jax.numpy`` (traceable) or ``numpy`` (on the host, no program).

    Examples
    --------
    D̂ = 1/m² at α = 0, and D = D̂/π is normalised: ∫ D cos α dω = ∫₀^{π/2} 2 D̂ cos α sin α dα = 1:

    >>> import numpy as np, ctfit
    >>> print(f"{float(ctfit.beckmann(0.0, 0.5)):.6f}")
    4.000000
    >>> alpha = np.linspace(0, np.pi / 2, 100_001)
    >>> d = np.asarray(ctfit.beckmann(np.tan(alpha) ** 2, 0.3))
    >>> print(f"{np.trapezoid(2 * d * np.cos(alpha) * np.sin(alpha), alpha):.6f}")
    1.000000
    """
    t = xp.minimum(xp.asarray(tan2), _TAN2_MAX)
    inv_m2 = 1 / xp.asarray(m) ** 2  # once per lobe, not per direction
    x = t * inv_m2
    # Eq. 4's exponential is 0 in the dtype beyond x = tan²α/m² > _exp_zero (far from the peak
    # of a narrow lobe: m = 1e-4 at grazing gives x ~ 1e20), and D̂ with it. Its derivative's
    # cotangent (1 + t)²/m² times that of the product (~1e32 in float32 there, times G) overflowed
    # to ∞ and met exp' = 0: NaN in dD̂/dm. Double-where: D̂ = 0 exactly there (the value it had),
    # the formula evaluated at the stand-in t = 0 (finite, and its derivative masked).
    far = x > _exp_zero(x.dtype)
    t = xp.where(far, 0, t)
    return xp.where(far, 0, xp.exp(-xp.where(far, 0, x)) * ((1 + t) * (1 + t)) * inv_m2)


def _exp_zero(dtype: Any) -> float:
    """An x beyond which exp(−x) rounds to 0 in ``dtype`` (e⁻ˣ below half its smallest subnormal)."""
    return float(-np.log(np.finfo(dtype).smallest_subnormal)) + 1.0


def gaussian_norm_integral(m: Float[ArrayLike, "*batch"], *, xp: Any = jnp) -> Float[Array, "*batch"]:
    """J(m) = I(m)/m² with I(m) = ∫₀^{π/2} exp(−α²/m²) cos α sin α dα; J → ½ as m → 0.

    Substituting α = m τ: J(m) = ∫₀^{T} exp(−τ²) sin(2 m τ)/(2 m) dτ with T = min(π/(2m), 9),
    by 64-point Gauss–Legendre quadrature (exact to float64 rounding for all m > 0). ``xp``: as for
    :func:`beckmann`.
    """
    m_a: Any = xp.asarray(m)
    upper = xp.minimum(0.5 * np.pi / m_a, 9.0)
    x = xp.asarray(_GL_X, dtype=upper.dtype)
    w = xp.asarray(_GL_W, dtype=upper.dtype)
    tau = upper[..., None] * x
    integrand = xp.exp(-tau * tau) * xp.sin(2 * m_a[..., None] * tau) / (2 * m_a[..., None])
    return upper * xp.sum(w * integrand, axis=-1)


def _alpha2(t: Array, xp: Any = jnp) -> Array:
    """α² = (arctan √t)², written as t·(arctan(x)/x)² with x = √t so it is smooth at t = 0."""
    small = t < 1e-8
    ts = xp.where(small, 1, t)
    x = xp.sqrt(ts)
    ratio = xp.where(small, 1 - t / 3, xp.arctan(x) / x)
    return t * ratio * ratio


def gaussian(tan2: Float[ArrayLike, "*#batch"], m: Float[ArrayLike, "*#batch"], *, normalized: bool = True, xp: Any = jnp) -> Float[Array, "*batch"]:
    """Gaussian D̂(α; m) = exp(−(α/m)²)/(2 m² J(m)) (normalised) or exp(−(α/m)²)/m² (1982).
    ``xp``: as for :func:`beckmann`.

    Examples
    --------
    Normalised like :func:`beckmann` (∫ D cos α dω = 1 with D = D̂/π); in the paper's form
    (``normalized=False``) the peak is 1/m², Beckmann's:

    >>> import numpy as np, ctfit
    >>> alpha = np.linspace(0, np.pi / 2, 100_001)
    >>> d = np.asarray(ctfit.gaussian(np.tan(alpha) ** 2, 0.3))
    >>> print(f"{np.trapezoid(2 * d * np.cos(alpha) * np.sin(alpha), alpha):.6f}")
    1.000000
    >>> print(f"{float(ctfit.gaussian(0.0, 0.5, normalized=False)):.6f}")
    4.000000
    """
    t = xp.minimum(xp.asarray(tan2), _TAN2_MAX)
    m = xp.asarray(m)
    inv_m2 = 1 / (m * m)  # the constants once per lobe, not per direction
    scale = inv_m2 / (2 * gaussian_norm_integral(m, xp=xp)) if normalized else inv_m2
    return xp.exp(-_alpha2(t, xp) * inv_m2) * scale
