"""Directions and the per-direction quantities the model needs, computed once per direction pair.

Conventions (stated once here, and in ``docs/conventions.md``):

- The local frame has the surface normal N = +z. θ is the polar angle from N, φ the azimuth
  from +x towards +y. Angles in files and on the command line are in degrees; the functions
  here that take angles say so in their names (``*_deg``).
- L (light, "incident", ``i``) and V (viewer, "outgoing", ``o``) both point *away* from the
  surface. The mirror direction of (θ_i, φ_i) is (θ_i, φ_i + 180°).
- H = (L + V)/|L + V| is the microfacet normal that reflects L into V (paper, §2.2); α is the
  angle between N and H.
- Directions on or below the horizon (N·L ≤ 0 or N·V ≤ 0) have a BRDF of 0.

Everything that depends on direction only (cosines, tan²α, sines for Smith's G) is collected in
:class:`Geometry`, so the spectral part of the model touches each direction once.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

from .numerics import safe_sqrt
from .pytrees import pytree

__all__ = ["Geometry", "geometry", "direction_from_angles_deg", "geometry_from_angles_deg"]


@pytree
@dataclasses.dataclass(frozen=True, eq=False)
class Geometry:
    """Per-direction-pair quantities (all broadcast to one batch shape).

    Fields: ``cos_l`` = N·L, ``cos_v`` = N·V, ``sin_l``, ``sin_v``, ``cos_h`` = N·H,
    ``tan2_h`` = tan²α, ``cos_vh`` = V·H (= L·H), and ``valid`` (both directions strictly
    above the horizon). Invalid entries hold harmless stand-in values (a normal-incidence
    configuration) so that no NaN is produced; the BRDF masks them to 0.

    Examples
    --------
    With the viewer in the mirror direction of the light, H = N (α = 0) and V·H = cos θ_i:

    >>> import ctfit
    >>> g = ctfit.geometry_from_angles_deg(30.0, 0.0, 30.0, 180.0)
    >>> print(f"{float(g.cos_h):.6f} {float(g.tan2_h):.6f} {float(g.cos_vh):.6f} {bool(g.valid)}")
    1.000000 0.000000 0.866025 True
    """

    cos_l: Float[Array, "*batch"]
    cos_v: Float[Array, "*batch"]
    sin_l: Float[Array, "*batch"]
    sin_v: Float[Array, "*batch"]
    cos_h: Float[Array, "*batch"]
    tan2_h: Float[Array, "*batch"]
    cos_vh: Float[Array, "*batch"]
    valid: Bool[Array, "*batch"]


def _components(x: Array) -> tuple[Array, ...]:
    return x[..., 0], x[..., 1], x[..., 2]


def _dot(a: tuple[Array, ...], b: tuple[Array, ...]) -> Array:
    # Written out, not jnp.sum(a * b, -1): no reduce op, so XLA fuses it with the rest (and it
    # avoids an XLA CPU miscompilation of small reductions, see tests/test_brdf.py).
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross_norm2(a: tuple[Array, ...], b: tuple[Array, ...]) -> Array:
    cx = a[1] * b[2] - a[2] * b[1]
    cy = a[2] * b[0] - a[0] * b[2]
    cz = a[0] * b[1] - a[1] * b[0]
    return cx * cx + cy * cy + cz * cz


def geometry(l: Float[ArrayLike, "*#batch 3"], v: Float[ArrayLike, "*#batch 3"], n: Float[ArrayLike, "*#batch 3"] | None = None, *,
             xp: Any = jnp) -> Geometry:
    """Geometry of unit vectors ``l`` (to the light) and ``v`` (to the viewer), shape (..., 3).

    ``n`` is the unit surface normal (default +z). Sines and tan²α come from cross products,
    not from 1 − cos², so they keep full relative precision near normal incidence and at the
    specular peak. ``xp``: the array module, ``jax.numpy`` (traceable), or ``numpy`` for host
    arrays of the inputs' dtype (a fit lays out its data's geometry so: no program to make).

    Examples
    --------
    Light along the normal, viewer at 60°: H lies halfway, α = 30°, so tan²α = 1/3 and V·H = cos 30°:

    >>> import numpy as np, ctfit
    >>> g = ctfit.geometry(np.array([0.0, 0.0, 1.0]), np.array([np.sin(np.pi / 3), 0.0, 0.5]))
    >>> print(f"{float(g.tan2_h):.6f} {float(g.cos_vh):.6f}")
    0.333333 0.866025
    """
    lv: Array = xp.asarray(l)  # (numpy arrays alike, for ``xp=numpy``)
    vv: Array = xp.asarray(v)
    dtype = lv.dtype
    lc, vc = _components(lv), _components(vv)
    if n is None:
        # N = +z: N·x is the z component and |N × x|² = x_x² + x_y².
        cos_l, cos_v = lc[2], vc[2]
    else:
        nc = _components(xp.asarray(n, dtype=dtype))
        cos_l, cos_v = _dot(nc, lc), _dot(nc, vc)
    valid = (cos_l > 0) & (cos_v > 0)
    # Stand-ins for invalid pairs: L = V = N.
    if n is None:
        zero, one = xp.zeros((), dtype), xp.ones((), dtype)
        nc = (zero, zero, one)
    lc = tuple(xp.where(valid, a, b) for a, b in zip(lc, nc))
    vc = tuple(xp.where(valid, a, b) for a, b in zip(vc, nc))
    cos_l = xp.where(valid, cos_l, 1)
    cos_v = xp.where(valid, cos_v, 1)
    hc = tuple(a + b for a, b in zip(lc, vc))
    h_len = xp.sqrt(_dot(hc, hc))  # > 0: both directions are above the horizon
    if n is None:
        h_n = hc[2]
        sin2_l = lc[0] * lc[0] + lc[1] * lc[1]
        sin2_v = vc[0] * vc[0] + vc[1] * vc[1]
        sin2_h = hc[0] * hc[0] + hc[1] * hc[1]
    else:
        h_n = _dot(nc, hc)
        sin2_l, sin2_v, sin2_h = _cross_norm2(nc, lc), _cross_norm2(nc, vc), _cross_norm2(nc, hc)
    return Geometry(
        cos_l=cos_l,
        cos_v=cos_v,
        sin_l=safe_sqrt(sin2_l),
        sin_v=safe_sqrt(sin2_v),
        cos_h=h_n / h_len,
        tan2_h=sin2_h / (h_n * h_n),
        cos_vh=0.5 * h_len,
        valid=valid,
    )


def direction_from_angles_deg(theta: Float[ArrayLike, "*#batch"], phi: Float[ArrayLike, "*#batch"], *, xp: Any = jnp) -> Float[Array, "*batch 3"]:
    """Unit vector(s) for polar angle θ and azimuth φ in degrees, shape (..., 3).

    cos θ is computed as sin(90° − θ), so θ = 90° gives exactly 0 (on the horizon) in every
    dtype, and θ = 0 gives exactly (0, 0, 1). ``xp``: as for :func:`geometry`.

    Examples
    --------
    >>> import numpy as np, ctfit
    >>> np.asarray(ctfit.direction_from_angles_deg(90.0, 0.0)).tolist()  # on the horizon: z is exactly 0
    [1.0, 0.0, 0.0]
    >>> ctfit.direction_from_angles_deg(np.array([0.0, 45.0, 60.0]), 90.0).shape  # θ and φ broadcast
    (3, 3)
    >>> ctfit.direction_from_angles_deg(30.0, np.array([0.0, 90.0, 180.0, 270.0])).shape
    (4, 3)
    """
    theta, phi = xp.broadcast_arrays(xp.asarray(theta), xp.mod(xp.asarray(phi), 360))
    st = xp.sin(xp.deg2rad(theta))
    ct = xp.sin(xp.deg2rad(90 - theta))
    phi_r = xp.deg2rad(phi)
    return xp.stack([st * xp.cos(phi_r), st * xp.sin(phi_r), ct], axis=-1)


def geometry_from_angles_deg(
    theta_i: Float[ArrayLike, "*#batch"], phi_i: Float[ArrayLike, "*#batch"], theta_o: Float[ArrayLike, "*#batch"], phi_o: Float[ArrayLike, "*#batch"], *,
    xp: Any = jnp,
) -> Geometry:
    """:func:`geometry` for angles in degrees (the measurement-CSV convention); ``xp``: as for
    :func:`geometry`.

    Examples
    --------
    Light at 45°: in the mirror direction (φ_o = 180°) H = N, back towards the light (φ_o = 0°)
    H = L, so α is 0° and 45°:

    >>> import numpy as np, ctfit
    >>> g = ctfit.geometry_from_angles_deg(45.0, 0.0, 45.0, np.array([180.0, 0.0]))
    >>> np.asarray(g.tan2_h, float).round(6).tolist()  # tan²α
    [0.0, 1.0]
    """
    return geometry(direction_from_angles_deg(theta_i, phi_i, xp=xp), direction_from_angles_deg(theta_o, phi_o, xp=xp), xp=xp)
