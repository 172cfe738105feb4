"""Pictures of materials as in Cook & Torrance (1982), Figures 6 and 7: shaded objects under two lights.

The scene (``docs/rendering.md`` states it with the reasons for each choice):

- **Camera.** Orthographic, looking down −z: every pixel sees along V = (0, 0, 1) (towards the
  viewer). The tile spans [−1, 1]² with x to the right and y up; pixels are sampled at their
  centres, ``supersample`` × ``supersample`` times per pixel and averaged in linear light.
- **Objects.** ``"sphere"``: radius 0.92, N = (x, y, z)/0.92. ``"vase"``: a surface of
  revolution about the y axis with radius r(y) (a cubic spline through a few profile points,
  :func:`vase_profile`, shrunk by 0.9 into the tile); the front surface at pixel (x, y) has
  z = √(r² − x²) and normal N ∝ (x, −r r′(y), z), from the gradient of x² + z² − r(y)². Seen at
  right angles to its axis, a surface of revolution hides nothing from itself, so this is the
  exact visible surface.
- **Lights.** Two distant D65 lights of equal intensity, with the paper's solid angles
  dω = 0.0001 sr and 0.0002 sr, from the upper left and the right (:data:`LIGHT_DIRECTIONS`).
- **Ambient.** I_ia = 0.01 · Σ_l I_il dω_il / π, reflected with R_a = π R_d (paper eq. 1,
  :func:`ctfit.ambient_reflectance`): the ambient light gives 1 % of the diffuse brightness the
  two lights give at normal incidence. (Read literally, "I_ia = 0.01 I_i" with dω = 10⁻⁴ makes
  the ambient term about 100 × the two lights' diffuse term and every object a flat disc; see the docs.)
- **Colour.** Spectral materials are evaluated on ``wavelength_step`` nm bands over 380–780 nm
  (their parameters interpolated linearly, held at the end values). The lights carry the D65
  spectrum, scaled to Y = 1 (:func:`scene_lights`), and the reflected spectrum I_r(λ) is
  integrated with the equal-energy colour-matching weights (``spectral_weights(wl, "E")``):
  XYZ = Σ I_r(λ) x̄ȳz̄(λ) Δλ / Σ ȳ Δλ. So D65 enters once, through the lights; a perfect white
  reflector lit at normal incidence by one light of unit dω has the XYZ of the D65 white, which
  CAT02 maps to linear sRGB (1, 1, 1). RGB materials (channels R, G, B) are shaded in their
  channels directly with white lights (1, 1, 1): their values are linear sRGB. A material whose
  one band has an unknown wavelength (``Material.band_unknown``, a fit of an ALTA file) is
  shaded in that band under white lights and shown grey, with a :class:`~ctfit.DataWarning`
  and "band unknown:" before its label.
- **Tone mapping, per tile** (the paper's rule, applied to each picture):
  :func:`ctfit.scale_to_display` scales the tile so that its brightest colour is shown at the
  maximum luminance its chromaticity allows, after desaturating negative channels at constant
  luminance and dominant wavelength; then sRGB encoding. With ``exposure="reference"`` (the
  default) the rule sees the tile *and* a white Lambertian object of the same shape under the
  same lights (:attr:`Tile.white_scale`): a highlight brighter than that white sets the
  scale, as the paper's rule would; otherwise the white does, so a dark material (carbon,
  rubber) stays dark instead of being stretched to white. ``exposure="tile"`` is the rule on
  the tile alone. Either way brightness is comparable between tiles only under
  ``"reference"`` and only among tiles whose highlights are not brighter than white.

:func:`render_compare` puts a fitted material beside "its measurement's nearest rendering":
every pixel of the second tile uses, per light and band, the measured BRDF of the nearest
measured direction pair (see its docstring), lit and tone-mapped the same way.
"""

from __future__ import annotations

import functools
import math
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._model import ambient_reflectance
from .._colour import eotf_inverse_sRGB, rgb_conversion, spectral_weights
from .._io import DataWarning
from .._colour import desaturate_to_gamut, scale_to_display
from .._model import Light, Material, Measurement, reflected_intensity

