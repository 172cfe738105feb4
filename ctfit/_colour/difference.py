"""CIELAB (CIE 15:2004 §8.2.1) and the CIEDE2000 colour difference (Sharma, Wu & Dalal 2005,
Color Res. Appl. 30(1), 21–30), in JAX: differentiable, with the double-``where`` guards at
black and at achromatic colours."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._model import float_dtype, safe_sqrt

__all__ = ["XYZ_to_Lab", "delta_E_CIE2000"]


_LAB_EPS = (6 / 29) ** 3


def _lab_f(t: Array) -> Array:
    big = t > _LAB_EPS
    safe = jnp.where(big, t, 1)
    return jnp.where(big, jnp.cbrt(safe), t / (3 * (6 / 29) ** 2) + 4 / 29)


def XYZ_to_Lab(XYZ: Float[ArrayLike, "*batch 3"], white_XYZ: Float[ArrayLike, " 3"]) -> Float[Array, "*batch 3"]:
    """CIELAB (CIE 15:2004 §8.2.1) relative to ``white_XYZ``: L* = 100 for the white. JAX.

    Differentiable at black (the cube root is only taken above (6/29)³).

    >>> import numpy as np
    >>> white = np.array([0.9505, 1.0, 1.089])
    >>> [round(float(v), 2) for v in XYZ_to_Lab(0.18 * white, white)]  # an 18 % grey: L* ≈ 50
    [49.5, 0.0, 0.0]
    """
    x = jnp.asarray(XYZ)
    x = x.astype(float_dtype(x))
    f = _lab_f(x / jnp.asarray(white_XYZ).astype(x.dtype))
    fx, fy, fz = f[..., 0], f[..., 1], f[..., 2]
    return jnp.stack([116 * fy - 16, 500 * (fx - fy), 200 * (fy - fz)], axis=-1)


def _safe_atan2_deg(y: Array, x: Array) -> Array:
    zero = (x == 0) & (y == 0)
    h = jnp.degrees(jnp.arctan2(jnp.where(zero, 0, y), jnp.where(zero, 1, x)))
    return jnp.where(zero, 0, jnp.mod(h, 360))


def delta_E_CIE2000(Lab1: Float[ArrayLike, "*#batch 3"], Lab2: Float[ArrayLike, "*#batch 3"]) -> Float[Array, "*batch"]:
    """CIEDE2000 colour difference (k_L = k_C = k_H = 1; Sharma et al. 2005). JAX.

    Agrees with ``colour.delta_E(..., method="CIE 2000")``; differentiable, with zero gradient
    where both colours are equal or achromatic (the hue terms are switched off there).

    >>> import numpy as np
    >>> round(float(delta_E_CIE2000(np.array([50, 2.6772, -79.7751]), np.array([50, 0, -82.7485]))), 4)  # Sharma's pair 1
    2.0425
    """
    L1, a1, b1 = (jnp.asarray(Lab1)[..., i] for i in range(3))
    L2, a2, b2 = (jnp.asarray(Lab2)[..., i] for i in range(3))
    c_bar = 0.5 * (safe_sqrt(a1 * a1 + b1 * b1) + safe_sqrt(a2 * a2 + b2 * b2))
    c7 = c_bar**7
    g = 0.5 * (1 - safe_sqrt(c7 / (c7 + 25.0**7)))
    a1p, a2p = (1 + g) * a1, (1 + g) * a2
    c1p, c2p = safe_sqrt(a1p * a1p + b1 * b1), safe_sqrt(a2p * a2p + b2 * b2)
    h1p, h2p = _safe_atan2_deg(b1, a1p), _safe_atan2_deg(b2, a2p)
    chroma = c1p * c2p != 0
    dh = h2p - h1p
    dh = jnp.where(dh > 180, dh - 360, jnp.where(dh < -180, dh + 360, dh))
    dh = jnp.where(chroma, dh, 0)
    dL = L2 - L1
    dC = c2p - c1p
    dH = 2 * safe_sqrt(c1p * c2p) * jnp.sin(jnp.radians(dh / 2))
    L_bar = 0.5 * (L1 + L2)
    cp_bar = 0.5 * (c1p + c2p)
    hsum = h1p + h2p
    h_bar = jnp.where(
        jnp.abs(h1p - h2p) <= 180, 0.5 * hsum, jnp.where(hsum < 360, 0.5 * (hsum + 360), 0.5 * (hsum - 360))
    )
    h_bar = jnp.where(chroma, h_bar, hsum)
    t = (
        1
        - 0.17 * jnp.cos(jnp.radians(h_bar - 30))
        + 0.24 * jnp.cos(jnp.radians(2 * h_bar))
        + 0.32 * jnp.cos(jnp.radians(3 * h_bar + 6))
        - 0.20 * jnp.cos(jnp.radians(4 * h_bar - 63))
    )
    d_theta = 30 * jnp.exp(-(((h_bar - 275) / 25) ** 2))
    cp7 = cp_bar**7
    r_c = 2 * safe_sqrt(cp7 / (cp7 + 25.0**7))
    l50 = (L_bar - 50) ** 2
    s_l = 1 + 0.015 * l50 / jnp.sqrt(20 + l50)
    s_c = 1 + 0.045 * cp_bar
    s_h = 1 + 0.015 * cp_bar * t
    r_t = -jnp.sin(jnp.radians(2 * d_theta)) * r_c
    tl, tc, th = dL / s_l, dC / s_c, dH / s_h
    return safe_sqrt(tl * tl + tc * tc + th * th + r_t * tc * th)
