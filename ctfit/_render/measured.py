"""A fitted material beside "its measurement's nearest rendering" (``ctfit render --compare``).

Every sample of the second tile uses, per light and band, the measured BRDF of the nearest
measured direction pair (isotropy and reciprocity assumed), lit and tone-mapped as the model's
tile; see :func:`render_compare`.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Literal

import numpy as np
import numpy.typing as npt
from jaxtyping import Float, UInt8

from .._model import Material, Measurement, ambient_reflectance
from .scene import Scene, Tile, render_scene, shade_tile, white_scale
from .sheet import assemble_sheet, tile_label
from .surfaces import VIEW_DIRECTION, Surface, surface_normals
from .tone import BACKGROUND, tone_map

__all__ = ["render_compare"]


def _embed(theta_i: np.ndarray, theta_o: np.ndarray, dphi: np.ndarray) -> np.ndarray:
    """Direction pairs as points of R⁶ (L, V in the local frame with L at φ = 0)."""
    st_o = np.sin(theta_o)
    return np.stack(
        [np.sin(theta_i), np.zeros_like(theta_i), np.cos(theta_i), st_o * np.cos(dphi), st_o * np.sin(dphi), np.cos(theta_o)],
        axis=-1,
    )


def _measured_pairs(data: Measurement) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per group of bands that share direction pairs: (bands, points (2D, 6), values (2D, bands)).

    Isotropy: only θ_i, θ_o and |Δφ| (folded to [0°, 180°]) are kept; reciprocity: every pair
    also stands for its swap (θ_o, θ_i, Δφ).
    """
    if data.brdf is None:
        raise ValueError(f"{data.source}: the measurement has no BRDF values to show")
    ti, to = np.deg2rad(data.theta_i), np.deg2rad(data.theta_o)
    d = np.mod(np.asarray(data.phi_o) - np.asarray(data.phi_i), 360.0)
    dphi = np.deg2rad(np.minimum(d, 360.0 - d))
    values = np.asarray(data.brdf, dtype=float)
    grid_order = data.grid()
    if grid_order is not None:
        pairs, order = grid_order
        grid = values[order].reshape(len(pairs), data.n_bands)
        first = order.reshape(len(pairs), data.n_bands)[:, 0]
        groups = [(np.arange(data.n_bands), first, grid)]
    else:
        groups = []
        for b in range(data.n_bands):
            idx = np.flatnonzero(data.band == b)
            groups.append((np.array([b]), idx, values[idx][:, None]))
    out = []
    for bands, idx, vals in groups:
        if len(idx) == 0:
            raise ValueError(f"{data.source}: band {data.band_labels[bands[0]]} has no samples")
        pts = np.concatenate([_embed(ti[idx], to[idx], dphi[idx]), _embed(to[idx], ti[idx], dphi[idx])])
        out.append((bands, pts, np.concatenate([vals, vals])))
    return out


