"""The Cook–Torrance BRDF R = s R_s + d R_d (Cook & Torrance 1982, eqs. 1–2, 5).

R_s = K · F(V·H, λ) · Σ_j w_j D̂(α; m_j) G_j / ((N·L)(N·V)) with K = 1/(4π) ("normalized") or
1/π ("cook-torrance-1982"), D̂ the distribution without its 1/π (``_distribution``), G the
shadowing term (``_shadowing``; shared by all lobes for the V-cavity, per lobe for Smith).
R_d is F0/π, a spectrum, or a constant; a plastic's R_d may instead be seen through its dielectric
interface, weighted by the Fresnel transmission in and out (:func:`transmitted_diffuse_factor`).
Values are in sr⁻¹, not multiplied by any cosine,
and 0 for directions on or below the horizon.

Work is split by what it depends on: everything that depends on the direction only — D̂, G and
the lobe sum — is computed once per direction (:func:`specular_geometric`), and the spectral part
(F and R_d) per band. Only the terms the :class:`~ctfit.Structure` uses are traced. Each function takes ``xp``, the array
module: ``jax.numpy`` (the default: traceable, differentiable) or ``numpy`` (on the host, no
program; the geometry then from :func:`~ctfit.geometry` with ``xp=numpy`` too).
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .directions import Geometry
from .distribution import beckmann, gaussian
from .fresnel_equations import (
    f0_from_n,
    f0_from_nk,
    fresnel_conductor,
    fresnel_dielectric,
    fresnel_dielectric_f0,
    fresnel_diffuse_reflectance,
)
from .material import Params, Structure, used
from .numerics import array_module
from .shadowing import smith_g1_reduced, smith_rational_g1_reduced, v_cavity_reduced

__all__ = [
    "brdf",
    "brdf_pairs",
    "specular_geometric",
    "fresnel",
    "normal_reflectance",
    "diffuse_reflectance",
    "ambient_reflectance",
    "specular_constant",
    "transmitted_diffuse_factor",
]

_INV_PI = 0.3183098861837907


def specular_constant(structure: Structure) -> float:
    """K in R_s = K F D̂ G/((N·L)(N·V)): 1/(4π) normalised, 1/π for the paper's literal form.

    Examples
    --------
    >>> import ctfit
    >>> print(f"{ctfit.specular_constant(ctfit.Structure()):.6f}")  # 1/(4π)
    0.079577
    >>> print(f"{ctfit.specular_constant(ctfit.Structure(normalization='cook-torrance-1982')):.6f}")  # 1/π
    0.318310
    """
    return 0.25 * _INV_PI if structure.normalization == "normalized" else _INV_PI


def _distribution(structure: Structure, tan2: ArrayLike, m: ArrayLike, xp: Any) -> Array:
    if structure.distribution == "beckmann":
        return beckmann(tan2, m, xp=xp)
    return gaussian(tan2, m, normalized=structure.normalization == "normalized", xp=xp)


def specular_geometric(structure: Structure, params: Params, geom: Geometry, *, xp: Any = jnp) -> Float[Array | np.ndarray, "*batch"]:
    """K Σ_j w_j D̂(α; m_j) G_j/((N·L)(N·V)) per direction: everything in R_s but F.

    Examples
    --------
    Seen and lit along the normal (α = 0, D̂ = 1/m², G = 1) one lobe gives K/m² = 1/(4π · 0.25):

    >>> import numpy as np, ctfit
    >>> peak = ctfit.geometry_from_angles_deg(0.0, 0.0, 0.0, 0.0)
    >>> p = ctfit.Params(m=np.array([0.5]), w=np.array([1.0]), f0=np.array([0.04]))
    >>> print(f"{float(ctfit.specular_geometric(ctfit.Structure(), p, peak)):.6f}")  # 1/π
    0.318310
    """
    m, w = used(params.m), used(params.w)
    # The lobe sum (eq. 5) is unrolled (lobes is static and small): no reduce op, so XLA fuses
    # it with F into one loop (and it avoids an XLA CPU miscompilation of a small reduction
    # whose result is broadcast over the bands, see tests/test_brdf.py).
    total: Array | None = None
    for j in range(structure.lobes):
        term = w[j] * _distribution(structure, geom.tan2_h, m[j], xp)
        if structure.geometry != "v-cavity":  # Smith: G1(L) G1(V) per lobe, exact or rational
            g1 = smith_g1_reduced if structure.geometry == "smith" else smith_rational_g1_reduced
            term = term * g1(geom.cos_l, geom.sin_l, m[j], xp=xp) * g1(geom.cos_v, geom.sin_v, m[j], xp=xp)
        total = term if total is None else total + term
    if structure.geometry == "v-cavity":
        total = v_cavity_reduced(geom.cos_l, geom.cos_v, geom.cos_h, geom.cos_vh, xp=xp) * used(total)
    return specular_constant(structure) * used(total)


def fresnel(structure: Structure, params: Params, cos_vh: Float[ArrayLike, "*batch #bands"], *, xp: Any = jnp) -> Float[Array, "*batch bands"]:
    """F(V·H) with the material's Fresnel form; ``cos_vh`` broadcasts against the band axis.

    Examples
    --------
    At normal incidence (V·H = 1) F is the normal reflectance F0; at grazing incidence it is 1:

    >>> import numpy as np, ctfit
    >>> p = ctfit.Params(m=np.array([0.3]), w=np.array([1.0]), f0=np.array([0.04, 0.9]))
    >>> np.asarray(ctfit.fresnel(ctfit.Structure(), p, np.array([[1.0], [0.0]])), float).round(6).tolist()
    [[0.04, 0.9], [1.0, 1.0]]
    """
    if structure.fresnel == "f0":
        return fresnel_dielectric_f0(cos_vh, used(params.f0), xp=xp)
    if structure.fresnel == "n":
        return fresnel_dielectric(cos_vh, used(params.n), xp=xp)
    return fresnel_conductor(cos_vh, used(params.n), used(params.k), xp=xp)


def normal_reflectance(structure: Structure, params: Params) -> Float[Array | np.ndarray, "*bands"]:
    """F0 per band from whichever Fresnel parameters the material has.

    Examples
    --------
    A real index n gives F0 = ((n − 1)/(n + 1))²:

    >>> import numpy as np, ctfit
    >>> p = ctfit.Params(m=np.array([0.3]), w=np.array([1.0]), n=np.array([1.5, 2.0]))
    >>> np.asarray(ctfit.normal_reflectance(ctfit.Structure(fresnel="n"), p), float).round(6).tolist()
    [0.04, 0.111111]
    """
    if structure.fresnel == "f0":
        return used(params.f0)
    if structure.fresnel == "n":
        return f0_from_n(used(params.n))
    return f0_from_nk(used(params.n), used(params.k))


def diffuse_reflectance(structure: Structure, params: Params) -> Float[Array | np.ndarray, "*bands"]:
    """R_d in sr⁻¹ per band (or scalar): F0/π, the ``rd`` spectrum, or the ``rd`` constant.

    Examples
    --------
    The paper's homogeneous material (``diffuse="F0/pi"``) has R_d = F0/π:

    >>> import numpy as np, ctfit
    >>> p = ctfit.Params(s=np.asarray(0.5), m=np.array([0.3]), w=np.array([1.0]), f0=np.array([0.04, 0.9]))
    >>> np.asarray(ctfit.diffuse_reflectance(ctfit.Structure(diffuse="F0/pi"), p), float).round(6).tolist()
    [0.012732, 0.286479]
    """
    if structure.diffuse == "F0/pi" or structure.diffuse is None:
        return normal_reflectance(structure, params) * _INV_PI
    return used(params.rd)


def transmitted_diffuse_factor(
    n: Float[ArrayLike, "*#batch"], cos_l: Float[ArrayLike, "*#batch"], cos_v: Float[ArrayLike, "*#batch"], *, xp: Any = jnp
) -> Float[Array, "*batch"]:
    """T(θ_i) T(θ_o) / (n² (1 − F_dr(1/n))): what multiplies a plastic's R_d when its diffuse light
    crosses the dielectric interface twice (``diffuse="transmitted"``).

    T = 1 − F is the Fresnel transmission of the smooth interface (the paper's F with the real
    index n, at the *surface* normal: cos θ_i = N·L, cos θ_o = N·V); light reflected back inside
    at the interface (the internal diffuse reflectance F_dr(1/n),
    :func:`~ctfit.fresnel_diffuse_reflectance`) returns to the diffuse layer, hence the
    1/(1 − F_dr); 1/n² is the radiance's change of solid angle across the interface. This is
    Mitsuba 3's ``plastic`` diffuse term (``src/bsdfs/plastic.cpp``, linear mode) exactly, and its
    ``roughplastic``'s with the smooth interface's transmission in place of the rough one's
    (equal for smooth surfaces; see docs/fitting.md).

    >>> import numpy as np
    >>> print(f"{float(transmitted_diffuse_factor(1.5, 1.0, 1.0)):.4f}")  # (1 − 0.04)² / (2.25 (1 − 0.597))
    1.0159
    """
    return (1 - fresnel_dielectric(cos_l, n, xp=xp)) * (1 - fresnel_dielectric(cos_v, n, xp=xp)) / (n * n * internal_transmittance(n))


FIT_INDEX_LIMIT = 2.5
"""Up to this index, 1 − F_dr(1/n) is Mitsuba's fit (Egan & Hilgeman); beyond it, where that fit
leaves its range (the factor fell from 0.97 at n = 3 and turned negative at n = 3.9: a negative
BRDF), the exact relation of the two sides of the interface (:func:`internal_transmittance`)."""


def internal_transmittance(n: Float[ArrayLike, "*#batch"]) -> Float[Array, "*batch"]:
    """1 − F_dr(1/n): the fraction of the diffuse light inside a dielectric of index n that
    crosses its interface. Mitsuba 3's fit of F_dr(1/n) up to :data:`FIT_INDEX_LIMIT`; beyond, the
    exact relation (1 − F_dr(n))/n² (reciprocity: what crosses outwards of the light from inside
    equals what crosses inwards, scaled by the solid angles, n²), positive for every n.

    >>> print(f"{float(internal_transmittance(1.5)):.4f}, {float(internal_transmittance(4.0)):.4f}")
    0.4032, 0.0395
    """
    xp = array_module(n)
    n = xp.asarray(n)
    far = xp.greater(n, FIT_INDEX_LIMIT)
    safe = xp.where(far, FIT_INDEX_LIMIT, n)  # (double where: the fit's branch never sees an index it would turn negative at)
    return xp.where(far, (1 - fresnel_diffuse_reflectance(n)) / (n * n), 1 - fresnel_diffuse_reflectance(1 / safe))


def ambient_reflectance(structure: Structure, params: Params) -> Float[Array | np.ndarray, "*bands"]:
    """The paper's ambient reflectance R_a = π R_d (§2.1), R_d as in :func:`diffuse_reflectance`.

    For a material without a diffuse part the default R_d = F0/π is used, so a metal still
    reflects ambient light with its normal reflectance. A transmitted diffuse part
    (:func:`transmitted_diffuse_factor`) reflects π R_d (1 − F_dr(n))² / (n² (1 − F_dr(1/n))) of
    uniform light: its factor averaged over both hemispheres.

    Examples
    --------
    A diffuse surface of albedo ρ = 0.5 (R_d = ρ/π) reflects half the ambient light, a metal F0:

    >>> import numpy as np, ctfit
    >>> matte = ctfit.Params(rd=np.asarray(0.5 / np.pi))
    >>> print(f"{float(ctfit.ambient_reflectance(ctfit.Structure(lobes=0, diffuse='constant'), matte)):.6f}")
    0.500000
    >>> metal = ctfit.Params(m=np.array([0.3]), w=np.array([1.0]), f0=np.array([0.9]))
    >>> np.asarray(ctfit.ambient_reflectance(ctfit.Structure(), metal), float).round(6).tolist()
    [0.9]
    """
    if structure.diffuse == "transmitted":
        n = used(params.n)
        through = (1 - fresnel_diffuse_reflectance(n)) ** 2 / (n * n * internal_transmittance(n))
        return jnp.pi * used(params.rd) * through
    return jnp.pi * diffuse_reflectance(structure, params)


def combine_parts(
    structure: Structure, params: Params, geom_valid: ArrayLike, spec: Any, cos_vh: Any, cos_lv: tuple[ArrayLike, ArrayLike] | None = None,
    *, xp: Any = jnp,
) -> Array:
    """s R_s + d R_d from the per-direction factor ``spec`` (already broadcast to the bands; it and
    ``cos_vh`` are None without a specular part);
    ``cos_lv`` = (N·L, N·V), broadcast like ``spec``, for a transmitted diffuse part."""
    if structure.has_specular:
        rs = fresnel(structure, params, cos_vh, xp=xp) * spec
    if not structure.has_diffuse:
        out = rs
    else:
        rd = diffuse_reflectance(structure, params)
        if structure.diffuse == "transmitted":
            if cos_lv is None:
                raise ValueError("a transmitted diffuse part needs cos_lv = (N·L, N·V)")
            rd = rd * transmitted_diffuse_factor(used(params.n), *cos_lv, xp=xp)
        if structure.has_s:
            s = used(params.s)
            out = s * rs + (1 - s) * rd
        else:
            out = xp.broadcast_to(rd, np.broadcast_shapes(np.shape(geom_valid), np.shape(rd)))
    return xp.where(geom_valid, out, 0)


def brdf(structure: Structure, params: Params, geom: Geometry, *, xp: Any = jnp) -> Float[Array, "*batch bands"]:
    """R for every direction pair × every band: shape ``geom.shape + (bands,)``.

    Per-band fields of ``params`` (f0, n, k, rd) have shape (bands,). D and G are evaluated once
    per direction, F once per (direction, band).

    Examples
    --------
    Lit and seen along the normal, R = F0 K D̂ G/((N·L)(N·V)) = F0/(4π m²), here F0/π; a viewer
    below the horizon sees 0:

    >>> import numpy as np, ctfit
    >>> p = ctfit.Params(m=np.array([0.5]), w=np.array([1.0]), f0=np.array([0.04, 0.9]))
    >>> geom = ctfit.geometry_from_angles_deg(np.zeros(2), 0.0, np.array([0.0, 95.0]), 0.0)
    >>> np.asarray(np.pi * ctfit.brdf(ctfit.Structure(), p, geom), float).round(6).tolist()  # (directions, bands)
    [[0.04, 0.9], [0.0, 0.0]]
    """
    valid = geom.valid[..., None]
    cos_lv = (geom.cos_l[..., None], geom.cos_v[..., None]) if structure.diffuse == "transmitted" else None
    if not structure.has_specular:
        return combine_parts(structure, params, valid, None, None, cos_lv, xp=xp)
    spec = specular_geometric(structure, params, geom, xp=xp)[..., None]
    return combine_parts(structure, params, valid, spec, geom.cos_vh[..., None], cos_lv, xp=xp)


def brdf_pairs(structure: Structure, params: Params, geom: Geometry, band: Int[Array | np.ndarray, "*batch"], *, xp: Any = jnp) -> Float[Array, "*batch"]:
    """R for samples that each have their own direction pair and band index ``band`` (int array).

    The scattered layout of a measurement file: per-band parameters are gathered per sample.

    Examples
    --------
    Two samples lit and seen along the normal, in bands 1 and 0 (R = F0/π there, see :func:`brdf`):

    >>> import numpy as np, ctfit
    >>> p = ctfit.Params(m=np.array([0.5]), w=np.array([1.0]), f0=np.array([0.04, 0.9]))
    >>> geom = ctfit.geometry_from_angles_deg(np.zeros(2), 0.0, np.zeros(2), 0.0)
    >>> np.asarray(np.pi * ctfit.brdf_pairs(ctfit.Structure(), p, geom, np.array([1, 0])), float).round(6).tolist()
    [0.9, 0.04]
    """
    gathered = Params(
        s=params.s,
        m=params.m,
        w=params.w,
        f0=None if params.f0 is None else params.f0[band],
        n=None if params.n is None else params.n[band],
        k=None if params.k is None else params.k[band],
        rd=None if params.rd is None or np.ndim(params.rd) == 0 else params.rd[band],
    )
    cos_lv = (geom.cos_l, geom.cos_v) if structure.diffuse == "transmitted" else None  # only a transmitted diffuse part needs them
    if not structure.has_specular:
        return combine_parts(structure, gathered, geom.valid, None, None, cos_lv, xp=xp)
    spec = specular_geometric(structure, params, geom, xp=xp)
    return combine_parts(structure, gathered, geom.valid, spec, geom.cos_vh, cos_lv, xp=xp)