__all__ = [
    "SHAPES",
    "LIGHT_DIRECTIONS",
    "SOLID_ANGLES",
    "AMBIENT_FRACTION",
    "Surface",
    "Tile",
    "surface",
    "vase_profile",
    "scene_lights",
    "render_bands",
    "shade_linear",
    "render_linear",
    "render_material",
    "render_materials",
    "render_compare",
    "measured_linear",
    "tone_map",
    "grid_layout",
    "save_png",
]

SHAPES = ("sphere", "vase")
# Towards the lights (x right, y up, z towards the viewer): a weaker light upper left in front,
# the paper's second light (twice the solid angle) from the right, a little above.
LIGHT_DIRECTIONS = ((-0.45, 0.55, 0.70), (0.75, 0.25, 0.61))
SOLID_ANGLES = (1e-4, 2e-4)  # sr, the paper's two light sources
AMBIENT_FRACTION = 0.01
EXPOSURES = ("reference", "tile")
VIEW = (0.0, 0.0, 1.0)
RADIUS = 0.92  # of the sphere, in tile units ([−1, 1] across)
VASE_SCALE = 0.9  # the vase's profile (heights ±0.95) shrunk by this factor into the tile
BACKGROUND = (0.1, 0.1, 0.1)  # linear sRGB: a neutral dark grey (encoded 89/255)
SPECTRAL_RANGE_NM = (380.0, 780.0)
_LABEL_HEIGHT_FRACTION = 0.11


# --- geometry -------------------------------------------------------------------------------


class Surface(NamedTuple):
    """Per-sample unit normals (h, w, 3) and the mask (h, w) of samples on the object."""

    normal: np.ndarray
    mask: np.ndarray


def _pixel_centres(n: int) -> np.ndarray:
    return (np.arange(n) + 0.5) / n * 2 - 1


# Radius of the vase against height, y from the foot (−0.95) to the lip (0.95).
_VASE_POINTS = (
    (-0.95, 0.34),
    (-0.80, 0.46),
    (-0.45, 0.62),
    (-0.05, 0.56),
    (0.35, 0.30),
    (0.62, 0.22),
    (0.82, 0.25),
    (0.95, 0.36),
)


@functools.cache
def _vase_spline():
    from scipy.interpolate import CubicSpline  # noqa: PLC0415

    y, r = np.asarray(_VASE_POINTS).T
    return CubicSpline(y, r, bc_type="natural")


def vase_profile(y):
    """``(r, dr/dy)`` of the vase's profile at heights ``y`` (r = 0 outside the vase)."""
    y = np.asarray(y, dtype=float)
    spline = _vase_spline()
    inside = (y >= _VASE_POINTS[0][0]) & (y <= _VASE_POINTS[-1][0])
    yc = np.clip(y, _VASE_POINTS[0][0], _VASE_POINTS[-1][0])
    return np.where(inside, spline(yc), 0.0), np.where(inside, spline(yc, 1), 0.0)


def surface(shape: str, size: int, supersample: int = 1) -> Surface:
    """Normals of ``shape`` ("sphere" or "vase") seen by the orthographic camera.

    ``size`` × ``size`` pixels, each sampled ``supersample``² times: arrays of side
    ``size * supersample``, row 0 at the top (y = +1). Off-object samples hold N = V.
    The arrays are cached and read-only.
    """
    if shape not in SHAPES:
        raise ValueError(f"shape must be one of {SHAPES}, got {shape!r}")
    if not (isinstance(size, int) and size >= 1) or not (isinstance(supersample, int) and supersample >= 1):
        raise ValueError(f"size and supersample must be positive integers, got {size!r}, {supersample!r}")
    return _surface(shape, size, supersample)


