"""Tone mapping of a rendered tile: the paper's scaling, gamut mapping, background and sRGB encoding.

The paper's rule, applied to each picture: :func:`ctfit.scale_to_display` scales the tile so
that its brightest colour is shown at the maximum luminance its chromaticity allows, after
desaturating negative channels at constant luminance and dominant wavelength; then sRGB
encoding. With ``exposure="reference"`` (the default) the rule sees the tile *and* a white
Lambertian object of the same shape under the same lights (:attr:`Tile.white_scale`): a
highlight brighter than that white sets the scale, as the paper's rule would; otherwise the
white does, so a dark material (carbon, rubber) stays dark instead of being stretched to white.
``exposure="tile"`` is the rule on the tile alone. Either way brightness is comparable between
tiles only under ``"reference"`` and only among tiles whose highlights are not brighter than white.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import numpy.typing as npt
from jaxtyping import Array, ArrayLike, Float, UInt8

from .._colour import desaturate_to_gamut, eotf_inverse_sRGB, scale_to_display
from .scene import Tile

__all__ = ["EXPOSURES", "BACKGROUND", "tone_map"]

EXPOSURES = ("reference", "tile")
BACKGROUND = (0.1, 0.1, 0.1)  # linear sRGB: a neutral dark grey (encoded 89/255)


def _padded_side(n: int) -> int:
    """A picture's side in pixels rounded up to one of four sizes per octave (at least 64): the
    tone mapping's programs are compiled per side, so the sides 113–128 share theirs, as do
    129–160, 161–192, …, while the padding adds at most a quarter to the side (a picture of
    2,049 pixels is mapped at 2,560, not 4,096)."""
    if n <= 64:
        return 64
    step = 1 << ((n - 1).bit_length() - 3)
    return -(-n // step) * step


def _padded(a: np.ndarray, side: int) -> np.ndarray:
    """``a`` (n, n, …) padded with zeros to (side, side, …)."""
    extra = side - a.shape[0]
    return np.pad(a, [(0, extra), (0, extra)] + [(0, 0)] * (a.ndim - 2))


@eqx.filter_jit
def _paper_scale(rgb: np.ndarray) -> Array:
    return scale_to_display(rgb.reshape(-1, 3))[1]  # the padding (black) changes nothing: the brightest sets it


@eqx.filter_jit
def _compose(rgb: np.ndarray, mask: np.ndarray, scale: ArrayLike, background: ArrayLike, supersample: int) -> Array:
    """uint8 sRGB: scaled and gamut-mapped object samples over the background, averaged in
    linear light over each pixel's ``supersample``² samples, then encoded."""
    shown = desaturate_to_gamut(desaturate_to_gamut(rgb, upper=None) * scale, upper=1.0)
    lin = jnp.where(mask[..., None], shown, jnp.asarray(background).astype(shown.dtype))
    n = lin.shape[0] // supersample
    lin = lin.reshape(n, supersample, n, supersample, 3).mean(axis=(1, 3))
    return jnp.clip(jnp.round(eotf_inverse_sRGB(lin) * 255), 0, 255).astype(jnp.uint8)


def tone_map(
    tile: Tile, scale: float | None = None, background: Float[npt.ArrayLike, " 3"] = BACKGROUND, exposure: str = "reference"
) -> tuple[UInt8[np.ndarray, "height width 3"], float]:
    """``(uint8 image (size, size, 3), scale)``: the paper's scaling, sRGB encoding, background.

    ``scale=None``: the paper's rule (:func:`ctfit.scale_to_display`): the tile's brightest
    colour at the maximum luminance its chromaticity allows. With ``exposure="reference"``
    (default) the rule is applied to the tile *and* a white Lambertian object of the same shape
    under the same lights, so a dark material stays dark and a highlight brighter than white
    sets the scale; ``exposure="tile"`` applies it to the tile alone. A given ``scale`` is
    applied as is; colours beyond the display are desaturated at constant luminance and
    dominant wavelength (:func:`ctfit.desaturate_to_gamut`).

    >>> from ctfit import material_from_dict, render_linear
    >>> dark = material_from_dict({"s": 0, "d": 1, "channels": ["R", "G", "B"], "Rd": 0.02})
    >>> tile = render_linear(dark, 8, supersample=1)
    >>> image, scale = tone_map(tile)
    >>> image.shape, image.dtype, int(image[0, 0, 0])  # the background: linear 0.1 is 89/255
    ((8, 8, 3), dtype('uint8'), 89)
    >>> int(tone_map(tile)[0].max()) < int(tone_map(tile, exposure="tile")[0].max())  # stays dark
    True
    """
    if exposure not in EXPOSURES:
        raise ValueError(f"exposure must be one of {EXPOSURES}, got {exposure!r}")
    rgb = np.where(tile.mask[..., None], tile.rgb, 0.0)
    side = rgb.shape[0] // tile.supersample  # pixels; padded (black, off the object), cut after
    samples = _padded_side(side) * tile.supersample
    rgb, mask = _padded(rgb, samples), _padded(tile.mask, samples)
    if scale is None:
        scale = float(_paper_scale(rgb))
        if exposure == "reference":
            scale = min(scale, float(tile.white_scale))
    img = _compose(rgb, mask, jnp.asarray(float(scale)), np.asarray(background, dtype=float), tile.supersample)
    return np.asarray(img)[:side, :side], float(scale)
