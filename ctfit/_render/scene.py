"""The renderer's scene: the paper's two lights, the ambient light, the bands and the shading to linear sRGB.

- **Lights.** Two distant D65 lights of equal intensity, with the paper's solid angles
  dω = 0.0001 sr and 0.0002 sr, from the upper left and the right (:data:`LIGHT_DIRECTIONS`,
  :data:`SOLID_ANGLES`).
- **Ambient.** I_ia = 0.01 · Σ_l I_il dω_il / π (:data:`AMBIENT_FRACTION`), reflected with
  R_a = π R_d (paper eq. 1, :func:`ctfit.ambient_reflectance`): the ambient light gives 1 % of
  the diffuse brightness the two lights give at normal incidence. (Read literally,
  "I_ia = 0.01 I_i" with dω = 10⁻⁴ makes the ambient term about 100 × the two lights' diffuse
  term and every object a flat disc; see ``docs/rendering.md``.)
- **Colour.** Spectral materials are evaluated on ``wavelength_step`` nm bands over 380–780 nm
  (their parameters interpolated linearly, held at the end values). The lights carry the D65
  spectrum, scaled to Y = 1, and the reflected spectrum I_r(λ) is integrated with the
  equal-energy colour-matching weights (``spectral_weights(wl, "E")``):
  XYZ = Σ I_r(λ) x̄ȳz̄(λ) Δλ / Σ ȳ Δλ. So D65 enters once, through the lights; a perfect white
  reflector lit at normal incidence by one light of unit dω has the XYZ of the D65 white, which
  CAT02 maps to linear sRGB (1, 1, 1). RGB materials (channels R, G, B) are shaded in their
  channels directly with white lights (1, 1, 1): their values are linear sRGB. A material whose
  one band has an unknown wavelength (``Material.band_unknown``, a fit of an ALTA file) is
  shaded in that band under white lights and shown grey, with a :class:`~ctfit.DataWarning`.
"""

from __future__ import annotations

import functools
import math
import warnings
from collections.abc import Sequence
from typing import Any, NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import numpy.typing as npt
from jaxtyping import Array, ArrayLike, Float

from .._colour import colour_science, rgb_conversion, spectral_weights, warn_outside_visible
from .._io import DataWarning
from .._model import Light, Material, Params, Structure, by_blocks, reflected_intensity
from .surfaces import VIEW_DIRECTION, Surface, surface_normals

__all__ = [
    "WAVELENGTH_STEP_NM",
    "check_wavelength_step",
    "LIGHT_DIRECTIONS",
    "SOLID_ANGLES",
    "AMBIENT_FRACTION",
    "Scene",
    "Tile",
    "render_scene",
    "shade_linear",
    "render_linear",
]

# Towards the lights (x right, y up, z towards the viewer): a weaker light upper left in front,
# the paper's second light (twice the solid angle) from the right, a little above.
LIGHT_DIRECTIONS = ((-0.45, 0.55, 0.70), (0.75, 0.25, 0.61))
SOLID_ANGLES = (1e-4, 2e-4)  # sr, the paper's two light sources
AMBIENT_FRACTION = 0.01
SPECTRAL_RANGE_NM = (380.0, 780.0)
WAVELENGTH_STEP_NM = (1.0, 20.0)
"""The steps of spectral rendering allowed, nm: from the CIE tables' 1 nm to 20 nm (ASTM E308's
coarsest tables). Against 1 nm, gold and copper spheres differ by CIEDE2000 ≤ 0.5 at their 99th
percentile up to 20 nm, 1.1 at 50 nm, 9.7 at 100 nm; the whole range (380 and 780 nm alone, where
the colour-matching functions are nearly 0) drew gold red."""


