"""Writing a rendered image as a PNG file."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from jaxtyping import UInt8

from .._io import atomic_save

__all__ = ["save_png"]


def save_png(image: UInt8[np.ndarray, "height width 3"], path: str | os.PathLike[str]) -> Path:
    """Write an (H, W, 3) uint8 image as PNG (Pillow), atomically; the parent folder is created.

    >>> import numpy as np
    >>> from PIL import Image
    >>> image = np.zeros((2, 3, 3), np.uint8)
    >>> image[0, 1] = (255, 128, 0)
    >>> path = save_png(image, "pictures/orange.png")  # relative to the working directory
    >>> bool((np.asarray(Image.open(path)) == image).all())
    True
    """
    from .._runtime import need

    need("plots", "a rendered picture")
    from PIL import Image

    a = np.asarray(image)
    if a.ndim != 3 or a.shape[-1] not in (3, 4) or a.dtype != np.uint8:
        raise ValueError(f"expected an (H, W, 3) uint8 image, got {a.shape} {a.dtype}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_save(path, lambda buffer: Image.fromarray(a).save(buffer, format="PNG"))
    return path
