"""The camera and the objects of the paper's Figures 6 and 7: a sphere and a vase, their normals per pixel.

- **Camera.** Orthographic, looking down −z: every pixel sees along V = (0, 0, 1) (towards the
  viewer, :data:`VIEW_DIRECTION`). The tile spans [−1, 1]² with x to the right and y up; pixels
  are sampled at their centres, ``supersample`` × ``supersample`` times per pixel.
- **Objects.** ``"sphere"``: radius 0.92, N = (x, y, z)/0.92. ``"vase"``: a surface of
  revolution about the y axis with radius r(y) (a cubic spline through a few profile points,
  :func:`vase_profile`, shrunk by 0.9 into the tile); the front surface at pixel (x, y) has
  z = √(r² − x²) and normal N ∝ (x, −r r′(y), z), from the gradient of x² + z² − r(y)². Seen at
  right angles to its axis, a surface of revolution hides nothing from itself, so this is the
  exact visible surface.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import numpy as np
from jaxtyping import ArrayLike

__all__ = ["SHAPES", "VIEW_DIRECTION", "Surface", "surface_normals", "vase_profile"]

SHAPES = ("sphere", "vase")
VIEW_DIRECTION = (0.0, 0.0, 1.0)  # towards the orthographic camera
RADIUS = 0.92  # of the sphere, in tile units ([−1, 1] across)
VASE_SCALE = 0.9  # the vase's profile (heights ±0.95) shrunk by this factor into the tile

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


class Surface(NamedTuple):
    """Per-sample unit normals (h, w, 3) and the mask (h, w) of samples on the object.

    >>> normal, mask = surface_normals("vase", 8)
    >>> normal.shape, mask.shape, bool(mask[0, 0])  # a corner is off the vase
    ((8, 8, 3), (8, 8), False)
    """

    normal: np.ndarray
    mask: np.ndarray


def _pixel_centres(n: int) -> np.ndarray:
    return (np.arange(n) + 0.5) / n * 2 - 1


@functools.cache
def _vase_spline() -> Any:
    from scipy.interpolate import CubicSpline

    y, r = np.asarray(_VASE_POINTS).T
    return CubicSpline(y, r, bc_type="natural")


def vase_profile(y: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """``(r, dr/dy)`` of the vase's profile at heights ``y`` (r = 0 outside the vase).

    >>> r, dr = vase_profile([-0.95, -0.45, 2.0])
    >>> [round(float(v), 2) for v in r]  # the foot, the belly (widest), outside the vase
    [0.34, 0.62, 0.0]
    """
    y = np.asarray(y, dtype=float)
    spline = _vase_spline()
    inside = (y >= _VASE_POINTS[0][0]) & (y <= _VASE_POINTS[-1][0])
    yc = np.clip(y, _VASE_POINTS[0][0], _VASE_POINTS[-1][0])
    return np.where(inside, spline(yc), 0.0), np.where(inside, spline(yc, 1), 0.0)


def surface_normals(shape: str, size: int, supersample: int = 1) -> Surface:
    """Unit normals of ``shape`` ("sphere" or "vase") seen by the renderer's orthographic camera.

    ``size`` × ``size`` pixels, each sampled ``supersample``² times: arrays of side
    ``size * supersample``, row 0 at the top (y = +1). Off-object samples hold N = V
    (:data:`VIEW_DIRECTION`). The arrays are cached and read-only.

    >>> surf = surface_normals("sphere", 4)
    >>> surf.normal.shape, int(surf.mask.sum())
    ((4, 4, 3), 12)
    >>> [round(float(v), 3) for v in surf.normal[1, 1]]  # up and to the left of the centre
    [-0.272, 0.272, 0.923]
    """
    if shape not in SHAPES:
        raise ValueError(f"shape must be one of {SHAPES}, got {shape!r}")
    if not (isinstance(size, int) and size >= 1) or not (isinstance(supersample, int) and supersample >= 1):
        raise ValueError(f"size and supersample must be positive integers, got {size!r}, {supersample!r}")
    return _surface_normals(shape, size, supersample)


@functools.lru_cache(maxsize=8)
def _surface_normals(shape: str, size: int, supersample: int) -> Surface:
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
    normal = np.where(mask[..., None], normal, np.asarray(VIEW_DIRECTION))
    normal.flags.writeable = False
    mask.flags.writeable = False
    return Surface(normal=normal, mask=mask)
