"""Colorimetry in JAX: reflectance spectrum → CIE XYZ → linear RGB → encoded RGB.

The pipeline (``docs/colour.md`` states it with every normalisation):

1. :func:`spectral_weights` builds, once and in NumPy, the weights ``W`` (λ, 3) that turn a
   reflectance spectrum sampled at given wavelengths into CIE XYZ under an illuminant S for an
   observer with colour-matching functions x̄, ȳ, z̄ (CIE 15:2004 §7.1):

       XYZ = Σ_λ R(λ) W(λ),   W(λ) = S(λ) [x̄ ȳ z̄](λ) Δ(λ) / Σ_λ S(λ) ȳ(λ) Δ(λ),

   so that a perfect white reflector (R ≡ 1) has Y = 1: its XYZ is the illuminant's white.
   Δ(λ) is the width of the wavelength cell each sample stands for (half-way to each
   neighbour, the end cells symmetric); on a uniform grid Δ = Δλ and this is CIE 15's
   summation, which is colour-science's ``sd_to_XYZ(..., method="Integration")``.
   The CMFs and illuminants come from colour-science (``colour.MSDS_CMFS``,
   ``colour.SDS_ILLUMINANTS``); nothing is copied by hand.
2. :func:`spectrum_to_XYZ` is then one matrix product: fast and differentiable.
3. :func:`rgb_conversion` builds the XYZ → linear RGB matrix of a colourspace from
   ``colour.RGB_COLOURSPACES``, with a von Kries chromatic adaptation (CAT02 by default) from
   the illuminant's white to the colourspace's white, so that a perfect white reflector gives
   linear RGB (1, 1, 1) exactly.
4. :func:`encode_RGB` applies the colourspace's encoding (sRGB's piecewise curve in JAX;
   other curves through colour-science in NumPy — not differentiable).

Resampling is never silent: when the spectrum's wavelengths are not on the 1 nm grid of the
colour-matching functions, or a user-supplied illuminant must be interpolated or extrapolated,
:class:`SpectralResamplingWarning` is issued. The tabulated CIE illuminants (5 nm) are
interpolated with the interpolator colour-science attaches to them (linear for the CIE
illuminants) and held constant beyond their range, without a warning; this is the documented
default, identical to what colour-science does.

Nothing here switches on float64; the dtypes follow the inputs (weights are cast to the
spectrum's floating dtype).

References
----------
- CIE 015:2004 Colorimetry, 3rd edition. §7.1 (tristimulus values), §8.2.1 (CIELAB),
  §9.1 (dominant wavelength and purity). ISBN 978-3-901906-33-6.
- Sharma, G., Wu, W. and Dalal, E. N. (2005). The CIEDE2000 colour-difference formula:
  implementation notes, supplementary test data, and mathematical observations.
  Color Research & Application 30(1), 21–30. doi:10.1002/col.20070
- IEC 61966-2-1:1999 (sRGB).
- Mansencal, T., Mauderer, M., Parsons, M., et al. Colour (colour-science for Python) 0.4.7.
  doi:10.5281/zenodo.17837391
- Cook, R. L. and Torrance, K. E. (1982). A Reflectance Model for Computer Graphics.
  ACM Transactions on Graphics 1(1), 7–24, §4. doi:10.1145/357290.357293
"""

from __future__ import annotations

import functools
import warnings

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._model import safe_sqrt
from .gamut import desaturate_to_gamut

__all__ = [
    "DEFAULT_OBSERVER",
    "SpectralResamplingWarning",
    "SpectralWeights",
    "spectral_weights",
    "spectrum_to_XYZ",
    "RGBConversion",
    "rgb_conversion",
    "XYZ_to_RGB",
    "RGB_to_XYZ",
    "eotf_inverse_sRGB",
    "encode_RGB",
    "XYZ_to_display_RGB",
    "spectrum_to_RGB",
    "XYZ_to_xy",
    "XYZ_to_Lab",
    "delta_E_CIE2000",
    "dominant_wavelength",
    "excitation_purity",
]