@functools.lru_cache(maxsize=8)
def _surface(shape: str, size: int, supersample: int) -> Surface:
    n = size * supersample
    c = _pixel_centres(n)
    x, y = np.meshgrid(c, -c)  # y up
    if shape == "sphere":
        ry = np.sqrt(np.maximum(RADIUS * RADIUS - y * y, 0.0))  # the circle's half-width at height y
        mask = np.abs(x) < ry
        z = np.sqrt(np.maximum(ry * ry - x * x, 0.0))
        normal = np.stack([x, y, z], axis=-1) / RADIUS
    else:
        r, dr = vase_profile(y / VASE_SCALE)
        r = VASE_SCALE * r  # the profile shrunk into the tile; dr/dy is unchanged
        mask = np.abs(x) < r
        z = np.sqrt(np.maximum(r * r - x * x, 0.0))
        normal = np.stack([x, -r * dr, z], axis=-1)
        normal /= np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-300)
    normal = np.where(mask[..., None], normal, np.asarray(VIEW))
    normal.flags.writeable = False
    mask.flags.writeable = False
    return Surface(normal=normal, mask=mask)


# --- lights and colour ----------------------------------------------------------------------


@functools.cache
def _spectral_setup(wavelength_nm: tuple[float, ...]):
    """(D65 spectrum with Y = 1, (λ, 3) matrix from I_r(λ) to linear sRGB) for the bands."""
    import colour  # noqa: PLC0415

    wl = np.asarray(wavelength_nm, dtype=float)
    weights = spectral_weights(wl, "E")
    d65 = np.asarray(colour.SDS_ILLUMINANTS["D65"][wl], dtype=float)
    d65 = d65 / (d65 @ np.asarray(weights.weights)[:, 1])
    white = d65 @ np.asarray(weights.weights)
    conv = rgb_conversion("sRGB", white, "CAT02")
    return d65, np.asarray(weights.weights) @ np.asarray(conv.matrix).T


def render_bands(material: Material, wavelength_step: float = 5.0, wavelength_nm=None):
    """``(params, light spectrum (bands,), to_rgb (bands, 3))`` of ``material`` for rendering.

    Spectral materials: ``wavelength_nm``, or 380–780 nm every ``wavelength_step`` nm; the
    parameters interpolated there, the D65 spectrum (Y = 1), and the matrix taking an intensity
    spectrum to linear sRGB. RGB materials: their R, G, B parameters, white (1, 1, 1), identity.
    A material whose one band has an unknown wavelength (``band_unknown``): that band, white
    light 1, and grey (the band's intensity in R, G and B alike).
    """
    if material.band_unknown:
        return material.params, np.ones(1), np.ones((1, 3))
    if material.is_rgb:
        return material.params_at(channels=("R", "G", "B")), np.ones(3), np.eye(3)
    if wavelength_nm is None:
        if not wavelength_step > 0:
            raise ValueError(f"wavelength_step must be > 0 nm, got {wavelength_step!r}")
        lo, hi = SPECTRAL_RANGE_NM
        wavelength_nm = np.arange(lo, hi + 1e-9, wavelength_step)
    wl = tuple(float(w) for w in np.asarray(wavelength_nm, dtype=float))
    spectrum, to_rgb = _spectral_setup(wl)
    params = material.params if material.wavelength_nm is None else material.params_at(wavelength_nm=np.asarray(wl))
    return params, spectrum, to_rgb


def scene_lights(spectrum, directions=LIGHT_DIRECTIONS, solid_angles=SOLID_ANGLES) -> list[Light]:
    """The paper's two lights: equal intensity ``spectrum`` (bands,), solid angles 1e-4 and 2e-4 sr."""
    if len(directions) != len(solid_angles):
        raise ValueError(f"{len(directions)} light directions but {len(solid_angles)} solid angles")
    return [Light(np.asarray(d, dtype=float), np.asarray(spectrum, dtype=float), float(w)) for d, w in zip(directions, solid_angles)]


def _ambient(lights: Sequence[Light], fraction: float):
    """I_ia = fraction · Σ I_il dω_il / π (see the module docstring)."""
    total = sum(np.asarray(l.spectrum) * float(l.solid_angle) for l in lights)
    return fraction * np.asarray(total) / math.pi