@functools.cache
def _spectral_setup(wavelength_nm: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(D65 spectrum with Y = 1, (λ, 3) matrix from I_r(λ) to linear sRGB) for the bands."""
    colour = colour_science()
    wl = np.asarray(wavelength_nm, dtype=float)
    weights = spectral_weights(wl, "E")
    d65 = np.asarray(colour.SDS_ILLUMINANTS["D65"][wl], dtype=float)
    d65 = d65 / (d65 @ np.asarray(weights.weights)[:, 1])
    white = d65 @ np.asarray(weights.weights)
    conv = rgb_conversion("sRGB", white, "CAT02")
    return d65, np.asarray(weights.weights) @ np.asarray(conv.matrix).T


def check_wavelength_step(wavelength_step: float) -> None:
    """Raise ``ValueError`` unless ``wavelength_step`` is in :data:`WAVELENGTH_STEP_NM`.

    >>> check_wavelength_step(100)
    Traceback (most recent call last):
    ValueError: wavelength_step must be in [1, 20] nm, got 100 (coarser steps misplace colours: CIEDE2000 up to 10 at 100 nm against 1 nm)
    """
    low, high = WAVELENGTH_STEP_NM
    if not low <= wavelength_step <= high:
        why = "coarser steps misplace colours: CIEDE2000 up to 10 at 100 nm against 1 nm" if wavelength_step > high else (
            "finer than the 1 nm tables of the colour-matching functions" if wavelength_step > 0 else "not a step")
        raise ValueError(f"wavelength_step must be in [{low:g}, {high:g}] nm, got {wavelength_step:g} ({why})")


def render_bands(
    material: Material, wavelength_step: float = 5.0, wavelength_nm: Float[ArrayLike, " bands"] | None = None
) -> tuple[Params, np.ndarray, np.ndarray]:
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
        return material.check_colour_channels().params_at(channels=("R", "G", "B")), np.ones(3), np.eye(3)
    if wavelength_nm is None:
        check_wavelength_step(wavelength_step)
        lo, hi = SPECTRAL_RANGE_NM
        wavelength_nm = np.arange(lo, hi + 1e-9, wavelength_step)
    wl = tuple(float(w) for w in np.asarray(wavelength_nm, dtype=float))
    warn_outside_visible(material)
    spectrum, to_rgb = _spectral_setup(wl)
    params = material.params if material.wavelength_nm is None else material.params_at(wavelength_nm=np.asarray(wl))
    return params, spectrum, to_rgb


def scene_lights(
    spectrum: Float[ArrayLike, " bands"], directions: Float[npt.ArrayLike, "lights 3"] = LIGHT_DIRECTIONS,
    solid_angles: Float[npt.ArrayLike, " lights"] = SOLID_ANGLES,
) -> list[Light]:
    """One light of intensity ``spectrum`` (bands,) per direction, with its solid angle."""
    directions, solid_angles = np.asarray(directions, dtype=float), np.asarray(solid_angles, dtype=float)
    if len(directions) != len(solid_angles):
        raise ValueError(f"{len(directions)} light directions but {len(solid_angles)} solid angles")
    return [Light(np.asarray(d, dtype=float), np.asarray(spectrum, dtype=float), float(w)) for d, w in zip(directions, solid_angles)]


class Scene(NamedTuple):
    """A material in the renderer's scene, on the bands it is shaded in (:func:`render_scene`).

    - ``params``: the material's parameters on those bands;
    - ``lights``: the :class:`~ctfit.Light` list (NumPy arrays);
    - ``ambient_fraction``: I_ia as a fraction of Σ_l I_il dω_il / π (see :attr:`ambient`);
    - ``to_rgb``: (bands, 3), the matrix from a reflected intensity spectrum to linear sRGB.

    >>> from ctfit import material_from_dict
    >>> matte = material_from_dict({"s": 0, "d": 1, "channels": ["R", "G", "B"], "Rd": 0.1})
    >>> scene = render_scene(matte, solid_angles=(1e-4, 2e-4), ambient=0.01)
    >>> [f"{v:.3g}" for v in scene.ambient]  # I_ia = 0.01 · (1e-4 + 2e-4)/π per channel
    ['9.55e-07', '9.55e-07', '9.55e-07']
    """

    params: Params
    lights: list[Light]
    ambient_fraction: float
    to_rgb: np.ndarray

    @property
    def ambient(self) -> np.ndarray:
        """The ambient intensity per band, I_ia = ambient_fraction · Σ_l I_il dω_il / π."""
        total = sum(np.asarray(l.spectrum) * float(l.solid_angle) for l in self.lights)
        return self.ambient_fraction * np.asarray(total) / math.pi


def render_scene(
    material: Material,
    *,
    directions: Float[npt.ArrayLike, "lights 3"] = LIGHT_DIRECTIONS,
    solid_angles: Float[npt.ArrayLike, " lights"] = SOLID_ANGLES,
    ambient: float = AMBIENT_FRACTION,
    wavelength_step: float = 5.0,
    wavelength_nm: Float[ArrayLike, " bands"] | None = None,
) -> Scene:
    """``material`` in the renderer's scene: its bands, lights and ambient light (module docstring).

    ``directions`` (towards the lights) and ``solid_angles`` (sr) give one light each;
    ``ambient`` is the ambient fraction. Spectral materials are shaded on ``wavelength_nm``,
    or 380–780 nm every ``wavelength_step`` nm, under D65 lights; RGB materials in R, G, B under
    white lights.

    >>> from ctfit import material_from_dict
    >>> gold = material_from_dict({"s": 1, "lobes": [{"m": 0.3}], "optical_constants": "Au"})
    >>> scene = render_scene(gold, wavelength_step=10.0)
    >>> len(scene.lights), scene.to_rgb.shape  # two lights, 41 bands to linear sRGB
    (2, (41, 3))
    """
    if material.band_unknown:
        warnings.warn(f"material {material.name!r}: its band's wavelength is unknown; rendered in grey", DataWarning, stacklevel=2)
    params, spectrum, to_rgb = render_bands(material, wavelength_step, wavelength_nm)
    return Scene(params, scene_lights(spectrum, directions, solid_angles), float(ambient), to_rgb)


@eqx.filter_jit
def _shade(
    structure: Structure, params: Params, normal: ArrayLike, view: ArrayLike, lights: Sequence[Light], ambient: ArrayLike, to_rgb: ArrayLike
) -> Array:
    intensity = reflected_intensity(structure, params, normal, view, lights, ambient)
    return intensity @ jnp.asarray(to_rgb).astype(intensity.dtype)


def shade_linear(structure: Structure, scene: Scene, normals: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 3"]:
    """Linear sRGB (…, 3) of eq. 1 at unit ``normals`` (…, 3), seen from :data:`VIEW_DIRECTION`.

    The reflected intensity per band (:func:`ctfit.reflected_intensity`) times ``scene.to_rgb``;
    jitted, differentiable in ``scene.params`` (which may be traced; the lights are NumPy).

    >>> import numpy as np
    >>> from ctfit import material_from_dict
    >>> matte = material_from_dict({"s": 0, "d": 1, "channels": ["R", "G", "B"], "Rd": [0.2, 0.1, 0.05]})
    >>> scene = render_scene(matte, directions=[(0.0, 0.0, 1.0)], solid_angles=[1.0], ambient=0.0)
    >>> rgb = shade_linear(matte.structure, scene, np.array([0.0, 0.0, 1.0]))  # N = L, dω = 1: I_r = R_d
    >>> [round(float(v), 4) for v in rgb]
    [0.2, 0.1, 0.05]
    """
    return _shade(structure, scene.params, normals, np.asarray(VIEW_DIRECTION), scene.lights, scene.ambient, scene.to_rgb)


class Tile(NamedTuple):
    """An unscaled rendering: linear sRGB per sample, before the paper's scaling (:func:`render_linear`).

    >>> from ctfit import material_from_dict
    >>> white = material_from_dict({"s": 0, "d": 1, "channels": ["R", "G", "B"], "Rd": 0.3183099})  # R_d = 1/π
    >>> tile = render_linear(white, 8, supersample=1)
    >>> round(float(tile.rgb.max() * tile.white_scale), 4)  # a white Lambertian object: its own reference
    1.0
    """

    rgb: np.ndarray  # (n, n, 3) linear, 0 off the object
    mask: np.ndarray  # (n, n)
    supersample: int
    white_scale: float  # 1 / brightest value of a white Lambertian object in the same scene


def white_scale(normals: np.ndarray, scene: Scene) -> float:
    """1 / max over the object of Σ_l dω_l (N·L_l)⁺/π + ambient: a white R_d = 1/π, in the
    units where a perfect white reflector lit by a unit light of unit dω is linear RGB 1."""
    lights = scene.lights
    e = sum(float(l.solid_angle) * np.maximum(normals @ np.asarray(l.direction, dtype=float), 0) for l in lights)
    amb = scene.ambient_fraction * sum(float(l.solid_angle) for l in lights) / math.pi
    peak = float(np.max(e)) / math.pi + amb if len(normals) else 0.0
    return 1 / peak if peak > 0 else 1.0


def shade_tile(structure: Structure, scene: Scene, surface: Surface, supersample: int) -> Tile:
    """The :class:`Tile` of ``scene`` on ``surface``: only samples on the object are shaded, in
    blocks of a few fixed sizes (:func:`~ctfit._model.evaluation.by_blocks`), so a picture of
    another size compiles nothing new."""
    normals = surface.normal[surface.mask]
    rgb = np.zeros(surface.mask.shape + (3,))
    shaded = by_blocks(lambda block: shade_linear(structure, scene, block), normals, tuple(VIEW_DIRECTION))
    rgb[surface.mask] = np.asarray(shaded, dtype=float)
    return Tile(rgb, surface.mask, supersample, white_scale(normals, scene))


def render_linear(material: Material, size: int = 256, shape: str = "sphere", *, supersample: int = 2, **scene: Any) -> Tile:
    """Unscaled linear sRGB of ``material`` on ``shape``: ``(rgb, mask, supersample, white_scale)``.

    ``rgb`` has side ``size * supersample``; only samples on the object are shaded (compiled
    per structure and band count, in blocks of a few fixed sizes: another ``size`` compiles
    nothing). ``scene``: the options of :func:`render_scene` (``directions``, ``solid_angles``,
    ``ambient``, ``wavelength_step``, ``wavelength_nm``).

    >>> from ctfit import material_from_dict
    >>> matte = material_from_dict({"s": 0, "d": 1, "channels": ["R", "G", "B"], "Rd": [0.2, 0.1, 0.05]})
    >>> tile = render_linear(matte, 8, supersample=1)
    >>> tile.rgb.shape, int(tile.mask.sum()), bool(tile.rgb[~tile.mask].any())
    ((8, 8, 3), 44, False)
    """
    surface = surface_normals(shape, size, supersample)
    return shade_tile(material.structure, render_scene(material, **scene), surface, supersample)
