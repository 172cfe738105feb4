"""A fitted material as a glTF 2.0 metallic-roughness material (with KHR_materials_ior and
KHR_materials_specular), and the BRDF that glTF defines for it.

glTF's BRDF (the specification's appendix B, KHR_materials_specular's ``fresnel_mix``), α = roughness²:

- specular_brdf = V D with GGX D = α²/(π ((N·H)²(α² − 1) + 1)²) and the height-correlated Smith
  V = 1/(2 (N·L √((N·V)²(1 − α²) + α²) + N·V √((N·L)²(1 − α²) + α²)));
- metal_brdf = specular_brdf · (c + (1 − c)(1 − V·H)⁵), c = baseColor;
- dielectric_brdf = (1 − S max(fr)) c/π + S fr specular_brdf, fr = f0 + (1 − f0)(1 − V·H)⁵,
  f0 = ((ior − 1)/(ior + 1))², S = specularFactor;
- the material: (1 − metallic) dielectric_brdf + metallic metal_brdf.

GGX is not Beckmann: the roughness is fitted to the fitted specular lobe (its direction-only
part, F = 1) by least squares of f cos θ_o over a grid of 4 × 45 × 31 direction pairs
(θ_i ∈ {10°, 30°, 50°, 70°}, θ_o ∈ {0°, 2°, …, 88°}, φ_o ∈ {0°, 6°, …, 180°}).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.optimize import minimize_scalar

from .._model import Material, Params, ambient_reflectance, evaluate_at, normal_reflectance
from .error_grid import unit_directions
from .rgb_bands import GAMUT_NOTE, band_to_rgb, into_gamut

__all__ = ["fit_ggx_roughness", "gltf_brdf", "gltf_material"]



def _cosines(theta_i, phi_i, theta_o, phi_o):
    l, v = unit_directions(theta_i, phi_i), unit_directions(theta_o, phi_o)
    h = l + v
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    return l[..., 2], v[..., 2], h[..., 2], np.sum(v * h, axis=-1)


def _specular_brdf(alpha, nl, nv, nh):
    a2 = alpha * alpha
    d = a2 / (np.pi * (nh * nh * (a2 - 1) + 1) ** 2)
    vis = 0.5 / (nl * np.sqrt(nv * nv * (1 - a2) + a2) + nv * np.sqrt(nl * nl * (1 - a2) + a2))
    return vis * d


def gltf_brdf(material: dict, theta_i, phi_i, theta_o, phi_o) -> np.ndarray:
    """glTF's BRDF (sr⁻¹) of a :func:`gltf_material` entry at directions in degrees: shape (…, 3).

    Examples
    --------
    A rough white dielectric with no specular layer is Lambertian, c/π:

    >>> import numpy as np
    >>> from ctfit._export.gltf import gltf_brdf
    >>> mat = {"pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0, "roughnessFactor": 1},
    ...        "extensions": {"KHR_materials_specular": {"specularFactor": 0}}}
    >>> (gltf_brdf(mat, 30.0, 0.0, 50.0, 90.0) * np.pi).round(6).tolist()
    [1.0, 1.0, 1.0]
    """
    pbr, ext = material["pbrMetallicRoughness"], material.get("extensions", {})
    base = np.asarray(pbr.get("baseColorFactor", [1, 1, 1, 1])[:3], float)
    metallic, rough = pbr.get("metallicFactor", 1.0), pbr.get("roughnessFactor", 1.0)
    ior = ext.get("KHR_materials_ior", {}).get("ior", 1.5)
    spec = ext.get("KHR_materials_specular", {})
    weight, colour = spec.get("specularFactor", 1.0), np.asarray(spec.get("specularColorFactor", [1, 1, 1]), float)
    nl, nv, nh, vh = (c[..., None] for c in _cosines(theta_i, phi_i, theta_o, phi_o))
    lobe = _specular_brdf(rough * rough, nl, nv, nh)
    schlick = (1 - np.abs(vh)) ** 5
    metal = lobe * (base + (1 - base) * schlick)
    f0 = np.minimum(((ior - 1) / (ior + 1)) ** 2 * colour, 1.0)
    fr = f0 + (1 - f0) * schlick
    dielectric = (1 - weight * np.max(fr, axis=-1, keepdims=True)) * base / np.pi + weight * fr * lobe
    return np.where((nl > 0) & (nv > 0), (1 - metallic) * dielectric + metallic * metal, 0.0)


def _fit_grid():
    ti, to, po = np.meshgrid([10.0, 30.0, 50.0, 70.0], np.arange(0.0, 89.0, 2.0), np.arange(0.0, 181.0, 6.0), indexing="ij")
    return ti.reshape(-1), np.zeros(ti.size), to.reshape(-1), po.reshape(-1)


def fit_ggx_roughness(material: Material) -> float:
    """The glTF roughness (α_GGX = roughness²) whose V D is closest to the material's specular lobe.

    The lobe is Σ w_j K D̂_j G_j/((N·L)(N·V)) with F = 1; least squares of f cos θ_o over the grid
    of the module docstring, roughness in [0.01, 1].

    Examples
    --------
    >>> import numpy as np, ctfit
    >>> from ctfit._export.gltf import fit_ggx_roughness
    >>> mat = ctfit.Material(ctfit.Structure(geometry="smith"), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.9])), channels=("G",))
    >>> 0.4 < fit_ggx_roughness(mat) < 0.5  # α_GGX ≈ m for narrow lobes: roughness ≈ √0.2
    True
    """
    st = dataclasses.replace(material.structure, fresnel="f0", diffuse=None, family="metal")
    p = material.params
    lobe = Material(st, Params(m=np.asarray(p.m, float), w=np.asarray(p.w, float), f0=np.ones(1)), channels=("F=1",))
    grid = _fit_grid()
    target = evaluate_at(lobe, theta_i=grid[0], phi_i=grid[1], theta_o=grid[2], phi_o=grid[3])[..., 0].astype(float)
    nl, nv, nh, _ = _cosines(*grid)
    scale = 4.0 if st.normalization == "cook-torrance-1982" else 1.0

    def loss(r):
        return float(np.sum((nv * (scale * _specular_brdf(r * r, nl, nv, nh) - target)) ** 2))

    return float(minimize_scalar(loss, bounds=(0.01, 1.0), method="bounded", options={"xatol": 1e-6}).x)


def gltf_material(material: Material) -> tuple[dict, list[str]]:
    """The glTF 2.0 ``materials[]`` entry closest to ``material`` (no error: see ``export_material``),
    and what it changes beyond glTF's BRDF, in words: a base colour outside sRGB's gamut
    (desaturated into [0, 1]³ at constant luminance, :func:`~ctfit._export.rgb_bands.into_gamut`),
    a metal's own R_d (glTF's one base colour is F0: its diffuse part becomes F0/π).

    A metal: metallic = s (1 without a diffuse part), baseColor = F0 in linear sRGB, and no
    dielectric specular layer (specularFactor 0), so its diffuse part is (1 − s) F0/π — the
    paper's R_d = F0/π exactly; without a specular part, metallic 0 and baseColor = π R_d.
    A plastic: metallic 0, ior = n (1/n for n < 1: the same f0, and glTF takes ior ≥ 1), specularFactor = s (at most 1), baseColor the diffuse
    part's albedo (1 − s) π R_d × its transmission, over 1 − s F0.

    Examples
    --------
    >>> import numpy as np, ctfit
    >>> from ctfit._export.gltf import gltf_material
    >>> red = ctfit.Material(ctfit.Structure(family="plastic", diffuse="spectrum"),
    ...                      ctfit.Params(s=np.array(0.1), m=np.array([0.2]), w=np.ones(1), n=np.array(1.5), rd=np.array([0.2, 0.02, 0.02])),
    ...                      channels=("R", "G", "B"))
    >>> mat, notes = gltf_material(red)
    >>> mat["pbrMetallicRoughness"]["metallicFactor"], mat["extensions"]["KHR_materials_ior"], notes
    (0.0, {'ior': 1.5}, [])
    """
    st, p = material.structure, material.params
    to_rgb = band_to_rgb(material)
    s = float(p.s) if st.has_s else float(st.has_specular)
    rough = fit_ggx_roughness(material) if st.has_specular else 1.0
    ext: dict[str, dict[str, float | list[float]]]
    if st.family == "metal" and st.has_specular:
        base = np.asarray(normal_reflectance(st, p), float).reshape(-1) @ to_rgb
        metallic, ext = s, {"KHR_materials_specular": {"specularFactor": 0.0}}
    elif st.family == "metal":  # a Lambertian surface alone
        base = np.broadcast_to(np.asarray(ambient_reflectance(st, p), float), (to_rgb.shape[0],)) @ to_rgb
        metallic, ext = 0.0, {"KHR_materials_specular": {"specularFactor": 0.0}}
    else:
        n = float(np.asarray(p.n).reshape(-1)[0])
        f0 = ((n - 1) / (n + 1)) ** 2
        diffuse = dataclasses.replace(st, lobes=0) if st.has_diffuse else None
        albedo = np.asarray(ambient_reflectance(diffuse, p), float) if diffuse else np.zeros(1)
        base = (1 - s) * np.broadcast_to(albedo, (to_rgb.shape[0],)) @ to_rgb / (1 - min(s, 1.0) * f0)
        metallic = 0.0
        # KHR_materials_ior takes ior ≥ 1; n and 1/n have the same f0, which is all glTF's Schlick F uses
        ext = {"KHR_materials_ior": {"ior": max(n, 1 / n)}, "KHR_materials_specular": {"specularFactor": min(s, 1.0), "specularColorFactor": [1.0, 1.0, 1.0]}}
    base, changed = into_gamut(base, 1.0)
    notes = [GAMUT_NOTE] if changed else []
    if st.family == "metal" and st.has_specular and st.has_rd:
        notes.append("glTF's one base colour is F0: the diffuse part F0/π, not R_d")
    colour = [float(c) for c in base] + [1.0]
    return {"name": material.name or "ctfit material",
            "pbrMetallicRoughness": {"baseColorFactor": colour, "metallicFactor": metallic, "roughnessFactor": rough},
            "extensions": ext}, notes
