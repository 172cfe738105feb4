"""The reflected intensity of a surface lit by point-like lights and ambient light (paper eq. 1, §2).

Cook & Torrance (1982), eq. 1:

    I_r = I_ia R_a + Σ_l I_il (N·L_l) dω_il (s R_s + d R_d),

with I_il the intensity (radiance) of light l, dω_il the solid angle it subtends, L_l the unit
vector towards it, I_ia the intensity of the ambient light, and R_a the ambient reflectance. The
paper takes R_a = π R_d (§2.1, the hemispherical reflectance of the diffuse part):
:func:`ctfit.ambient_reflectance`, which uses R_d = F0/π for a material without a diffuse
part, so that a metal reflects ambient light with its normal reflectance.

Everything is in world coordinates: the surface normal N and the viewer direction V are given
per point (any batch shape, broadcast against each other), the lights' directions once. Each
light goes through :func:`ctfit.geometry` (with that normal) and :func:`ctfit.brdf`, which is 0
for directions on or below the horizon (N·L ≤ 0 or N·V ≤ 0), so a light behind the surface
adds nothing and silhouette points (N·V = 0) get the ambient term only. The ambient term is
added wherever it is evaluated; the caller decides which points are visible.

Intensities have the units of the light spectra (I_il, I_ia) per band; the bands are those of
the material's per-band parameters (wavelengths or RGB channels). The function is pure JAX:
jit-able, vmap-able and differentiable in the parameters, the directions and the lights.

References
----------
- Cook, R. L. and Torrance, K. E. (1982). A Reflectance Model for Computer Graphics.
  ACM Transactions on Graphics 1(1), 7–24, eq. 1 and §2.1. doi:10.1145/357290.357293
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .cook_torrance import ambient_reflectance, brdf
from .directions import geometry
from .material import Params, Structure

__all__ = ["Light", "reflected_intensity"]


class Light(eqx.Module):
    """A distant light of small solid angle (one term of the sum in eq. 1).

    - ``direction``: (3,) unit vector from the surface towards the light, world coordinates.
    - ``spectrum``: (bands,) intensity I_il per band (a wavelength or an RGB channel), or a
      scalar for the same intensity in every band.
    - ``solid_angle``: dω_il in steradians (scalar).

    Examples
    --------
    The direction is normalised; the spectrum gives I_il per band:

    >>> import ctfit
    >>> light = ctfit.Light([0.0, 0.0, 2.0], [1.0, 0.5], 1e-3)
    >>> light.direction.tolist(), light.spectrum.tolist(), float(light.solid_angle)
    ([0.0, 0.0, 1.0], [1.0, 0.5], 0.001)
    """

    direction: Float[Array | np.ndarray, " 3"]
    spectrum: Float[Array | np.ndarray, "*bands"]
    solid_angle: Float[Array | np.ndarray, ""]

    def __init__(self, direction: Float[ArrayLike, " 3"], spectrum: Float[ArrayLike, "*bands"], solid_angle: Float[ArrayLike, ""]) -> None:
        # NumPy for concrete inputs (no per-light dispatch of tiny JAX ops), JAX for traced ones.
        xp = np if isinstance(direction, (np.ndarray, list, tuple)) else jnp
        d = xp.asarray(direction)
        if not xp.issubdtype(d.dtype, xp.floating):
            d = d.astype(float)
        if d.shape != (3,):
            raise ValueError(f"a light's direction must have shape (3,), got {d.shape}")
        self.direction = d / xp.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        self.spectrum = spectrum if isinstance(spectrum, (np.ndarray, jnp.ndarray)) else np.asarray(spectrum, dtype=float)
        self.solid_angle = solid_angle if isinstance(solid_angle, (np.ndarray, jnp.ndarray)) else np.asarray(solid_angle, dtype=float)
        if np.ndim(self.solid_angle) != 0:
            raise ValueError(f"a light's solid_angle must be a scalar, got shape {np.shape(self.solid_angle)}")


def reflected_intensity(
    structure: Structure,
    params: Params,
    normal: Float[ArrayLike, "*#batch 3"],
    view: Float[ArrayLike, "*#batch 3"],
    lights: Sequence[Light],
    ambient: Float[ArrayLike, "*bands"] | None = None,
) -> Float[Array, "*batch bands"]:
    """I_r (…, bands) of eq. 1 at points with unit ``normal`` and unit ``view`` (…, 3).

    ``lights``: a sequence of :class:`Light` (unrolled: the number of lights is static).
    ``ambient``: the ambient intensity I_ia, (bands,) or a scalar, or None for no ambient term.
    ``normal`` and ``view`` broadcast against each other (e.g. one view direction for an
    orthographic camera). Per-band parameters of ``params`` have shape (bands,).

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from ctfit import Light, Params, Structure, reflected_intensity
    >>> st = Structure(lobes=0, diffuse="constant")
    >>> light = Light(jnp.array([0.0, 0.0, 1.0]), jnp.ones(1), 1e-4)
    >>> I = reflected_intensity(st, Params(rd=jnp.asarray(0.2)), jnp.array([0.0, 0.0, 1.0]), jnp.array([0.0, 0.0, 1.0]), [light])
    >>> round(float(I[0]), 8)  # I dω R_d at normal incidence
    2e-05
    """
    normal = jnp.asarray(normal)
    view = jnp.asarray(view)
    total = None
    for light in lights:
        l = light.direction.astype(normal.dtype)
        geom = geometry(l, view, normal)
        r = brdf(structure, params, geom)  # (…, bands), 0 below the horizon
        # N·L is 1 in the geometry's stand-in for invalid pairs; R is 0 there.
        cos_l = jnp.where(geom.valid, geom.cos_l, 0)[..., None]
        e = jnp.asarray(light.spectrum).astype(r.dtype) * jnp.asarray(light.solid_angle).astype(r.dtype)
        term = e * cos_l * r
        total = term if total is None else total + term
    if ambient is not None:
        ra = ambient_reflectance(structure, params)
        amb = jnp.asarray(ambient) * ra
        shape = jnp.broadcast_shapes(jnp.shape(normal)[:-1], jnp.shape(view)[:-1])
        if total is None:
            total = jnp.broadcast_to(amb, shape + jnp.shape(amb)[-1:] if jnp.ndim(amb) else shape + (1,))
        else:
            total = total + amb
    if total is None:
        raise ValueError("reflected_intensity needs at least one light or an ambient intensity")
    return total
