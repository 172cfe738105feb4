"""The colour of a material's reflection: the library function behind ``ctfit color``.

"Reflectance colour" means the colour of the spectrum R(λ) that the material reflects, seen
under the illuminant, not scaled (a perfect white reflector has Y = 1, sRGB (1, 1, 1)):

- materials with a specular part (lobes ≥ 1): the Fresnel reflectance R(λ) = F(θ, λ) at the
  angle θ between the viewer and the facet normal — at θ = 0 the normal reflectance F0(λ),
  towards 90° the light's colour (paper §4, Figure 5). The diffuse part is not included.
- diffuse-only materials: the ambient (hemispherical) reflectance R(λ) = π R_d(λ), which does
  not depend on θ.

Spectral materials are evaluated on the observer's 1 nm grid (360–830 nm): their parameters
are interpolated linearly between the listed wavelengths and held at the end values outside
(``docs/formats.md``), then F is computed per nanometre — so no colour-matching function
or illuminant is resampled except the 5 nm CIE illuminant tables (linearly, as colour-science
does). RGB materials (channels R, G, B) give linear RGB of ``colourspace`` directly; their
white is the colourspace's white and ``illuminant`` is not used. A material whose one band has
an unknown wavelength (``Material.band_unknown``, a fit of an ALTA file) has no colour: the
report refuses it.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import equinox as eqx
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._io import float_list
from .._model import Material, ambient_reflectance, fresnel
from .chromaticity import XYZ_to_xy, dominant_wavelength, excitation_purity
from .gamut import in_gamut
from .rgb import RGB_to_XYZ, RGBConversion, XYZ_to_display_RGB, XYZ_to_RGB, encode_RGB, rgb_conversion
from .tristimulus import DEFAULT_OBSERVER, colour_science, observer_cmfs, spectral_weights, spectrum_to_XYZ, warn_outside_visible

__all__ = ["colour_report", "reflectance_spectrum"]


_fresnel = eqx.filter_jit(fresnel)
_ambient = eqx.filter_jit(ambient_reflectance)
_spectrum_to_XYZ = eqx.filter_jit(spectrum_to_XYZ)


@eqx.filter_jit
def _to_rgb(XYZ: ArrayLike, conv: RGBConversion) -> tuple[Array, Array | np.ndarray]:
    """Linear RGB, and gamut-mapped linear RGB, of a colourspace (compiled once per shape). The
    encoding is applied outside: some colourspaces' encodings are evaluated in NumPy."""
    return XYZ_to_RGB(XYZ, conv), XYZ_to_display_RGB(XYZ, conv, encode=False)


def _cos(angle_deg: float) -> float:
    a = float(angle_deg)
    if not (math.isfinite(a) and 0 <= a <= 90):
        raise ValueError(f"angle_deg must be in [0, 90], got {angle_deg!r}")
    return 0.0 if a == 90 else math.cos(math.radians(a))


def reflectance_spectrum(
    material: Material, angle_deg: float = 0.0, wavelength_nm: Float[ArrayLike, " bands"] | None = None
) -> tuple[str, Float[np.ndarray, " bands"]]:
    """``(quantity, R)``: the reflected spectrum (or RGB) the report is the colour of.

    ``quantity`` is ``"F(theta)"`` (specular part present) or ``"pi*Rd"`` (diffuse only). ``R``
    has one value per ``wavelength_nm`` (spectral materials; default: the material's own
    wavelengths), or per R, G, B channel (RGB materials).

    >>> from ctfit import material_from_dict
    >>> glass = material_from_dict({"s": 1, "lobes": [{"m": 0.2}], "channels": ["R", "G", "B"], "n": 1.5})
    >>> quantity, r = reflectance_spectrum(glass, 60.0)
    >>> quantity, [round(float(v), 4) for v in r]  # F(60°) of n = 1.5: 0.089, up from F0 = 0.04
    ('F(theta)', [0.0892, 0.0892, 0.0892])
    """
    cos = _cos(angle_deg)
    st = material.structure
    n_bands: int | None
    if material.is_rgb:
        params = material.params_at(channels=("R", "G", "B"))
        n_bands = 3
    elif material.wavelength_nm is None:
        params = material.params  # scalar (grey) parameters
        n_bands = None if wavelength_nm is None else np.size(wavelength_nm)
    else:
        wl = material.wavelength_nm if wavelength_nm is None else wavelength_nm
        params = material.params_at(wavelength_nm=wl)
        n_bands = np.size(wl)
    if st.has_specular:
        quantity, r = "F(theta)", _fresnel(st, params, np.asarray(cos))
    else:
        quantity, r = "pi*Rd", _ambient(st, params)
    r = np.asarray(r, dtype=float)
    if n_bands is not None:
        r = np.broadcast_to(r, (n_bands,)).copy()
    return quantity, r


