"""Spectra to CIE XYZ in JAX, with colour-science's colour-matching functions and illuminants.

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
3. :func:`~ctfit._colour.rgb.rgb_conversion` (:mod:`ctfit._colour.rgb`) builds the XYZ → linear RGB matrix of a colourspace from
   ``colour.RGB_COLOURSPACES``, with a von Kries chromatic adaptation (CAT02 by default) from
   the illuminant's white to the colourspace's white, so that a perfect white reflector gives
   linear RGB (1, 1, 1) exactly.
4. :func:`~ctfit._colour.rgb.encode_RGB` applies the colourspace's encoding (sRGB's piecewise curve in JAX;
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
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._model import float_dtype

__all__ = ["DEFAULT_OBSERVER", "SpectralResamplingWarning", "SpectralWeights", "VISIBLE_NM", "colour_science", "observer_cmfs", "spectral_weights",
           "spectrum_to_XYZ", "table_entry", "warn_outside_visible"]


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


VISIBLE_NM = (380.0, 780.0)
"""The visible range (nm) a spectral material needs one band in for its colour to be measured
(:func:`warn_outside_visible`); the renderer's default bands span it."""


def warn_outside_visible(material: Any) -> None:
    """A :class:`SpectralResamplingWarning` when none of a spectral material's bands lies in
    :data:`VISIBLE_NM`: its colour is then that of its values held from the nearest band across
    the visible (``docs/formats.md``'s rule), not a colour the data holds. RGB materials and
    materials of one band (grey wherever it lies) say nothing.

    >>> import warnings, numpy as np, ctfit
    >>> infrared = ctfit.Material(ctfit.Structure(lobes=0, diffuse="spectrum"), ctfit.Params(rd=np.array([0.2, 0.3])),
    ...                           wavelength_nm=np.array([900.0, 1500.0]), name="ir")
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     warn_outside_visible(infrared)
    >>> print(caught[0].message)
    material 'ir': no band in the visible range (380–780 nm; its bands 900–1500 nm): its colour is its 900 nm value held flat across the visible
    """
    wl = getattr(material, "wavelength_nm", None)
    if material.is_rgb or wl is None or np.size(wl) < 2:
        return
    wl = np.asarray(wl, dtype=float)
    lo, hi = VISIBLE_NM
    if np.any((wl >= lo) & (wl <= hi)):
        return
    if wl.max() < lo or wl.min() > hi:
        held = f"its {(wl.max() if wl.max() < lo else wl.min()):g} nm value held flat across the visible"
    else:
        held = f"interpolated between its {wl[wl < lo].max():g} and {wl[wl > hi].min():g} nm values across the visible"
    warnings.warn(f"material {material.name!r}: no band in the visible range ({lo:g}–{hi:g} nm; its bands {wl.min():g}–{wl.max():g} nm): its colour is {held}",
                  SpectralResamplingWarning, stacklevel=3)


def colour_science() -> Any:
    """The colour-science package, imported on first use (it takes a while). Its import sets
    NumPy's print options to ``legacy="1.13"``; ctfit keeps the user's settings as they were."""
    with np.printoptions():
        import colour  # heavy; imported on first use

    return colour


def table_entry(table: str, key: str, what: str, names: list[str], also: str = "") -> Any:
    """``colour.<table>[key]``; a ValueError naming ``what`` and ``names`` (some of the keys) if absent."""
    try:
        return getattr(colour_science(), table)[key]
    except KeyError:
        raise ValueError(f"unknown {what} {key!r}; one of colour.{table}, e.g. {names}{also}") from None


@functools.cache
def observer_cmfs(observer: str) -> Any:
    """The colour-matching functions of ``observer`` (a name in ``colour.MSDS_CMFS``)."""
    names = sorted(k for k in colour_science().MSDS_CMFS.keys() if "Observer" in k)
    return table_entry("MSDS_CMFS", observer, "observer", names)


def _illuminant_sd(illuminant: str | tuple[Float[ArrayLike, " wavelengths"], Float[ArrayLike, " wavelengths"]]) -> tuple[str, Any, bool]:
    """(name, SpectralDistribution, user_supplied) from a name, an SD or (wavelengths, values)."""
    colour = colour_science()
    if isinstance(illuminant, str):
        names = list(colour.SDS_ILLUMINANTS.keys())[:12]
        return illuminant, table_entry("SDS_ILLUMINANTS", illuminant, "illuminant", names, ", or a (wavelengths, values) pair"), False
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


def _on_grid(wl: np.ndarray, grid: np.ndarray) -> np.ndarray | None:
    """Indices of ``wl`` in ``grid`` when every value is a node (to 1e-9 nm), else None."""
    idx = np.clip(np.searchsorted(grid, wl), 0, grid.size - 1)
    idx_lo = np.clip(idx - 1, 0, grid.size - 1)
    best = np.where(np.abs(grid[idx] - wl) <= np.abs(grid[idx_lo] - wl), idx, idx_lo)
    return best if np.all(np.abs(grid[best] - wl) < 1e-9) else None


def _warn_resampling(message: str) -> None:
    """A :class:`SpectralResamplingWarning` attributed to the caller of :func:`spectral_weights`."""
    warnings.warn(message, SpectralResamplingWarning, stacklevel=3)


def _cell_widths(wl: np.ndarray) -> np.ndarray:
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

    wavelength_nm: Float[np.ndarray, " bands"]
    weights: Float[np.ndarray, "bands 3"]
    white_XYZ: Float[np.ndarray, " 3"]
    illuminant: str = eqx.field(static=True)
    observer: str = eqx.field(static=True)

    @property
    def white_xy(self) -> Float[np.ndarray, " 2"]:
        w = np.asarray(self.white_XYZ)
        return w[:2] / w.sum()


def spectral_weights(
    wavelength_nm: Float[ArrayLike, " bands"],
    illuminant: str | tuple[Float[ArrayLike, " wavelengths"], Float[ArrayLike, " wavelengths"]] = "D65",
    observer: str = DEFAULT_OBSERVER,
) -> SpectralWeights:
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



def spectrum_to_XYZ(reflectance: Float[ArrayLike, "*batch bands"], weights: SpectralWeights) -> Float[Array, "*batch 3"]:
    """CIE XYZ (…, 3) of reflectance spectra (…, λ) on ``weights.wavelength_nm``.

    Y of a perfect white reflector is 1. One matrix product: differentiable, batched.
    Non-finite values propagate (a NaN anywhere in a spectrum gives NaN XYZ).

    >>> import numpy as np
    >>> w = spectral_weights(np.arange(360.0, 831.0, 5.0))
    >>> [round(float(v), 4) for v in spectrum_to_XYZ(np.full(95, 0.5), w)]  # a 50 % grey under D65
    [0.4752, 0.5, 0.5445]
    """
    r = jnp.asarray(reflectance)
    r = r.astype(float_dtype(r))
    n = np.shape(weights.weights)[0]
    if r.ndim == 0 or r.shape[-1] != n:
        raise ValueError(f"reflectance must have {n} wavelengths on its last axis, got shape {r.shape}")
    return r @ jnp.asarray(weights.weights).astype(r.dtype)

