"""Geometric attenuation G (shadowing and masking), returned divided by (N·L)(N·V).

The specular term of Cook & Torrance (1982, eq. 2 and §2.2) carries G/((N·L)(N·V)). Both
factors go to 0 at grazing angles while the ratio stays finite, so ctfit computes the ratio
("reduced" G) directly; that keeps R_s finite at θ → 90° in every dtype.

- ``v_cavity_reduced``: the paper's G = min{1, 2(N·H)(N·V)/(V·H), 2(N·H)(N·L)/(V·H)}
  (eq. 8, after Blinn 1977 and Torrance & Sparrow 1967), divided by (N·L)(N·V).
- ``smith_g1_reduced``: beyond the paper, Smith's masking for a Beckmann surface, exact erf
  form G1 = 2 / (1 + erf a + exp(−a²)/(a√π)), a = 1/(m tan θ) (Walter et al. 2007, eq. 25
  integrated exactly), divided by cos θ. The pair G = G1(L) G1(V) is the separable
  shadowing-masking function Mitsuba 3 uses with ``sample_visible = false`` (it evaluates the
  same G1 through a rational approximation of the erf form).
- ``smith_rational_g1_reduced``: the rational approximation of that G1 (Walter et al. 2007,
  eq. 27), G1 ≈ (3.535a + 2.181a²)/(1 + 2.276a + 2.577a²) for a < 1.6 and 1 beyond, divided by
  cos θ — what Mitsuba 3 and many renderers evaluate. Fitting data those renderers made with
  their own G1 removes a model difference of up to 0.31 % per factor.

References
----------
- Smith, B. G. (1967). Geometrical shadowing of a random rough surface. IEEE Trans.
  Antennas Propag. 15(5), 668–671.
- Walter, B., Marschner, S. R., Li, H., Torrance, K. E. (2007). Microfacet Models for
  Refraction through Rough Surfaces. EGSR 2007. doi:10.2312/EGWR/EGSR07/195-206
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
from jax.scipy.special import erf
from jaxtyping import Array, ArrayLike, Float

__all__ = ["v_cavity_reduced", "smith_g1_reduced", "smith_rational_g1_reduced"]

_SQRT_PI = 1.7724538509055159
# erf(30) = 1 and exp(−900) = 0 in every float format: beyond it G1 is exactly 1.
_A_MAX = 30.0


def v_cavity_reduced(
    cos_l: Float[ArrayLike, "*#batch"], cos_v: Float[ArrayLike, "*#batch"], cos_h: Float[ArrayLike, "*#batch"], cos_vh: Float[ArrayLike, "*#batch"],
    *, xp: Any = jnp,
) -> Float[Array, "*batch"]:
    """G/((N·L)(N·V)) = min{1/((N·L)(N·V)), 2(N·H)/((V·H)(N·L)), 2(N·H)/((V·H)(N·V))}.

    Requires N·L > 0, N·V > 0 and V·H > 0 (callers mask other directions). ``xp``: the array
    module, ``jax.numpy`` (traceable) or ``numpy`` (on the host, no program); so for the other
    functions here.

    Examples
    --------
    1 at normal incidence; with light and viewer both at θ (V = L = H) G = 2 cos²θ once θ > 45°,
    which goes to 0 at grazing angles while G/((N·L)(N·V)) stays 2:

    >>> import numpy as np, ctfit
    >>> theta = np.array([0.0, 80.0, 89.9])
    >>> g = ctfit.geometry_from_angles_deg(theta, 0.0, theta, 0.0)
    >>> np.asarray(ctfit.v_cavity_reduced(g.cos_l, g.cos_v, g.cos_h, g.cos_vh), float).round(4).tolist()
    [1.0, 2.0, 2.0]
    """
    # = min{1, 2(N·H)(N·V)/(V·H), 2(N·H)(N·L)/(V·H)} / ((N·L)(N·V)), with two divisions.
    two_h = 2 * cos_h / cos_vh
    return xp.minimum(1, two_h * xp.minimum(cos_l, cos_v)) / (cos_l * cos_v)


def smith_g1_reduced(cos_t: Float[ArrayLike, "*#batch"], sin_t: Float[ArrayLike, "*#batch"], m: Float[ArrayLike, "*#batch"], *, xp: Any = jnp
                     ) -> Float[Array, "*batch"]:
    """Smith's Beckmann G1(θ; m)/cos θ for a direction with cos θ > 0 and sin θ ≥ 0.

    With a = cos θ/(m sin θ), multiplying the exact form through by m sin θ gives

        G1/cos θ = 2√π / (√π cos θ (1 + erf a) + m sin θ exp(−a²)),

    finite at θ = 90° (= 2√π/m) and equal to 1/cos θ once erf a = 1 (a ≥ 30).

    Examples
    --------
    G1 = 1 at normal incidence; on the horizon G1/cos θ = 2√π/m = 7.0898 for m = 0.5:

    >>> import numpy as np, ctfit
    >>> np.asarray(ctfit.smith_g1_reduced(np.array([1.0, 0.0]), np.array([0.0, 1.0]), 0.5), float).round(4).tolist()
    [1.0, 7.0898]
    """
    cos_t, sin_t, m = xp.asarray(cos_t), xp.asarray(sin_t), xp.asarray(m)
    a = cos_t / xp.maximum(m * sin_t, cos_t / _A_MAX)
    if xp is jnp:
        erf_a = erf(a)
    else:
        from scipy.special import erf as host_erf

        erf_a = host_erf(a)
    return 2 * _SQRT_PI / (_SQRT_PI * cos_t * (1 + erf_a) + m * sin_t * xp.exp(-a * a))


_RATIONAL_A_MAX = 1.6  # Walter et al. 2007, eq. 27: G1 = 1 from here on (the rational form is 1.000057 there)


def smith_rational_g1_reduced(
    cos_t: Float[ArrayLike, "*#batch"], sin_t: Float[ArrayLike, "*#batch"], m: Float[ArrayLike, "*#batch"], *, xp: Any = jnp
) -> Float[Array, "*batch"]:
    """Walter et al.'s rational approximation of Smith's Beckmann G1(θ; m), divided by cos θ, for
    a direction with cos θ > 0 and sin θ ≥ 0.

    With c = cos θ and s = m sin θ (so a = c/s), multiplying eq. 27 through by s² gives

        G1/cos θ = (3.535 s + 2.181 c) / (s² + 2.276 c s + 2.577 c²)   for c < 1.6 s,
        G1/cos θ = 1/c                                                 otherwise,

    both finite for c > 0 (= 3.535/s at θ = 90°), so the unselected branch of the ``where`` has
    finite values and derivatives.
    """
    c, s = xp.asarray(cos_t), xp.asarray(m) * xp.asarray(sin_t)
    rational = (3.535 * s + 2.181 * c) / (s * s + 2.276 * c * s + 2.577 * c * c)
    return xp.where(c >= _RATIONAL_A_MAX * s, 1 / c, rational)