@eqx.filter_jit
def shade_linear(structure, params, normal, view, lights, ambient, to_rgb):
    """Linear RGB (…, 3) of eq. 1 at the given normals: I_r(bands) @ ``to_rgb`` (bands, 3)."""
    intensity = reflected_intensity(structure, params, normal, view, lights, ambient)
    return intensity @ jnp.asarray(to_rgb).astype(intensity.dtype)


class Tile(NamedTuple):
    """An unscaled rendering: linear sRGB per sample, before the paper's scaling."""

    rgb: np.ndarray  # (n, n, 3) linear, 0 off the object
    mask: np.ndarray  # (n, n)
    supersample: int
    white_scale: float  # 1 / brightest value of a white Lambertian object in the same scene


def _white_scale(normals, lights, ambient_fraction) -> float:
    """1 / max over the object of Σ_l dω_l (N·L_l)⁺/π + ambient: a white R_d = 1/π, in the
    units where a perfect white reflector lit by a unit light of unit dω is linear RGB 1."""
    e = sum(float(l.solid_angle) * np.maximum(normals @ np.asarray(l.direction, dtype=float), 0) for l in lights)
    amb = ambient_fraction * sum(float(l.solid_angle) for l in lights) / math.pi
    peak = float(np.max(e)) / math.pi + amb if len(normals) else 0.0
    return 1 / peak if peak > 0 else 1.0


def render_linear(
    material: Material,
    size: int = 256,
    shape: str = "sphere",
    *,
    directions=LIGHT_DIRECTIONS,
    solid_angles=SOLID_ANGLES,
    ambient: float = AMBIENT_FRACTION,
    wavelength_step: float = 5.0,
    wavelength_nm=None,
    supersample: int = 2,
) -> Tile:
    """Unscaled linear sRGB of ``material`` on ``shape``: ``(rgb, mask, supersample)``.

    ``rgb`` has side ``size * supersample``; only samples on the object are shaded (one
    compiled function per structure, band count and number of object samples).
    """
    surf = surface(shape, size, supersample)
    if material.band_unknown:
        warnings.warn(f"material {material.name!r}: its band's wavelength is unknown; rendered in grey", DataWarning, stacklevel=2)
    params, spectrum, to_rgb = render_bands(material, wavelength_step, wavelength_nm)
    lights = scene_lights(spectrum, directions, solid_angles)
    normals = surf.normal[surf.mask]
    rgb_on = shade_linear(
        material.structure, params, normals, np.asarray(VIEW), lights, _ambient(lights, ambient), to_rgb
    )
    rgb = np.zeros(surf.mask.shape + (3,))
    rgb[surf.mask] = np.asarray(rgb_on, dtype=float)
    return Tile(rgb, surf.mask, supersample, _white_scale(normals, lights, ambient))


@eqx.filter_jit
def _paper_scale(rgb):
    return scale_to_display(rgb.reshape(-1, 3))[1]


@eqx.filter_jit
def _compose(rgb, mask, scale, background, supersample: int):
    """uint8 sRGB: scaled and gamut-mapped object samples over the background, averaged in
    linear light over each pixel's ``supersample``² samples, then encoded."""
    shown = desaturate_to_gamut(desaturate_to_gamut(rgb, upper=None) * scale, upper=1.0)
    lin = jnp.where(mask[..., None], shown, jnp.asarray(background).astype(shown.dtype))
    n = lin.shape[0] // supersample
    lin = lin.reshape(n, supersample, n, supersample, 3).mean(axis=(1, 3))
    return jnp.clip(jnp.round(eotf_inverse_sRGB(lin) * 255), 0, 255).astype(jnp.uint8)


