"""The colour of each posterior draw: ``ctfit color``'s colour (sRGB, CIELAB) at normal incidence.

Every conversion is those of :mod:`ctfit._colour` (colour-science's data, the package's gamut mapping),
applied to a batch of draws.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from .._model import Material, Params, Structure
from .result import summarise

__all__ = ["draw_colours", "colour_summary"]


def _interp_matrix(src, dst) -> np.ndarray:
    """A (len(dst), len(src)) matrix doing np.interp (linear, held at the ends) from src to dst."""
    src = np.asarray(src, dtype=float)
    eye = np.eye(src.size)
    return np.stack([np.interp(dst, src, eye[j]) for j in range(src.size)], axis=1)


@functools.partial(jax.jit, static_argnums=0)
def _normal_fresnel(structure: Structure, params: Params):
    from .._model import fresnel

    return fresnel(structure, params, jnp.ones((), params.f0.dtype if params.f0 is not None else params.n.dtype))


def draw_colours(material: Material, chain: dict, *, illuminant="D65", max_draws: int = 2000) -> dict:
    """sRGB (encoded, gamut-mapped as in :func:`ctfit._colour.report.colour_report`) and CIELAB
    under ``illuminant`` of every draw (at most ``max_draws``, evenly spaced): arrays (n, 3).

    The colour is that of ``colour_report`` at normal incidence: the normal reflectance F0(λ)
    when there is a specular part (F(0) from the interpolated F0, n or n and k, as the report
    computes it), π R_d(λ) otherwise.
    """
    from .._colour import DEFAULT_OBSERVER, XYZ_to_display_RGB, XYZ_to_Lab, observer_cmfs, rgb_conversion, spectral_weights, warn_outside_visible

    if material.band_unknown:
        raise ValueError("the band's wavelength is unknown (single-band data), so there is no colour")
    st = material.structure
    key = next(k for k in ("F0", "n", "Rd") if k in chain)
    n_all = chain[key].shape[0]
    idx = np.unique(np.linspace(0, n_all - 1, min(max_draws, n_all)).round().astype(int))

    def band_param(name):
        v = chain.get(name)
        return None if v is None else np.asarray(v, dtype=float)[idx]

    if material.is_rgb:
        order = [material.channels.index(c) for c in ("R", "G", "B")]
        to_bands = lambda a: a[:, order]
        n_out = 3
    else:
        warn_outside_visible(material)
        grid = np.asarray(observer_cmfs(DEFAULT_OBSERVER).wavelengths, dtype=float)
        A = _interp_matrix(material.wavelength_nm, grid)
        to_bands = lambda a: a @ A.T
        n_out = grid.size
    if st.has_specular:
        names = {"f0": ("f0",), "n": ("n",), "conductor": ("n", "k")}[st.fresnel]
        src = {"f0": "F0", "n": "n", "k": "k"}
        p = Params(**{f: jnp.asarray(to_bands(band_param(src[f]))) for f in names})
        r = np.asarray(_normal_fresnel(st, p), dtype=float)
    else:
        rd = band_param("Rd")
        r = np.pi * (np.repeat(rd[:, None], n_out, axis=1) if rd.ndim == 1 else to_bands(rd))
    if material.is_rgb:
        conv = rgb_conversion("sRGB", None, None)
        XYZ = r @ np.linalg.inv(np.asarray(conv.matrix)).T
        white = conv.white_XYZ
        illum = "sRGB white"
    else:
        weights = spectral_weights(grid, illuminant, DEFAULT_OBSERVER)
        conv = rgb_conversion("sRGB", weights.white_XYZ, "CAT02")
        XYZ = r @ np.asarray(weights.weights, dtype=float)
        white = np.asarray(weights.white_XYZ, dtype=float)
        illum = weights.illuminant
    srgb = np.asarray(XYZ_to_display_RGB(XYZ, conv), dtype=float)  # encoded, gamut-mapped: colour_report's
    lab = np.asarray(XYZ_to_Lab(XYZ, white), dtype=float)
    return {"sRGB": srgb, "Lab": lab, "XYZ": XYZ, "illuminant": illum, "draws": int(idx.size)}


def colour_summary(material: Material, chain: dict) -> tuple[dict | None, str | None]:
    try:
        c = draw_colours(material, chain)
    except Exception as e:  # colour is a derived extra: never lose the samples over it
        return None, f"colour not computed: {type(e).__name__}: {e}"
    med = np.median(c["sRGB"], axis=0)
    hexs = "#" + "".join(f"{int(v):02x}" for v in np.clip(np.round(med * 255), 0, 255))
    return {
        "quantity": "F(0) = F0" if material.structure.has_specular else "pi*Rd",
        "illuminant": c["illuminant"],
        "observer": "CIE 1931 2 Degree Standard Observer",
        "sRGB": summarise(c["sRGB"]),
        "sRGB_hex_median": hexs,
        "Lab": summarise(c["Lab"]),
        "draws": c["draws"],
        "note": "as ctfit color (colour_report) at normal incidence, for each posterior draw",
    }, None