def _hex(srgb: ArrayLike) -> str:
    v = np.clip(np.round(np.asarray(srgb, dtype=float) * 255), 0, 255).astype(int)
    return "#" + "".join(f"{c:02x}" for c in v)


class _Reflection(NamedTuple):
    """The reflected colour before its conversions: XYZ (float64), its white and the conversion."""

    quantity: str
    XYZ: np.ndarray
    eps: float  # machine epsilon of the dtype the spectrum was integrated in
    white_XYZ: np.ndarray
    illuminant: str
    conversion: RGBConversion  # to the report's colourspace


def _reflection(
    material: Material, angle_deg: float, illuminant: Any, colourspace: str, observer: str, chromatic_adaptation: str | None
) -> _Reflection:
    """XYZ of the reflected spectrum (spectral materials) or of the linear RGB (RGB materials)."""
    if material.is_rgb:
        conv = rgb_conversion(colourspace, None, None)
        quantity, r = reflectance_spectrum(material, angle_deg)
        XYZ = RGB_to_XYZ(np.asarray(r, dtype=float), conv)
        return _Reflection(quantity, np.asarray(XYZ, dtype=float), float(np.finfo(XYZ.dtype).eps), conv.white_XYZ, f"{colourspace} white", conv)
    warn_outside_visible(material)
    grid = np.asarray(observer_cmfs(observer).wavelengths, dtype=float)
    quantity, r = reflectance_spectrum(material, angle_deg, grid)
    weights = spectral_weights(grid, illuminant, observer)
    conv = rgb_conversion(colourspace, weights.white_XYZ, chromatic_adaptation)
    XYZ = _spectrum_to_XYZ(r, weights)
    white = np.asarray(weights.white_XYZ, dtype=float)
    return _Reflection(quantity, np.asarray(XYZ, dtype=float), float(np.finfo(XYZ.dtype).eps), white, weights.illuminant, conv)


def _shown(XYZ: ArrayLike, conv: RGBConversion) -> tuple[np.ndarray, np.ndarray]:
    """(linear RGB, encoded gamut-mapped RGB) of ``conv``'s colourspace."""
    lin, mapped = _to_rgb(XYZ, conv)
    return np.asarray(lin, dtype=float), np.asarray(encode_RGB(mapped, conv.colourspace), dtype=float)


def _dominant(xy: ArrayLike, white_xy: ArrayLike, observer: str, eps: float) -> tuple[float, float]:
    """Dominant wavelength and excitation purity; (NaN, 0) for a white up to the dtype's rounding."""
    lam = float(dominant_wavelength(xy, white_xy, observer))
    purity = float(excitation_purity(xy, white_xy, observer))
    if purity < 100 * eps:  # a white, up to the rounding of the dtype the spectrum was integrated in
        return math.nan, 0.0
    return lam, purity


