"""Tiles on a sheet: one tone-mapped tile per material in a grid, each labelled below (Figure 7).

Each tile is tone-mapped on its own (the paper's rule is per picture, :mod:`.tone`); labels are
drawn with Pillow in DejaVu Sans (shipped with matplotlib), cut with "…" when too long.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
from jaxtyping import Float, UInt8

from .._colour import eotf_inverse_sRGB
from .._model import Material
from .scene import render_linear
from .tone import BACKGROUND, tone_map

__all__ = ["grid_layout", "assemble_sheet", "tile_label", "render_material", "render_materials"]

_LABEL_HEIGHT_FRACTION = 0.11


def grid_layout(n_tiles: int, size: int, columns: int | None = None, labels: bool = True) -> tuple[int, int, list[tuple[int, int]]]:
    """``(height, width, boxes)``: the grid's image size and each tile's (top, left) corner.

    ``columns`` defaults to min(n, 6). With ``labels`` each tile has a text strip below it.

    >>> grid_layout(3, 100, columns=2)  # two rows of 100-pixel tiles, each with a 14-pixel strip
    (228, 200, [(0, 0), (0, 100), (114, 0)])
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


def _font(px: int) -> Any:
    """DejaVu Sans (shipped with matplotlib, as in the other figures), else Pillow's default."""
    from PIL import ImageFont

    try:
        from matplotlib import font_manager

        return ImageFont.truetype(font_manager.findfont("DejaVu Sans", fallback_to_default=True), px)
    except (ImportError, OSError, ValueError):
        pass
    try:
        return ImageFont.load_default(size=px)
    except TypeError:  # Pillow < 10.1, or no FreeType: the fixed bitmap font
        return ImageFont.load_default()


def _fit_text(draw: Any, text: str, font: Any, width: int) -> str:
    if draw.textlength(text, font=font) <= width:
        return text
    while text and draw.textlength(text + "…", font=font) > width:
        text = text[:-1]
    return text + "…"


def assemble_sheet(
    tiles: list[np.ndarray], names: list[str] | None, size: int, columns: int | None, background: npt.ArrayLike
) -> UInt8[np.ndarray, "height width 3"]:
    """The tiles (uint8, ``size`` square) on a grid (:func:`grid_layout`) over ``background``
    (linear sRGB), each with its name below it unless ``names`` is None."""
    from .._runtime import need

    need("plots", "a rendered picture")  # and for _font below
    from PIL import Image, ImageDraw

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


def tile_label(name: str, material: Material) -> str:
    """``name``, after "band unknown: " for a material whose band's wavelength is unknown."""
    return f"band unknown: {name}" if material.band_unknown else name  # first: a long name is cut at its end


def _names(materials: Sequence[Material], labels: bool | Sequence[str] | None) -> list[str] | None:
    if labels is False:
        return None
    if labels is None or labels is True:
        return [tile_label(m.name or f"material {i + 1}", m) for i, m in enumerate(materials)]
    labels = [str(x) for x in labels]
    if len(labels) != len(materials):
        raise ValueError(f"{len(labels)} labels for {len(materials)} materials")
    return labels


def render_material(
    material: Material, size: int = 256, shape: str = "sphere", *, exposure: str = "reference",
    background: Float[npt.ArrayLike, " 3"] = BACKGROUND, **options: Any,
) -> UInt8[np.ndarray, "height width 3"]:
    """One tile, (size, size, 3) uint8; ``options`` as for :func:`ctfit.render_linear`.

    >>> from ctfit import material_from_dict
    >>> matte = material_from_dict({"s": 0, "d": 1, "channels": ["R", "G", "B"], "Rd": [0.2, 0.1, 0.05]})
    >>> image = render_material(matte, 16, "vase", supersample=1)
    >>> image.shape, image.dtype
    ((16, 16, 3), dtype('uint8'))
    >>> r, g, b = (int(v) for v in image[8, 8])
    >>> r > g > b  # a reddish-brown matte vase
    True
    """
    return tone_map(render_linear(material, size, shape, **options), exposure=exposure, background=background)[0]


def render_materials(
    materials: Sequence[Material],
    size: int = 256,
    shape: str | Sequence[str] = "sphere",
    labels: bool | Sequence[str] | None = None,
    *,
    columns: int | None = None,
    exposure: str = "reference",
    background: Float[npt.ArrayLike, " 3"] = BACKGROUND,
    **options: Any,
) -> UInt8[np.ndarray, "height width 3"]:
    """A grid of tiles, one per material, (H, W, 3) uint8, like the paper's Figure 7.

    ``shape``: one of ``"sphere"``, ``"vase"`` for every tile, or one per material. ``labels``:
    None (the materials' names), False (no text strip), or one string per material. Each tile is
    tone-mapped on its own (:func:`ctfit.tone_map`). ``options`` go to :func:`ctfit.render_linear`.

    >>> from ctfit import material_from_dict
    >>> matte = material_from_dict({"s": 0, "d": 1, "channels": ["R", "G", "B"], "Rd": 0.1})
    >>> mirror = material_from_dict({"s": 1, "lobes": [{"m": 0.1}], "channels": ["R", "G", "B"], "F0": 0.9})
    >>> render_materials([matte, mirror], 16, ["sphere", "vase"], ["matte", "mirror"], supersample=1).shape
    (30, 32, 3)
    """
    if isinstance(materials, Material):
        raise TypeError("materials must be a sequence of ctfit.Material (one tile each): [material] for one, or ctfit.render_material(material)")
    materials = list(materials)
    shapes = [shape] * len(materials) if isinstance(shape, str) else list(shape)
    if len(shapes) != len(materials):
        raise ValueError(f"{len(shapes)} shapes for {len(materials)} materials")
    names = _names(materials, labels)
    tiles = [render_material(m, size, s, exposure=exposure, background=background, **options) for m, s in zip(materials, shapes)]
    return assemble_sheet(tiles, names, size, columns, background)