DEFAULT_OBSERVER = "CIE 1931 2 Degree Standard Observer"


class SpectralResamplingWarning(UserWarning):
    """Colour-matching functions or an illuminant had to be interpolated to the spectrum.

    >>> import warnings, numpy as np
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     _ = spectral_weights(np.arange(400.5, 700.0, 10.0))  # off the CMFs' 1 nm grid
    >>> caught[0].category.__name__
    'SpectralResamplingWarning'
    """


def colour_science():
    """The colour-science package, imported on first use (it takes a while). Its import sets
    NumPy's print options to ``legacy="1.13"``; ctfit keeps the user's settings as they were."""
    with np.printoptions():
        import colour  # noqa: PLC0415  (heavy; imported on first use)

    return colour


def _entry(table: str, key: str, what: str, names: list[str], also: str = ""):
    """``colour.<table>[key]``; a ValueError naming ``what`` and ``names`` (some of the keys) if absent."""
    try:
        return getattr(colour_science(), table)[key]
    except KeyError:
        raise ValueError(f"unknown {what} {key!r}; one of colour.{table}, e.g. {names}{also}") from None


@functools.cache
def observer_cmfs(observer: str):
    """The colour-matching functions of ``observer`` (a name in ``colour.MSDS_CMFS``)."""
    names = sorted(k for k in colour_science().MSDS_CMFS.keys() if "Observer" in k)
    return _entry("MSDS_CMFS", observer, "observer", names)


def _illuminant_sd(illuminant):
    """(name, SpectralDistribution, user_supplied) from a name, an SD or (wavelengths, values)."""
    colour = colour_science()
    if isinstance(illuminant, str):
        names = list(colour.SDS_ILLUMINANTS.keys())[:12]
        return illuminant, _entry("SDS_ILLUMINANTS", illuminant, "illuminant", names, ", or a (wavelengths, values) pair"), False
    if isinstance(illuminant, colour.SpectralDistribution):
        return illuminant.name, illuminant, True
    try:
        wl, values = illuminant
        wl = np.asarray(wl, dtype=float)
        values = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise TypeError(
            "illuminant must be a colour-science name, a colour.SpectralDistribution or a "
            f"(wavelengths, values) pair, got {type(illuminant).__name__}"
        ) from None
    if wl.ndim != 1 or wl.shape != values.shape or wl.size < 2:
        raise ValueError("an illuminant (wavelengths, values) needs two 1-D arrays of equal length ≥ 2")
    if not (np.all(np.isfinite(wl)) and np.all(np.isfinite(values)) and np.all(np.diff(wl) > 0)):
        raise ValueError("illuminant wavelengths must be finite and increasing, values finite")
    sd = colour.SpectralDistribution(values, wl, name="custom", interpolator=colour.LinearInterpolator)
    return "custom", sd, True


def _on_grid(wl, grid):
    """Indices of ``wl`` in ``grid`` when every value is a node (to 1e-9 nm), else None."""
    idx = np.clip(np.searchsorted(grid, wl), 0, grid.size - 1)
    idx_lo = np.clip(idx - 1, 0, grid.size - 1)
    best = np.where(np.abs(grid[idx] - wl) <= np.abs(grid[idx_lo] - wl), idx, idx_lo)
    return best if np.all(np.abs(grid[best] - wl) < 1e-9) else None


def _warn_resampling(message: str) -> None:
    """A :class:`SpectralResamplingWarning` attributed to the caller of :func:`spectral_weights`."""
    warnings.warn(message, SpectralResamplingWarning, stacklevel=3)


def _cell_widths(wl):
    """Δ(λ): half-way to each neighbour; the end cells are symmetric (Δλ on a uniform grid)."""
    d = np.diff(wl)
    left = np.concatenate([d[:1], d])
    right = np.concatenate([d, d[-1:]])
    return 0.5 * (left + right)