def tone_map(tile: Tile, scale=None, background=BACKGROUND, exposure: str = "reference"):
    """``(uint8 image (size, size, 3), scale)``: the paper's scaling, sRGB encoding, background.

    ``scale=None``: the paper's rule (:func:`ctfit.scale_to_display`): the tile's brightest
    colour at the maximum luminance its chromaticity allows. With ``exposure="reference"``
    (default) the rule is applied to the tile *and* a white Lambertian object of the same shape
    under the same lights, so a dark material stays dark and a highlight brighter than white
    sets the scale; ``exposure="tile"`` applies it to the tile alone. A given ``scale`` is
    applied as is; colours beyond the display are desaturated at constant luminance and
    dominant wavelength (:func:`ctfit.desaturate_to_gamut`).
    """
    if exposure not in EXPOSURES:
        raise ValueError(f"exposure must be one of {EXPOSURES}, got {exposure!r}")
    rgb = np.where(tile.mask[..., None], tile.rgb, 0.0)
    if scale is None:
        scale = float(_paper_scale(rgb))
        if exposure == "reference":
            scale = min(scale, float(tile.white_scale))
    img = _compose(rgb, tile.mask, jnp.asarray(float(scale)), np.asarray(background, dtype=float), tile.supersample)
    return np.asarray(img), float(scale)


def render_material(
    material: Material, size: int = 256, shape: str = "sphere", *, exposure: str = "reference", background=BACKGROUND, **options
) -> np.ndarray:
    """One tile, (size, size, 3) uint8; ``options`` as for :func:`render_linear`."""
    return tone_map(render_linear(material, size, shape, **options), exposure=exposure, background=background)[0]


# --- the grid -------------------------------------------------------------------------------


