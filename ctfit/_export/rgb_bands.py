"""A material's per-band quantities as linear sRGB, for targets that hold three channels (glTF, MERL, Mitsuba's RGB variants)."""

from __future__ import annotations

import dataclasses

import numpy as np

from .._colour import DEFAULT_OBSERVER, XYZ_to_RGB, desaturate_to_gamut, observer_cmfs, rgb_conversion, spectral_weights, spectrum_to_XYZ, warn_outside_visible
from .._model import Material, normal_reflectance

__all__ = ["band_to_rgb", "in_rgb_order", "into_gamut", "rgb_material", "F0_MAX", "GAMUT_NOTE"]

F0_MAX = 1 - 1e-6
"""The largest F0 an RGB target is given: F0 = 1 has an infinite effective index."""

GAMUT_NOTE = "colours outside sRGB's gamut desaturated into it"
"""What an export says where :func:`into_gamut` changed a colour."""


def in_rgb_order(material: Material) -> Material:
    """The material with its channels R, G, B in that order (picked by name, as ``ctfit color``
    and the renderer pick them), which every RGB target writes; any other material as it is.

    >>> import numpy as np, ctfit
    >>> from ctfit._export.rgb_bands import in_rgb_order
    >>> bgr = ctfit.Material(ctfit.Structure(), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.3, 0.6, 0.9])), channels=("B", "G", "R"))
    >>> rgb = in_rgb_order(bgr)
    >>> rgb.channels, rgb.params.f0.tolist()
    (('R', 'G', 'B'), [0.9, 0.6, 0.3])
    """
    if not material.is_rgb or tuple(material.channels) == _RGB or sorted(material.channels) != sorted(_RGB):
        return material
    return dataclasses.replace(material, params=material.params_at(channels=_RGB), channels=_RGB)


_RGB = ("R", "G", "B")


def band_to_rgb(material: Material) -> np.ndarray:
    """The (bands, 3) matrix that takes values per band to linear sRGB (R, G, B).

    R, G, B channels are taken as they are; one band (or a band of unknown wavelength) is grey;
    a spectrum is the one ``docs/formats.md`` defines — linear between the listed wavelengths,
    held at the end values beyond them — on the observer's 1 nm grid (360–830 nm), integrated as
    a reflectance under D65 with the CIE 1931 observer (a flat spectrum of 1 is white (1, 1, 1)):
    the colour ``ctfit color`` gives a spectrum. Linear, so it applies to BRDF values as to F0.

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
    warn_outside_visible(material)
    wl = np.asarray(material.wavelength_nm, float)
    grid = np.asarray(observer_cmfs(DEFAULT_OBSERVER).wavelengths, float)
    weights = spectral_weights(grid)
    spectra = np.stack([np.interp(grid, wl, band) for band in np.eye(wl.size)])  # each band's unit value, as a spectrum
    xyz = np.asarray(spectrum_to_XYZ(spectra, weights), float)
    return np.asarray(XYZ_to_RGB(xyz, rgb_conversion("sRGB", white_XYZ=weights.white_XYZ)), float)


def into_gamut(rgb, upper: float | None = None) -> tuple[np.ndarray, bool]:
    """Linear-sRGB colours (…, 3) with each one outside [0, ``upper``]³ (``upper`` None: only
    negative channels) desaturated into it at constant luminance, the paper's rule
    (:func:`~ctfit.desaturate_to_gamut`), the others as they are; and whether any was changed.

    Examples
    --------
    >>> import numpy as np
    >>> from ctfit._export.rgb_bands import into_gamut
    >>> colours, changed = into_gamut(np.array([[0.5, 0.2, -0.1], [0.3, 0.2, 0.1]]))
    >>> colours.round(4).tolist(), changed
    ([[0.4246, 0.2123, 0.0], [0.3, 0.2, 0.1]], True)
    """
    rgb = np.array(rgb, dtype=float)
    out = np.any((rgb < 0) | (rgb > (np.inf if upper is None else upper)), axis=-1)
    if np.any(out):
        rgb[out] = desaturate_to_gamut(rgb[out], upper=upper, xp=np)
    return rgb, bool(np.any(out))


def rgb_material(material: Material) -> tuple[Material, list[str]]:
    """The material with its spectra as linear-sRGB colours (:func:`band_to_rgb`), and what that
    changes in words; an RGB or one-band material as it is, with no notes.

    What is linear in a spectrum keeps its colour exactly: R_d, and F0 (the BRDF at normal
    incidence, and ``F0/pi``). The Fresnel term is not linear in F0: F0's colour becomes the
    paper's effective index per channel (fresnel "f0", k = 0), so the normal-incidence colour is
    exact and the shift towards the light's colour at grazing angles is the paper's, channel by
    channel; a metal's real n or a conductor's n, k per band become the same (through their F0).
    A colour outside sRGB's gamut is desaturated into it at constant luminance
    (:func:`into_gamut`); F0 is at most :data:`F0_MAX`. A plastic's one index is kept.

    Examples
    --------
    >>> import numpy as np, ctfit
    >>> from ctfit._export.rgb_bands import rgb_material
    >>> wl = np.arange(400.0, 701.0, 10.0)
    >>> grey = ctfit.Material(ctfit.Structure(fresnel="n"), ctfit.Params(m=np.array([0.2]), w=np.ones(1), n=np.full(31, 1.5)), wavelength_nm=wl)
    >>> rgb, notes = rgb_material(grey)
    >>> rgb.channels, rgb.structure.fresnel, rgb.params.f0.round(6).tolist()
    (('R', 'G', 'B'), 'f0', [0.04, 0.04, 0.04])
    >>> notes[1]
    'the real index n as the effective index of F0 (k = 0)'
    """
    if material.is_rgb or material.band_unknown or len(material.wavelength_nm) == 1:
        return material, []
    st, p = material.structure, material.params
    to_rgb = band_to_rgb(material)
    raw: dict = {}
    if st.has_rd and np.ndim(p.rd) > 0:
        raw["rd"] = (np.asarray(p.rd, float) @ to_rgb, None)
    notes = ["spectra as linear-sRGB colours (D65, CIE 1931)"]
    if st.needs_fresnel_params and not st.shared_index:
        raw["f0"] = (np.minimum(np.asarray(normal_reflectance(st, p), float), F0_MAX) @ to_rgb, F0_MAX)
        notes[0] += ", F0 by the effective index of its colour per channel"
        if st.fresnel != "f0":
            notes.append("the real index n as the effective index of F0 (k = 0)" if st.fresnel == "n" else "n, k as the effective index of F0 (k = 0)")
        st = dataclasses.replace(st, fresnel="f0")
    mapped = {name: into_gamut(c, upper) for name, (c, upper) in raw.items()}
    colours: dict[str, np.ndarray | None] = {name: c for name, (c, _) in mapped.items()}
    if any(changed for _, changed in mapped.values()):
        notes.append(GAMUT_NOTE)
    if "f0" in colours:
        colours.update(n=None, k=None)
    elif p.n is not None:  # a plastic's one index (a file may list it per band)
        colours["n"] = np.asarray(p.n, float).reshape(-1)[0]
    params = dataclasses.replace(p, **colours)
    return dataclasses.replace(material, structure=st, params=params, wavelength_nm=None, channels=("R", "G", "B")), notes
