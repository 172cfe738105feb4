"""CIE XYZ to a colourspace's RGB: the conversion matrix (with chromatic adaptation), the
encoding, and the whole pipeline to the colour to show (with the paper's gamut mapping).

The matrices and encodings are colour-science's (``colour.RGB_COLOURSPACES``); sRGB's curve and
the linear one run in JAX (:func:`encode_RGB`'s table), any other in colour-science's NumPy.
References: IEC 61966-2-1:1999 (sRGB); ``docs/colour.md``.
"""

from __future__ import annotations

import functools
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._model import float_dtype
from .gamut import desaturate_to_gamut
from .tristimulus import SpectralWeights, colour_science, spectrum_to_XYZ, table_entry

__all__ = ["RGBConversion", "rgb_conversion", "XYZ_to_RGB", "RGB_to_XYZ", "eotf_inverse_sRGB", "encode_RGB", "XYZ_to_display_RGB", "spectrum_to_RGB"]


@functools.cache
def _colourspace(name: str) -> Any:
    return table_entry("RGB_COLOURSPACES", name, "colourspace", sorted(colour_science().RGB_COLOURSPACES.keys())[:12])


class RGBConversion(eqx.Module):
    """XYZ (scene, illuminant white) → linear RGB of a colourspace; build with :func:`rgb_conversion`.

    - ``matrix``: (3, 3), ``rgb = matrix @ XYZ``; includes the chromatic adaptation, so the
      scene white maps to (1, 1, 1).
    - ``luminance``: (3,) relative luminance of each linear channel (the Y row of the
      colourspace's RGB → XYZ matrix, scaled to sum to 1): the luminance used by the gamut
      mapping, for which white of luminance Y is (Y, Y, Y).

    >>> conv = rgb_conversion("sRGB")
    >>> conv.colourspace, [round(float(v), 4) for v in conv.luminance]
    ('sRGB', [0.2126, 0.7152, 0.0722])
    """

    matrix: Float[np.ndarray, "3 3"]
    luminance: Float[np.ndarray, " 3"]
    colourspace: str = eqx.field(static=True)
    chromatic_adaptation: str | None = eqx.field(static=True)

    @property
    def white_XYZ(self) -> Float[np.ndarray, " 3"]:
        """The scene white that maps to RGB (1, 1, 1)."""
        return np.linalg.solve(np.asarray(self.matrix), np.ones(3))


def rgb_conversion(
    colourspace: str = "sRGB", white_XYZ: Float[ArrayLike, " 3"] | None = None, chromatic_adaptation: str | None = "CAT02"
) -> RGBConversion:
    """The XYZ → linear RGB conversion of ``colourspace`` (any name in ``colour.RGB_COLOURSPACES``).

    ``white_XYZ`` is the scene white (e.g. ``SpectralWeights.white_XYZ``). With a
    ``chromatic_adaptation`` transform ("CAT02", "Bradford", any of
    ``colour.CHROMATIC_ADAPTATION_TRANSFORMS``), the von Kries matrix maps it to the
    colourspace's white ``M⁻¹ (1, 1, 1)`` (M: the colourspace's published XYZ → RGB matrix), so
    that the scene white is RGB (1, 1, 1) exactly. ``white_XYZ=None`` or
    ``chromatic_adaptation=None`` passes XYZ to M unchanged.

    >>> import numpy as np
    >>> from ctfit._colour.tristimulus import spectral_weights
    >>> white_A = spectral_weights(np.arange(360.0, 831.0, 5.0), "A").white_XYZ  # incandescent light
    >>> conv = rgb_conversion("sRGB", white_A, "CAT02")
    >>> [round(float(v), 6) for v in conv.matrix @ white_A]  # its white is display white
    [1.0, 1.0, 1.0]
    """
    colour = colour_science()
    cs = _colourspace(colourspace)
    m = np.asarray(cs.matrix_XYZ_to_RGB, dtype=float)
    m_inv = np.linalg.inv(m)
    display_white = m_inv @ np.ones(3)
    adapt = np.eye(3)
    if white_XYZ is not None and chromatic_adaptation is not None:
        w = np.asarray(white_XYZ, dtype=float)
        if w.shape != (3,) or not np.all(np.isfinite(w)) or not w[1] > 0:
            raise ValueError(f"white_XYZ must be 3 finite values with Y > 0, got {white_XYZ!r}")
        if chromatic_adaptation not in colour.CHROMATIC_ADAPTATION_TRANSFORMS:
            raise ValueError(
                f"unknown chromatic adaptation {chromatic_adaptation!r}; one of "
                f"{sorted(colour.CHROMATIC_ADAPTATION_TRANSFORMS.keys())}"
            )
        adapt = colour.adaptation.matrix_chromatic_adaptation_VonKries(
            w, display_white, transform=chromatic_adaptation
        )
    lum = m_inv[1] / m_inv[1].sum()
    return RGBConversion(
        matrix=m @ adapt, luminance=lum, colourspace=colourspace, chromatic_adaptation=chromatic_adaptation
    )


def XYZ_to_RGB(XYZ: Float[ArrayLike, "*batch 3"], conversion: RGBConversion) -> Float[Array, "*batch 3"]:
    """Linear RGB (…, 3) from XYZ (…, 3); no encoding, no gamut mapping (channels may be < 0).

    >>> import numpy as np
    >>> conv = rgb_conversion("sRGB")
    >>> [round(float(v), 4) for v in XYZ_to_RGB(np.array([0.4124, 0.2126, 0.0193]), conv)]  # sRGB's red primary
    [1.0, 0.0, 0.0]
    """
    x = jnp.asarray(XYZ)
    x = x.astype(float_dtype(x))
    return x @ jnp.asarray(conversion.matrix).astype(x.dtype).T