def grid_layout(n_tiles: int, size: int, columns: int | None = None, labels: bool = True):
    """``(height, width, boxes)``: the grid's image size and each tile's (top, left) corner.

    ``columns`` defaults to min(n, 6). With ``labels`` each tile has a text strip below it.
    """
    if n_tiles < 1:
        raise ValueError("nothing to render: give at least one material")
    cols = min(n_tiles, 6) if columns is None else int(columns)
    if cols < 1:
        raise ValueError(f"columns must be ≥ 1, got {columns!r}")
    rows = -(-n_tiles // cols)
    label_h = _label_height(size) if labels else 0
    cell_h = size + label_h
    boxes = [((i // cols) * cell_h, (i % cols) * size) for i in range(n_tiles)]
    return rows * cell_h, cols * size, boxes


def _label_height(size: int) -> int:
    return max(14, round(size * _LABEL_HEIGHT_FRACTION))


def _font(px: int):
    """DejaVu Sans (shipped with matplotlib, as in the other figures), else Pillow's default."""
    from PIL import ImageFont  # noqa: PLC0415

    try:
        from matplotlib import font_manager  # noqa: PLC0415

        return ImageFont.truetype(font_manager.findfont("DejaVu Sans", fallback_to_default=True), px)
    except (ImportError, OSError, ValueError):
        pass
    try:
        return ImageFont.load_default(size=px)
    except TypeError:  # Pillow < 10.1, or no FreeType: the fixed bitmap font
        return ImageFont.load_default()


def _assemble(tiles: list[np.ndarray], names: list[str] | None, size: int, columns: int | None, background):
    from PIL import Image, ImageDraw  # noqa: PLC0415

    height, width, boxes = grid_layout(len(tiles), size, columns, labels=names is not None)
    bg = np.clip(np.round(np.asarray(eotf_inverse_sRGB(np.asarray(background, dtype=float))) * 255), 0, 255)
    out = np.empty((height, width, 3), np.uint8)
    out[...] = bg.astype(np.uint8)
    for tile, (top, left) in zip(tiles, boxes):
        out[top : top + size, left : left + size] = tile
    if names is None:
        return out
    img = Image.fromarray(out)
    draw = ImageDraw.Draw(img)
    label_h = _label_height(size)
    font = _font(max(9, round(label_h * 0.55)))
    for name, (top, left) in zip(names, boxes):
        text = _fit_text(draw, name, font, size - 6)
        # One baseline for every label, whatever its letters: anchor "ms" (middle, baseline).
        draw.text((left + size / 2, top + size + 0.7 * label_h), text, fill=(235, 235, 235), font=font, anchor="ms")
    return np.asarray(img)


def _fit_text(draw, text: str, font, width: int) -> str:
    if draw.textlength(text, font=font) <= width:
        return text
    while text and draw.textlength(text + "…", font=font) > width:
        text = text[:-1]
    return text + "…"


def _label(name: str, material: Material) -> str:
    return f"band unknown: {name}" if material.band_unknown else name  # first: a long name is cut at its end


def _names(materials, labels):
    if labels is False:
        return None
    if labels is None or labels is True:
        return [_label(m.name or f"material {i + 1}", m) for i, m in enumerate(materials)]
    labels = [str(x) for x in labels]
    if len(labels) != len(materials):
        raise ValueError(f"{len(labels)} labels for {len(materials)} materials")
    return labels


def render_materials(
    materials: Sequence[Material],
    size: int = 256,
    shape: str | Sequence[str] = "sphere",
    labels=None,
    *,
    columns: int | None = None,
    exposure: str = "reference",
    background=BACKGROUND,
    **options,
) -> np.ndarray:
    """A grid of tiles, one per material, (H, W, 3) uint8, like the paper's Figure 7.

    ``shape``: one of :data:`SHAPES` for every tile, or one per material. ``labels``: None
    (the materials' names), False (no text strip), or one string per material. Each tile is
    tone-mapped on its own (see the module docstring). ``options`` go to :func:`render_linear`.
    """
    materials = list(materials)
    shapes = [shape] * len(materials) if isinstance(shape, str) else list(shape)
    if len(shapes) != len(materials):
        raise ValueError(f"{len(shapes)} shapes for {len(materials)} materials")
    names = _names(materials, labels)
    tiles = [
        tone_map(render_linear(m, size, s, **options), exposure=exposure, background=background)[0]
        for m, s in zip(materials, shapes)
    ]
    return _assemble(tiles, names, size, columns, background)


# --- the measurement beside the fit -------------------------------------------------------


def _embed(theta_i, theta_o, dphi):
    """Direction pairs as points of R⁶ (L, V in the local frame with L at φ = 0)."""
    st_o = np.sin(theta_o)
    return np.stack(
        [np.sin(theta_i), np.zeros_like(theta_i), np.cos(theta_i), st_o * np.cos(dphi), st_o * np.sin(dphi), np.cos(theta_o)],
        axis=-1,
    )


def _measured_pairs(data: Measurement):
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


def _pixel_angles(normal, light, view):
    """θ_i, θ_o, |Δφ| (radians) of each normal (P, 3) for one light and the view, and validity."""
    cl, cv = normal @ light, normal @ view
    tl = light - cl[:, None] * normal
    tv = view - cv[:, None] * normal
    den = np.linalg.norm(tl, axis=-1) * np.linalg.norm(tv, axis=-1)
    cos_dphi = np.where(den > 1e-12, np.sum(tl * tv, axis=-1) / np.where(den > 1e-12, den, 1), 1.0)
    valid = (cl > 0) & (cv > 0)
    return np.arccos(np.clip(cl, -1, 1)), np.arccos(np.clip(cv, -1, 1)), np.arccos(np.clip(cos_dphi, -1, 1)), valid


def measured_linear(
    material: Material,
    data: Measurement,
    size: int = 256,
    shape: str = "sphere",
    *,
    directions=LIGHT_DIRECTIONS,
    solid_angles=SOLID_ANGLES,
    ambient: float = AMBIENT_FRACTION,
    supersample: int = 2,
    max_distance: float = 0.35,
):
    """``(tile, coverage)``: the scene shaded with the measured BRDF, nearest direction pair per band.

    For every object sample and light, the local (θ_i, θ_o, |Δφ|) is looked up in the data
    (isotropy and reciprocity assumed) by the Euclidean distance between the pairs' unit
    vectors (L, V) in R⁶ — about the angle between them; the nearest measured pair gives the
    BRDF of each band. Samples whose nearest pair is farther than ``max_distance`` for a light
    that reaches them have no data and are shown as background. The ambient term, which needs
    the hemispherical reflectance the data does not give, is the material's R_a = π R_d.
    ``coverage`` is the fraction of object samples with data. The bands are the data's.
    """
    from scipy.spatial import cKDTree  # noqa: PLC0415

    if data.channels is not None:
        if tuple(data.channels) != ("R", "G", "B") or not material.is_rgb:
            raise ValueError(
                f"{data.source}: RGB data (channels {list(data.channels)}) needs channels R, G, B and an RGB "
                f"material; material {material.name!r} is {'RGB' if material.is_rgb else 'spectral'}"
            )
        params, spectrum, to_rgb = render_bands(material)
    else:
        if material.is_rgb:
            raise ValueError(f"{data.source}: spectral data needs a spectral material; {material.name!r} has RGB channels")
        params, spectrum, to_rgb = render_bands(material, wavelength_nm=data.wavelength_nm)
    lights = scene_lights(spectrum, directions, solid_angles)
    surf = surface(shape, size, supersample)
    normals = surf.normal[surf.mask]
    view = np.asarray(VIEW)
    n_bands = len(spectrum)
    ra = np.broadcast_to(np.asarray(ambient_reflectance(material.structure, params), dtype=float), (n_bands,))
    intensity = np.broadcast_to(_ambient(lights, ambient) * ra, (len(normals), n_bands)).copy()
    missing = np.zeros(len(normals), bool)
    groups = _measured_pairs(data)
    trees = [cKDTree(pts) for _, pts, _ in groups]
    for light in lights:
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
    mask = surf.mask.copy()
    rgb = np.zeros(mask.shape + (3,))
    rgb[mask] = intensity @ to_rgb
    rows, cols = np.nonzero(mask)
    mask[rows[missing], cols[missing]] = False  # no measured pair near enough: shown as background
    rgb[~mask] = 0
    white = _white_scale(normals, lights, ambient)
    return Tile(rgb, mask, supersample, white), 1 - missing.mean() if len(missing) else 0.0


def render_compare(
    material: Material,
    data: Measurement,
    size: int = 256,
    shape: str = "sphere",
    labels=None,
    *,
    exposure: str = "reference",
    background=BACKGROUND,
    **options,
) -> np.ndarray:
    """Two tiles, (H, W, 3) uint8: ``material`` and the nearest-measured rendering of ``data``.

    Both are shaded on the data's bands with the same lights; both use the model tile's
    exposure (the paper's scale of the left tile), so brightness is comparable and measured
    colours beyond the display are desaturated. ``labels``: None (defaults), False, or two
    strings. ``options``: ``directions``, ``solid_angles``, ``ambient``, ``supersample``
    (both tiles), ``max_distance`` (the measured tile).
    """
    max_distance = options.pop("max_distance", 0.35)
    if data.band_unknown != material.band_unknown:
        unknown, known = (data.source, material.name) if data.band_unknown else (material.name, data.source)
        raise ValueError(f"{unknown}: its band's wavelength is unknown, so it cannot be shown beside {known}, whose bands are known")
    if data.channels is not None:
        model = render_linear(material, size, shape, **options)
    else:
        model = render_linear(material, size, shape, wavelength_nm=data.wavelength_nm, **options)
    measured, coverage = measured_linear(material, data, size, shape, max_distance=max_distance, **options)
    left, scale = tone_map(model, background=background, exposure=exposure)
    right, _ = tone_map(measured, scale=scale, background=background)
    if labels is None:
        names = [_label(f"model: {material.name}", material), f"measured, nearest pair ({coverage:.0%})"]
    elif labels is False:
        names = None
    else:
        names = [str(x) for x in labels]
        if len(names) != 2:
            raise ValueError(f"--compare shows two tiles; got {len(names)} labels")
    return _assemble([left, right], names, size, 2, background)


def save_png(image: np.ndarray, path) -> Path:
    """Write an (H, W, 3) uint8 image as PNG (Pillow); the parent folder is created."""
    from PIL import Image  # noqa: PLC0415

    a = np.asarray(image)
    if a.ndim != 3 or a.shape[-1] not in (3, 4) or a.dtype != np.uint8:
        raise ValueError(f"expected an (H, W, 3) uint8 image, got {a.shape} {a.dtype}")
    from .._io import atomic_save  # noqa: PLC0415

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_save(path, lambda buffer: Image.fromarray(a).save(buffer, format="PNG"))
    return path
