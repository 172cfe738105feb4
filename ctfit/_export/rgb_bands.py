"""A material's per-band quantities as linear sRGB, for targets that hold three channels (glTF, MERL)."""

from __future__ import annotations

import numpy as np

from .._colour import XYZ_to_RGB, rgb_conversion, spectral_weights, spectrum_to_XYZ
from .._model import Material

__all__ = ["band_to_rgb"]


def band_to_rgb(material: Material) -> np.ndarray:
    """The (bands, 3) matrix that takes values per band to linear sRGB (R, G, B).

    R, G, B channels are taken as they are; one band (or a band of unknown wavelength) is grey;
    a spectrum is integrated as a reflectance under D65 with the CIE 1931 observer (a flat
    spectrum of 1 is white (1, 1, 1)) — linear, so it applies to BRDF values as to F0.

    Examples
    --------
    >>> import numpy as np, ctfit
    >>> from ctfit._export.rgb_bands import band_to_rgb
    >>> grey = ctfit.Material(ctfit.Structure(), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.arange(400.0, 701.0, 10.0) * 0 + 0.5),
    ...                       wavelength_nm=np.arange(400.0, 701.0, 10.0))
    >>> (np.full(31, 0.5) @ band_to_rgb(grey)).round(3).tolist()
    [0.5, 0.5, 0.5]
    """
    if material.is_rgb:
        channels = tuple(material.channels)
        if len(channels) == 1:
            return np.ones((1, 3))
        if channels != ("R", "G", "B"):
            raise ValueError(f"material {material.name!r}: an RGB target needs R, G, B channels or wavelengths, not channels {list(channels)}")
        return np.eye(3)
    if material.band_unknown or len(material.wavelength_nm) == 1:
        return np.ones((1, 3))
    weights = spectral_weights(np.asarray(material.wavelength_nm, float))
    xyz = np.asarray(spectrum_to_XYZ(np.eye(len(material.wavelength_nm)), weights), float)
    return np.asarray(XYZ_to_RGB(xyz, rgb_conversion("sRGB", white_XYZ=weights.white_XYZ)), float)