def RGB_to_XYZ(rgb: Float[ArrayLike, "*batch 3"], conversion: RGBConversion) -> Float[Array, "*batch 3"]:
    """Inverse of :func:`XYZ_to_RGB`.

    >>> import numpy as np
    >>> [round(float(v), 4) for v in RGB_to_XYZ(np.ones(3), rgb_conversion("sRGB"))]  # sRGB's white, D65
    [0.9505, 1.0, 1.089]
    """
    x = jnp.asarray(rgb)
    x = x.astype(float_dtype(x))
    return x @ jnp.asarray(np.linalg.inv(np.asarray(conversion.matrix))).astype(x.dtype).T


def eotf_inverse_sRGB(L: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch"]:
    """sRGB encoding (IEC 61966-2-1): 12.92 L for L ≤ 0.0031308, else 1.055 L^(1/2.4) − 0.055.

    JAX, differentiable everywhere (the power is never evaluated at 0). Negative values use
    the linear segment; NaN and ±inf propagate.

    >>> import numpy as np
    >>> [round(float(v), 4) for v in eotf_inverse_sRGB(np.array([0.0, 0.002, 0.18, 1.0]))]  # 18 % grey → 0.46
    [0.0, 0.0258, 0.4614, 1.0]
    """
    L = jnp.asarray(L)
    L = L.astype(float_dtype(L))
    big = L > 0.0031308
    safe = jnp.where(big, L, 1)
    return jnp.where(big, 1.055 * safe ** (1 / 2.4) - 0.055, 12.92 * L)


@functools.cache
def _jax_encodings() -> dict:
    """colour-science's encoding functions that ctfit evaluates in JAX (differentiable, jittable),
    each with its JAX form: sRGB's curve (sRGB, Display P3, …) and the linear one (ACES2065-1, …)."""
    colour = colour_science()
    return {colour.models.eotf_inverse_sRGB: eotf_inverse_sRGB, colour.linear_function: jnp.asarray}


def encode_RGB(rgb: Float[ArrayLike, "*batch 3"], colourspace: str = "sRGB") -> Float[Array | np.ndarray, "*batch 3"]:
    """Apply the colourspace's encoding (its ``cctf_encoding``) to linear RGB.

    In JAX (differentiable, jittable) when the encoding is sRGB's curve (sRGB, Display P3, …)
    or linear (ACES2065-1, …). Any other curve is colour-science's own function on NumPy
    arrays: not differentiable and not traceable (a TypeError says so under jit/grad).

    >>> import numpy as np
    >>> [round(float(encode_RGB(np.array([0.18]), cs)[0]), 4) for cs in ("sRGB", "Adobe RGB (1998)", "ACES2065-1")]
    [0.4614, 0.4585, 0.18]
    """
    cs = _colourspace(colourspace)
    in_jax = _jax_encodings().get(cs.cctf_encoding)
    if in_jax is not None:
        return in_jax(rgb)
    try:
        a = np.asarray(rgb, dtype=float)
    except Exception as e:  # a tracer
        raise TypeError(
            f"the encoding of {colourspace!r} is evaluated by colour-science in NumPy and cannot be "
            "traced or differentiated; encode outside jit/grad, or use a colourspace with the sRGB curve"
        ) from e
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.asarray(cs.cctf_encoding(a), dtype=float)


def XYZ_to_display_RGB(
    XYZ: Float[ArrayLike, "*batch 3"], conversion: RGBConversion, *, upper: float | None = 1.0, encode: bool = True
) -> Float[Array | np.ndarray, "*batch 3"]:
    """XYZ (…, 3) → linear RGB → the paper's gamut mapping → encoding: the colour to show.

    The gamut mapping is :func:`ctfit.desaturate_to_gamut` with the colourspace's luminance and
    ``upper`` (None: only negative channels are mapped); ``encode=False`` stops before the
    encoding (:func:`encode_RGB`). Differentiable for colourspaces whose encoding is evaluated
    in JAX.

    >>> import numpy as np
    >>> from ctfit._colour.tristimulus import spectral_weights
    >>> w = spectral_weights(np.arange(360.0, 831.0, 5.0))
    >>> conv = rgb_conversion("sRGB", w.white_XYZ)
    >>> [round(float(v), 4) for v in XYZ_to_display_RGB(w.white_XYZ * 0.2, conv)]  # 20 % grey, encoded
    [0.4845, 0.4845, 0.4845]
    """
    rgb = desaturate_to_gamut(XYZ_to_RGB(XYZ, conversion), conversion.luminance, upper=upper)
    return encode_RGB(rgb, conversion.colourspace) if encode else rgb


def spectrum_to_RGB(
    reflectance: Float[ArrayLike, "*batch bands"], weights: SpectralWeights, conversion: RGBConversion, *, upper: float | None = 1.0,
    encode: bool = True,
) -> Float[Array | np.ndarray, "*batch 3"]:
    """The whole pipeline: reflectance (…, λ) → XYZ → :func:`XYZ_to_display_RGB`.

    >>> import numpy as np
    >>> from ctfit._colour.tristimulus import spectral_weights
    >>> wl = np.arange(360.0, 831.0, 5.0)
    >>> w = spectral_weights(wl)
    >>> conv = rgb_conversion("sRGB", w.white_XYZ)
    >>> red = np.where(wl > 600, 0.9, 0.05)  # reflects the long wavelengths
    >>> [round(float(v), 3) for v in spectrum_to_RGB(red, w, conv)]
    [0.869, 0.13, 0.223]
    """
    return XYZ_to_display_RGB(spectrum_to_XYZ(reflectance, weights), conversion, upper=upper, encode=encode)