class SpectralWeights(eqx.Module):
    """Integration weights of a wavelength grid: XYZ = reflectance @ ``weights``.

    - ``wavelength_nm``: the spectrum's wavelengths, shape (λ,).
    - ``weights``: shape (λ, 3), zero outside the observer's tabulated range (360–830 nm).
    - ``white_XYZ``: XYZ of a perfect white reflector, ``weights.sum(0)``; Y = 1.
    - ``illuminant``, ``observer``: names (``"custom"`` for a user spectrum).

    Build it with :func:`spectral_weights`.

    >>> import numpy as np
    >>> w = spectral_weights(np.arange(400.0, 701.0, 10.0))
    >>> w.weights.shape, w.illuminant, [round(float(v), 4) for v in w.white_xy]
    ((31, 3), 'D65', [0.3127, 0.3293])
    """

    wavelength_nm: np.ndarray
    weights: np.ndarray
    white_XYZ: np.ndarray
    illuminant: str = eqx.field(static=True)
    observer: str = eqx.field(static=True)

    @property
    def white_xy(self) -> np.ndarray:
        w = np.asarray(self.white_XYZ)
        return w[:2] / w.sum()


def spectral_weights(wavelength_nm, illuminant="D65", observer: str = DEFAULT_OBSERVER) -> SpectralWeights:
    """Weights that integrate a reflectance spectrum on ``wavelength_nm`` to XYZ (Y(white) = 1).

    ``illuminant`` is a name from ``colour.SDS_ILLUMINANTS`` ("D65", the paper's "D6500", by
    default), a ``colour.SpectralDistribution`` or a ``(wavelengths, values)`` pair (linearly
    interpolated). ``observer`` is a name from ``colour.MSDS_CMFS``, e.g.
    "CIE 1931 2 Degree Standard Observer" (default) or "CIE 1964 10 Degree Standard Observer".

    Wavelengths outside the observer's range contribute nothing; if the grid covers less than
    that range, the integral (and its white normalisation) covers the grid only, as
    colour-science does for spectral arrays. Warns with :class:`SpectralResamplingWarning` when
    the CMFs (1 nm) must be interpolated to off-grid wavelengths (colour-science's Sprague
    interpolator), or a user-supplied illuminant to wavelengths it does not list.

    Examples
    --------
    >>> import numpy as np
    >>> w = spectral_weights(np.arange(360.0, 831.0, 5.0))
    >>> [round(float(v), 4) for v in w.white_XYZ]  # D65's white point, Y = 1
    [0.9505, 1.0, 1.089]
    """
    wl = np.asarray(wavelength_nm, dtype=float)
    if wl.ndim != 1 or wl.size < 2:
        raise ValueError(f"wavelength_nm must be a 1-D array of at least 2 wavelengths, got shape {wl.shape}")
    if not np.all(np.isfinite(wl)) or not np.all(np.diff(wl) > 0):
        raise ValueError("wavelength_nm must be finite and strictly increasing")
    cmfs = observer_cmfs(observer)
    grid = np.asarray(cmfs.wavelengths, dtype=float)
    inside = (wl >= grid[0] - 1e-9) & (wl <= grid[-1] + 1e-9)
    if not inside.any():
        raise ValueError(
            f"no wavelength of {wl.min():g}–{wl.max():g} nm lies in the range of the {observer} "
            f"({grid[0]:g}–{grid[-1]:g} nm)"
        )
    wl_in = wl[inside]
    idx = _on_grid(wl_in, grid)
    if idx is not None:
        cmf = np.asarray(cmfs.values, dtype=float)[idx]
    else:
        _warn_resampling(
            f"the {observer} colour-matching functions (tabulated every {cmfs.shape.interval:g} nm) "
            f"are interpolated (Sprague) to {wl_in.size} wavelengths not all on that grid"
        )
        cmf = np.asarray(cmfs[wl_in], dtype=float)

    name, sd, user = _illuminant_sd(illuminant)
    sd_wl = np.asarray(sd.wavelengths, dtype=float)
    if user and (_on_grid(wl_in, sd_wl) is None):
        outside = np.any((wl_in < sd_wl[0]) | (wl_in > sd_wl[-1]))
        _warn_resampling(
            f"illuminant {name!r} is {'interpolated and extrapolated' if outside else 'interpolated'} "
            f"to the spectrum's wavelengths ({sd_wl[0]:g}–{sd_wl[-1]:g} nm tabulated)"
        )
    s = np.asarray(sd[wl_in], dtype=float)

    w_in = s[:, None] * cmf * _cell_widths(wl)[inside][:, None]
    norm = w_in[:, 1].sum()
    if not norm > 0:
        raise ValueError(f"illuminant {name!r} has no luminance over {wl_in[0]:g}–{wl_in[-1]:g} nm")
    weights = np.zeros((wl.size, 3))
    weights[inside] = w_in / norm
    return SpectralWeights(
        wavelength_nm=wl, weights=weights, white_XYZ=weights.sum(0), illuminant=name, observer=observer
    )