def _pixel_angles(normal: np.ndarray, light: np.ndarray, view: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """θ_i, θ_o, |Δφ| (radians) of each normal (P, 3) for one light and the view, and validity."""
    cl, cv = normal @ light, normal @ view
    tl = light - cl[:, None] * normal
    tv = view - cv[:, None] * normal
    den = np.linalg.norm(tl, axis=-1) * np.linalg.norm(tv, axis=-1)
    cos_dphi = np.where(den > 1e-12, np.sum(tl * tv, axis=-1) / np.where(den > 1e-12, den, 1), 1.0)
    valid = (cl > 0) & (cv > 0)
    return np.arccos(np.clip(cl, -1, 1)), np.arccos(np.clip(cv, -1, 1)), np.arccos(np.clip(cos_dphi, -1, 1)), valid


def _check_bands(material: Material, data: Measurement) -> None:
    """RGB data needs an RGB material with channels R, G, B; spectral data a spectral material."""
    if data.channels is not None:
        if tuple(data.channels) != ("R", "G", "B") or not material.is_rgb:
            raise ValueError(
                f"{data.source}: RGB data (channels {list(data.channels)}) needs channels R, G, B and an RGB "
                f"material; material {material.name!r} is {'RGB' if material.is_rgb else 'spectral'}"
            )
    elif material.is_rgb:
        raise ValueError(f"{data.source}: spectral data needs a spectral material; {material.name!r} has RGB channels")
    check_colour_bands(data)


def check_colour_bands(data: Measurement) -> None:
    """Spectral data is shown in colour on its own bands: at least two wavelengths."""
    if data.channels is None and not data.band_unknown and data.n_bands < 2:
        raise ValueError(f"{data.source}: one band ({float(data.wavelength_nm[0]):g} nm): a measurement is shown in colour, "
                         "which takes at least two wavelengths")


def measured_tile(
    material: Material, data: Measurement, scene: Scene, surface: Surface, supersample: int, max_distance: float
) -> tuple[Tile, float]:
    """``(tile, coverage)``: ``scene`` shaded with the measured BRDF, nearest direction pair per band.

    For every object sample and light, the local (θ_i, θ_o, |Δφ|) is looked up in the data
    (isotropy and reciprocity assumed) by the Euclidean distance between the pairs' unit
    vectors (L, V) in R⁶ — about the angle between them; the nearest measured pair gives the
    BRDF of each band. Samples whose nearest pair is farther than ``max_distance`` for a light
    that reaches them have no data and are shown as background. The ambient term, which needs
    the hemispherical reflectance the data does not give, is the material's R_a = π R_d.
    ``coverage`` is the fraction of object samples with data. ``scene`` is on the data's bands.
    """
    from scipy.spatial import cKDTree

    normals = surface.normal[surface.mask]
    view = np.asarray(VIEW_DIRECTION)
    n_bands = len(scene.to_rgb)
    ra = np.broadcast_to(np.asarray(ambient_reflectance(material.structure, scene.params), dtype=float), (n_bands,))
    intensity = np.broadcast_to(scene.ambient * ra, (len(normals), n_bands)).copy()
    missing = np.zeros(len(normals), bool)
    groups = _measured_pairs(data)
    trees = [cKDTree(pts) for _, pts, _ in groups]
    for light in scene.lights:
        ld = np.asarray(light.direction, dtype=float)
        ti, to, dphi, valid = _pixel_angles(normals, ld, view)
        q = _embed(ti[valid], to[valid], dphi[valid])
        r = np.zeros((int(valid.sum()), n_bands))
        for (bands, _, vals), tree in zip(groups, trees):
            dist, j = tree.query(q)
            r[:, bands] = vals[j]
            missing[np.flatnonzero(valid)[dist > max_distance]] = True
        e = np.asarray(light.spectrum, dtype=float) * float(light.solid_angle)
        intensity[valid] += e * np.cos(ti[valid])[:, None] * r
    mask = surface.mask.copy()
    rgb = np.zeros(mask.shape + (3,))
    rgb[mask] = intensity @ scene.to_rgb
    rows, cols = np.nonzero(mask)
    mask[rows[missing], cols[missing]] = False  # no measured pair near enough: shown as background
    rgb[~mask] = 0
    tile = Tile(rgb, mask, supersample, white_scale(normals, scene))
    return tile, 1 - missing.mean() if len(missing) else 0.0


def render_compare(
    material: Material,
    data: Measurement,
    size: int = 256,
    shape: str = "sphere",
    labels: Sequence[str] | Literal[False] | None = None,
    *,
    exposure: str = "reference",
    background: Float[npt.ArrayLike, " 3"] = BACKGROUND,
    supersample: int = 2,
    max_distance: float = 0.35,
    **scene: Any,
) -> UInt8[np.ndarray, "height width 3"]:
    """Two tiles, (H, W, 3) uint8: ``material`` and the nearest-measured rendering of ``data``.

    Both are shaded on the data's bands with the same lights; both use the model tile's
    exposure (the paper's scale of the left tile), so brightness is comparable and measured
    colours beyond the display are desaturated. ``labels``: None (defaults), False, or two
    strings. ``max_distance``: how far (about the angle, in radians) the nearest measured
    direction pair may be before a sample is left as background. ``scene``: ``directions``,
    ``solid_angles``, ``ambient`` (:func:`ctfit.render_linear`).

    >>> from ctfit import material_from_dict, simulate
    >>> mirror = material_from_dict({"s": 1, "lobes": [{"m": 0.3}], "channels": ["R", "G", "B"], "F0": [0.9, 0.6, 0.3]})
    >>> data = simulate(mirror, 500, seed=1)
    >>> render_compare(mirror, data, 16, supersample=1).shape  # two tiles and their labels
    (30, 32, 3)
    """
    if data.band_unknown != material.band_unknown:
        unknown, known = (data.source, material.name) if data.band_unknown else (material.name, data.source)
        raise ValueError(f"{unknown}: its band's wavelength is unknown, so it cannot be shown beside {known}, whose bands are known")
    _check_bands(material, data)
    surface = surface_normals(shape, size, supersample)
    on_bands = render_scene(material, wavelength_nm=data.wavelength_nm, **scene)
    model = shade_tile(material.structure, on_bands, surface, supersample)
    measured, coverage = measured_tile(material, data, on_bands, surface, supersample, max_distance)
    left, scale = tone_map(model, background=background, exposure=exposure)
    right, _ = tone_map(measured, scale=scale, background=background)
    if labels is None:
        names = [tile_label(f"model: {material.name}", material), f"measured, nearest pair ({coverage:.0%})"]
    elif labels is False:
        names = None
    else:
        names = [str(x) for x in labels]
        if len(names) != 2:
            raise ValueError(f"a comparison shows two tiles; got {len(names)} labels")
    return assemble_sheet([left, right], names, size, 2, background)