def colour_report(
    material: Material,
    angle_deg: float = 0.0,
    illuminant: str | tuple[Float[ArrayLike, " wavelengths"], Float[ArrayLike, " wavelengths"]] = "D65",
    colourspace: str = "sRGB",
    observer: str = DEFAULT_OBSERVER,
    chromatic_adaptation: str | None = "CAT02",
) -> dict:
    """The reflectance colour of ``material`` at ``angle_deg`` (see the module docstring).

    Keys (JSON-ready: floats, lists, strings; None where undefined):

    - ``XYZ``: CIE XYZ, Y of a perfect white reflector = 1; ``xy``: its chromaticity (the
      white's for black); ``white_XYZ``, ``white_xy``: the illuminant's white.
    - ``linear_rgb``: linear RGB of ``colourspace`` after chromatic adaptation, before gamut
      mapping (may be < 0 or > 1); ``in_gamut``: whether it is inside [0, 1]³ (to 1e-9, or
      100 machine epsilons in float32).
    - ``rgb``: encoded RGB of ``colourspace`` after the paper's gamut mapping
      (:func:`ctfit.desaturate_to_gamut`, upper 1), in [0, 1]; not scaled.
    - ``sRGB``: the same for sRGB (equal to ``rgb`` when ``colourspace`` is sRGB); ``hex``:
      ``"#rrggbb"`` of ``sRGB``.
    - ``Lab``: CIELAB relative to the illuminant's white (colour-science's ``XYZ_to_Lab``).
    - ``dominant_wavelength_nm``: seen from the illuminant's white; negative for purples
      (−complementary wavelength); None for achromatic colours (excitation purity below
      100 machine epsilons of the computation's dtype, then reported as 0).
      ``excitation_purity``.
    - ``quantity`` (``"F(theta)"`` or ``"pi*Rd"``), ``material``, ``angle_deg``,
      ``illuminant``, ``observer``, ``colourspace``, ``chromatic_adaptation``.

    >>> from ctfit import material_from_dict
    >>> gold = material_from_dict({"s": 1, "lobes": [{"m": 0.3}], "optical_constants": "Au"})
    >>> report = colour_report(gold)
    >>> report["hex"], round(report["dominant_wavelength_nm"])  # at normal incidence: yellow
    ('#ffdeae', 579)
    """
    material.check_colour_channels()
    if material.band_unknown:
        raise ValueError(
            f"material {material.name!r}: its band's wavelength is unknown (single-band data), so there is no colour to report"
        )
    c = _reflection(material, angle_deg, illuminant, colourspace, observer, chromatic_adaptation)
    if not np.all(np.isfinite(c.XYZ)):  # the model is finite on its domain: a guard, not a path
        raise ValueError(f"material {material.name!r}: its {c.quantity} at {float(angle_deg):g}° is not finite, so there is no colour to report")
    white_xy = c.white_XYZ[:2] / c.white_XYZ.sum()
    lin, rgb = _shown(c.XYZ, c.conversion)
    if colourspace == "sRGB":
        srgb = rgb
    else:  # an RGB material in another colourspace goes through XYZ, adapted with CAT02 by default
        adaptation = (chromatic_adaptation or "CAT02") if material.is_rgb else chromatic_adaptation
        srgb = _shown(c.XYZ, rgb_conversion("sRGB", c.white_XYZ, adaptation))[1]
    xy = np.asarray(XYZ_to_xy(c.XYZ, white_xy), dtype=float)
    lam, purity = _dominant(xy, white_xy, observer, c.eps)
    return {
        "material": material.name,
        "quantity": c.quantity,
        "angle_deg": float(angle_deg),
        "illuminant": c.illuminant,
        "observer": observer,
        "colourspace": colourspace,
        "chromatic_adaptation": chromatic_adaptation if not material.is_rgb else None,
        "XYZ": float_list(c.XYZ),
        "xy": float_list(xy),
        "white_XYZ": float_list(c.white_XYZ),
        "white_xy": float_list(white_xy),
        "linear_rgb": float_list(lin),
        "in_gamut": bool(in_gamut(lin, atol=max(1e-9, 100 * c.eps))),
        "rgb": float_list(rgb),
        "sRGB": float_list(srgb),
        "hex": _hex(srgb),
        "Lab": float_list(colour_science().XYZ_to_Lab(c.XYZ, illuminant=white_xy)),
        "dominant_wavelength_nm": None if not math.isfinite(lam) else lam,
        "excitation_purity": None if not math.isfinite(purity) else purity,
    }