def _float_dtype(x):
    return x.dtype if jnp.issubdtype(x.dtype, jnp.floating) else jnp.result_type(float)


def spectrum_to_XYZ(reflectance, weights: SpectralWeights):
    """CIE XYZ (…, 3) of reflectance spectra (…, λ) on ``weights.wavelength_nm``.

    Y of a perfect white reflector is 1. One matrix product: differentiable, batched.
    Non-finite values propagate (a NaN anywhere in a spectrum gives NaN XYZ).

    >>> import numpy as np
    >>> w = spectral_weights(np.arange(360.0, 831.0, 5.0))
    >>> [round(float(v), 4) for v in spectrum_to_XYZ(np.full(95, 0.5), w)]  # a 50 % grey under D65
    [0.4752, 0.5, 0.5445]
    """
    r = jnp.asarray(reflectance)
    r = r.astype(_float_dtype(r))
    n = np.shape(weights.weights)[0]
    if r.ndim == 0 or r.shape[-1] != n:
        raise ValueError(f"reflectance must have {n} wavelengths on its last axis, got shape {r.shape}")
    return r @ jnp.asarray(weights.weights).astype(r.dtype)


@functools.cache
def _colourspace(name: str):
    return _entry("RGB_COLOURSPACES", name, "colourspace", sorted(colour_science().RGB_COLOURSPACES.keys())[:12])


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

    matrix: np.ndarray
    luminance: np.ndarray
    colourspace: str = eqx.field(static=True)
    chromatic_adaptation: str | None = eqx.field(static=True)

    @property
    def white_XYZ(self) -> np.ndarray:
        """The scene white that maps to RGB (1, 1, 1)."""
        return np.linalg.solve(np.asarray(self.matrix), np.ones(3))


def rgb_conversion(colourspace: str = "sRGB", white_XYZ=None, chromatic_adaptation: str | None = "CAT02") -> RGBConversion:
    """The XYZ → linear RGB conversion of ``colourspace`` (any name in ``colour.RGB_COLOURSPACES``).

    ``white_XYZ`` is the scene white (e.g. ``SpectralWeights.white_XYZ``). With a
    ``chromatic_adaptation`` transform ("CAT02", "Bradford", any of
    ``colour.CHROMATIC_ADAPTATION_TRANSFORMS``), the von Kries matrix maps it to the
    colourspace's white ``M⁻¹ (1, 1, 1)`` (M: the colourspace's published XYZ → RGB matrix), so
    that the scene white is RGB (1, 1, 1) exactly. ``white_XYZ=None`` or
    ``chromatic_adaptation=None`` passes XYZ to M unchanged.

    >>> import numpy as np
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


def XYZ_to_RGB(XYZ, conversion: RGBConversion):
    """Linear RGB (…, 3) from XYZ (…, 3); no encoding, no gamut mapping (channels may be < 0).

    >>> import numpy as np
    >>> conv = rgb_conversion("sRGB")
    >>> [round(float(v), 4) for v in XYZ_to_RGB(np.array([0.4124, 0.2126, 0.0193]), conv)]  # sRGB's red primary
    [1.0, 0.0, 0.0]
    """
    x = jnp.asarray(XYZ)
    x = x.astype(_float_dtype(x))
    return x @ jnp.asarray(conversion.matrix).astype(x.dtype).T


def RGB_to_XYZ(rgb, conversion: RGBConversion):
    """Inverse of :func:`XYZ_to_RGB`.

    >>> import numpy as np
    >>> [round(float(v), 4) for v in RGB_to_XYZ(np.ones(3), rgb_conversion("sRGB"))]  # sRGB's white, D65
    [0.9505, 1.0, 1.089]
    """
    x = jnp.asarray(rgb)
    x = x.astype(_float_dtype(x))
    return x @ jnp.asarray(np.linalg.inv(np.asarray(conversion.matrix))).astype(x.dtype).T


def eotf_inverse_sRGB(L):
    """sRGB encoding (IEC 61966-2-1): 12.92 L for L ≤ 0.0031308, else 1.055 L^(1/2.4) − 0.055.

    JAX, differentiable everywhere (the power is never evaluated at 0). Negative values use
    the linear segment; NaN and ±inf propagate.

    >>> import numpy as np
    >>> [round(float(v), 4) for v in eotf_inverse_sRGB(np.array([0.0, 0.002, 0.18, 1.0]))]  # 18 % grey → 0.46
    [0.0, 0.0258, 0.4614, 1.0]
    """
    L = jnp.asarray(L)
    L = L.astype(_float_dtype(L))
    big = L > 0.0031308
    safe = jnp.where(big, L, 1)
    return jnp.where(big, 1.055 * safe ** (1 / 2.4) - 0.055, 12.92 * L)


def encode_RGB(rgb, colourspace: str = "sRGB"):
    """Apply the colourspace's encoding (its ``cctf_encoding``) to linear RGB.

    In JAX (differentiable, jittable) when the encoding is sRGB's curve (sRGB, Display P3, …)
    or linear (ACES2065-1, …). Any other curve is colour-science's own function on NumPy
    arrays: not differentiable and not traceable (a TypeError says so under jit/grad).

    >>> import numpy as np
    >>> [round(float(encode_RGB(np.array([0.18]), cs)[0]), 4) for cs in ("sRGB", "Adobe RGB (1998)", "ACES2065-1")]
    [0.4614, 0.4585, 0.18]
    """
    colour = colour_science()
    cs = _colourspace(colourspace)
    if cs.cctf_encoding is colour.models.eotf_inverse_sRGB:
        return eotf_inverse_sRGB(rgb)
    if cs.cctf_encoding is colour.linear_function:
        return jnp.asarray(rgb)
    try:
        a = np.asarray(rgb, dtype=float)
    except Exception as e:  # a tracer
        raise TypeError(
            f"the encoding of {colourspace!r} is evaluated by colour-science in NumPy and cannot be "
            "traced or differentiated; encode outside jit/grad, or use a colourspace with the sRGB curve"
        ) from e
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.asarray(cs.cctf_encoding(a), dtype=float)


def XYZ_to_display_RGB(XYZ, conversion: RGBConversion, *, upper=1.0, encode=True):
    """XYZ (…, 3) → linear RGB → the paper's gamut mapping → encoding: the colour to show.

    The gamut mapping is :func:`ctfit.desaturate_to_gamut` with the colourspace's luminance and
    ``upper`` (None: only negative channels are mapped); ``encode=False`` stops before the
    encoding (:func:`encode_RGB`). Differentiable for colourspaces whose encoding is evaluated
    in JAX.

    >>> import numpy as np
    >>> w = spectral_weights(np.arange(360.0, 831.0, 5.0))
    >>> conv = rgb_conversion("sRGB", w.white_XYZ)
    >>> [round(float(v), 4) for v in XYZ_to_display_RGB(w.white_XYZ * 0.2, conv)]  # 20 % grey, encoded
    [0.4845, 0.4845, 0.4845]
    """
    rgb = desaturate_to_gamut(XYZ_to_RGB(XYZ, conversion), conversion.luminance, upper=upper)
    return encode_RGB(rgb, conversion.colourspace) if encode else rgb


def spectrum_to_RGB(reflectance, weights: SpectralWeights, conversion: RGBConversion, *, upper=1.0, encode=True):
    """The whole pipeline: reflectance (…, λ) → XYZ → :func:`XYZ_to_display_RGB`.

    >>> import numpy as np
    >>> wl = np.arange(360.0, 831.0, 5.0)
    >>> w = spectral_weights(wl)
    >>> conv = rgb_conversion("sRGB", w.white_XYZ)
    >>> red = np.where(wl > 600, 0.9, 0.05)  # reflects the long wavelengths
    >>> [round(float(v), 3) for v in spectrum_to_RGB(red, w, conv)]
    [0.869, 0.13, 0.223]
    """
    return XYZ_to_display_RGB(spectrum_to_XYZ(reflectance, weights), conversion, upper=upper, encode=encode)


def _safe_div(a, b):
    ok = b != 0
    return jnp.where(ok, a / jnp.where(ok, b, 1), 0), ok


def XYZ_to_xy(XYZ, xy_n=None):
    """CIE xy chromaticity (…, 2). Where X + Y + Z = 0 (black) it is ``xy_n`` if given, else (0, 0).

    >>> import numpy as np
    >>> [round(float(v), 4) for v in XYZ_to_xy(np.array([0.9505, 1.0, 1.089]))]  # D65's white point
    [0.3127, 0.329]
    """
    x = jnp.asarray(XYZ)
    x = x.astype(_float_dtype(x))
    s = jnp.sum(x, axis=-1, keepdims=True)
    xy, ok = _safe_div(x[..., :2], s)
    if xy_n is not None:
        xy = jnp.where(ok, xy, jnp.asarray(xy_n).astype(x.dtype))
    return xy


_LAB_EPS = (6 / 29) ** 3


def _lab_f(t):
    big = t > _LAB_EPS
    safe = jnp.where(big, t, 1)
    return jnp.where(big, jnp.cbrt(safe), t / (3 * (6 / 29) ** 2) + 4 / 29)


def XYZ_to_Lab(XYZ, white_XYZ):
    """CIELAB (CIE 15:2004 §8.2.1) relative to ``white_XYZ``: L* = 100 for the white. JAX.

    Differentiable at black (the cube root is only taken above (6/29)³).

    >>> import numpy as np
    >>> white = np.array([0.9505, 1.0, 1.089])
    >>> [round(float(v), 2) for v in XYZ_to_Lab(0.18 * white, white)]  # an 18 % grey: L* ≈ 50
    [49.5, 0.0, 0.0]
    """
    x = jnp.asarray(XYZ)
    x = x.astype(_float_dtype(x))
    f = _lab_f(x / jnp.asarray(white_XYZ).astype(x.dtype))
    fx, fy, fz = f[..., 0], f[..., 1], f[..., 2]
    return jnp.stack([116 * fy - 16, 500 * (fx - fy), 200 * (fy - fz)], axis=-1)


def _safe_atan2_deg(y, x):
    zero = (x == 0) & (y == 0)
    h = jnp.degrees(jnp.arctan2(jnp.where(zero, 0, y), jnp.where(zero, 1, x)))
    return jnp.where(zero, 0, jnp.mod(h, 360))


def delta_E_CIE2000(Lab1, Lab2):
    """CIEDE2000 colour difference (k_L = k_C = k_H = 1; Sharma et al. 2005). JAX.

    Agrees with ``colour.delta_E(..., method="CIE 2000")``; differentiable, with zero gradient
    where both colours are equal or achromatic (the hue terms are switched off there).

    >>> import numpy as np
    >>> round(float(delta_E_CIE2000(np.array([50, 2.6772, -79.7751]), np.array([50, 0, -82.7485]))), 4)  # Sharma's pair 1
    2.0425
    """
    L1, a1, b1 = (jnp.asarray(Lab1)[..., i] for i in range(3))
    L2, a2, b2 = (jnp.asarray(Lab2)[..., i] for i in range(3))
    c_bar = 0.5 * (safe_sqrt(a1 * a1 + b1 * b1) + safe_sqrt(a2 * a2 + b2 * b2))
    c7 = c_bar**7
    g = 0.5 * (1 - safe_sqrt(c7 / (c7 + 25.0**7)))
    a1p, a2p = (1 + g) * a1, (1 + g) * a2
    c1p, c2p = safe_sqrt(a1p * a1p + b1 * b1), safe_sqrt(a2p * a2p + b2 * b2)
    h1p, h2p = _safe_atan2_deg(b1, a1p), _safe_atan2_deg(b2, a2p)
    chroma = c1p * c2p != 0
    dh = h2p - h1p
    dh = jnp.where(dh > 180, dh - 360, jnp.where(dh < -180, dh + 360, dh))
    dh = jnp.where(chroma, dh, 0)
    dL = L2 - L1
    dC = c2p - c1p
    dH = 2 * safe_sqrt(c1p * c2p) * jnp.sin(jnp.radians(dh / 2))
    L_bar = 0.5 * (L1 + L2)
    cp_bar = 0.5 * (c1p + c2p)
    hsum = h1p + h2p
    h_bar = jnp.where(
        jnp.abs(h1p - h2p) <= 180, 0.5 * hsum, jnp.where(hsum < 360, 0.5 * (hsum + 360), 0.5 * (hsum - 360))
    )
    h_bar = jnp.where(chroma, h_bar, hsum)
    t = (
        1
        - 0.17 * jnp.cos(jnp.radians(h_bar - 30))
        + 0.24 * jnp.cos(jnp.radians(2 * h_bar))
        + 0.32 * jnp.cos(jnp.radians(3 * h_bar + 6))
        - 0.20 * jnp.cos(jnp.radians(4 * h_bar - 63))
    )
    d_theta = 30 * jnp.exp(-(((h_bar - 275) / 25) ** 2))
    cp7 = cp_bar**7
    r_c = 2 * safe_sqrt(cp7 / (cp7 + 25.0**7))
    l50 = (L_bar - 50) ** 2
    s_l = 1 + 0.015 * l50 / jnp.sqrt(20 + l50)
    s_c = 1 + 0.045 * cp_bar
    s_h = 1 + 0.015 * cp_bar * t
    r_t = -jnp.sin(jnp.radians(2 * d_theta)) * r_c
    tl, tc, th = dL / s_l, dC / s_c, dH / s_h
    return safe_sqrt(tl * tl + tc * tc + th * th + r_t * tc * th)


# ---- dominant wavelength and excitation purity (CIE 15:2004 §9.1), NumPy, for reports ----


@functools.cache
def _locus(observer: str):
    cmfs = observer_cmfs(observer)
    v = np.asarray(cmfs.values, dtype=float)
    return v[:, :2] / v.sum(1, keepdims=True), np.asarray(cmfs.wavelengths, dtype=float)


def _first_hit(origin, direction, observer, *, purple: bool):
    """Ray origin + t·direction (t > 0) against the spectral locus (and the purple line if asked).

    Returns (t, wavelength, segment is purple line) for the smallest t; t = inf where nothing is hit.
    """
    xy_s, wl = _locus(observer)
    p0, p1 = xy_s[:-1], xy_s[1:]
    w0, w1 = wl[:-1], wl[1:]
    if purple:
        p0 = np.vstack([p0, xy_s[-1:]])
        p1 = np.vstack([p1, xy_s[:1]])
        w0 = np.append(w0, np.nan)
        w1 = np.append(w1, np.nan)
    e = p1 - p0  # (S, 2)
    o = origin[..., None, :]
    d = direction[..., None, :]
    w = p0 - o  # (…, S, 2)
    den = d[..., 0] * e[:, 1] - d[..., 1] * e[:, 0]
    ok = np.abs(den) > 1e-300
    den = np.where(ok, den, 1)
    t = (w[..., 0] * e[:, 1] - w[..., 1] * e[:, 0]) / den
    u = (w[..., 0] * d[..., 1] - w[..., 1] * d[..., 0]) / den
    hit = ok & (t > 1e-12) & (u >= -1e-12) & (u <= 1 + 1e-12)
    t = np.where(hit, t, np.inf)
    j = np.argmin(t, axis=-1)
    t_best = np.take_along_axis(t, j[..., None], -1)[..., 0]
    u_best = np.clip(np.take_along_axis(u, j[..., None], -1)[..., 0], 0, 1)
    lam = w0[j] + u_best * (w1[j] - w0[j])
    return t_best, lam, np.isnan(lam) & np.isfinite(t_best)


def _dominant(xy, xy_n, observer):
    xy = np.asarray(xy, dtype=float)
    xy_n = np.broadcast_to(np.asarray(xy_n, dtype=float), xy.shape)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        d = xy - xy_n
        t, lam, on_purple = _first_hit(xy_n, d, observer, purple=True)
        _, lam_c, _ = _first_hit(xy_n, -d, observer, purple=False)
        lam = np.where(on_purple, -lam_c, lam)
        # Closer than 1e-12 to the white (rounding, e.g. a reflectance of exactly 1): achromatic.
        achromatic = ~np.isfinite(t) | (np.hypot(d[..., 0], d[..., 1]) <= 1e-12)
        lam = np.where(achromatic, np.nan, lam)
        purity = np.where(achromatic, 0.0, 1 / np.where(np.isfinite(t) & (t > 0), t, np.inf))
        bad = ~np.all(np.isfinite(xy), axis=-1) | ~np.all(np.isfinite(xy_n), axis=-1)
        lam = np.where(bad, np.nan, lam)
        purity = np.where(bad, np.nan, purity)
    return lam, purity


def dominant_wavelength(xy, xy_n, observer: str = DEFAULT_OBSERVER) -> np.ndarray:
    """Dominant wavelength (nm) of chromaticities ``xy`` (…, 2) seen against the white ``xy_n``.

    The ray from ``xy_n`` through ``xy`` meets the spectral locus of ``observer`` (its
    tabulated 1 nm points joined by straight segments, as colour-science does) at λ_d,
    interpolated along the segment. Where it meets the line of purples instead, the value is
    −λ_c, the complementary wavelength with a minus sign (colour-science's convention).
    NaN where ``xy`` is within 1e-12 of ``xy_n`` (achromatic) or is not finite. NumPy.

    >>> import numpy as np
    >>> d65 = np.array([0.3127, 0.3290])
    >>> [round(float(v), 1) for v in dominant_wavelength(np.array([[0.5, 0.4], [0.3, 0.15]]), d65)]  # orange, purple
    [589.5, -554.8]
    """
    return _dominant(xy, xy_n, observer)[0]


def excitation_purity(xy, xy_n, observer: str = DEFAULT_OBSERVER) -> np.ndarray:
    """Excitation purity |xy − xy_n| / |xy_b − xy_n|, xy_b the locus or purple-line point. NumPy.

    0 for achromatic colours; greater than 1 outside the spectral locus; NaN for non-finite input.

    >>> import numpy as np
    >>> d65 = np.array([0.3127, 0.3290])
    >>> [round(float(v), 3) for v in excitation_purity(np.array([[0.5, 0.4], [0.3127, 0.3290]]), d65)]
    [0.722, 0.0]
    """
    return _dominant(xy, xy_n, observer)[1]
