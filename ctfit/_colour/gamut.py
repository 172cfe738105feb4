"""The paper's gamut mapping: desaturate towards white at constant luminance and dominant wavelength.

Cook & Torrance (1982, §4 and appendix) reproduce colours that fall outside the monitor's
gamut by moving them towards the white point at constant dominant wavelength, and scale the
scene so that the brightest colour is shown at the maximum luminance its chromaticity allows.

In linear RGB, with the channel luminances ``L`` (summing to 1, so white of luminance Y is
(Y, Y, Y)), a colour c of luminance Y = L·c is replaced by

    c' = (1 − t) (Y, Y, Y) + t c,

the additive mixture of c with the white of equal luminance. In chromaticity the mixture lies
on the segment from the white point to c, so the dominant wavelength (seen from that white)
is unchanged, and so is Y. ``t`` is the largest value in [0, 1] with every channel of c' in
[0, upper]: per channel, t ≤ Y/(Y − c_i) where c_i < 0 and t ≤ (upper − Y)/(c_i − Y) where
c_i > upper. A colour with Y ≤ 0 has no in-gamut colour of its luminance and becomes black;
one with Y ≥ upper becomes white of luminance ``upper``. In-gamut colours are untouched.

Every division is guarded twice (``where`` on the value and on the denominator) so values and
gradients stay finite for black, for white and for colours on the gamut boundary. Non-finite
input raises nothing: that pixel comes out with NaN channels (a NaN channel stays NaN), and no
other pixel is affected.
"""

from __future__ import annotations

import functools
from typing import Any

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float

from .._model import float_dtype

__all__ = ["desaturate_to_gamut", "in_gamut", "scale_to_display", "srgb_luminance"]


@functools.cache
def srgb_luminance() -> Float[np.ndarray, " 3"]:
    """Luminance of sRGB's linear channels (Y row of its RGB → XYZ matrix, summing to 1).

    >>> [round(float(v), 4) for v in srgb_luminance()]
    [0.2126, 0.7152, 0.0722]
    """
    from .tristimulus import colour_science

    m_inv = np.linalg.inv(np.asarray(colour_science().RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB, dtype=float))
    return m_inv[1] / m_inv[1].sum()


def _float(x: ArrayLike) -> Array:
    x = jnp.asarray(x)
    return x.astype(float_dtype(x))


def _ratio(num: Any, den: Any, use: Any, xp: Any = jnp) -> Any:
    """num/den where ``use``, else 1 (no constraint); both branches finite."""
    ok = use & (den > 0)
    r = num / xp.where(ok, den, 1)
    return xp.where(ok, r, xp.where(use, 0, 1))


def desaturate_to_gamut(
    rgb: Float[ArrayLike, "*batch 3"], luminance: Float[ArrayLike, " 3"] | None = None, *, upper: float | None = 1.0, xp: Any = jnp
) -> Float[Array, "*batch 3"]:
    """Map linear RGB (…, 3) into [0, upper]³ by mixing with the white of equal luminance.

    ``luminance``: the (3,) channel luminances, summing to 1 (default: sRGB's); pass
    :attr:`RGBConversion.luminance` for other colourspaces. ``upper=None`` maps only negative
    channels (no upper bound). See the module docstring for the formula. ``xp``: ``jax.numpy``
    (traceable, differentiable) or ``numpy`` (on the host in float64, nothing compiled).

    Examples
    --------
    >>> import numpy as np
    >>> rgb = np.array([0.5, 0.2, -0.1])  # beyond sRGB's gamut: a negative blue
    >>> c = desaturate_to_gamut(rgb)
    >>> [round(float(v), 4) for v in c], round(float(c @ srgb_luminance()), 4) == round(float(rgb @ srgb_luminance()), 4)
    ([0.4246, 0.2123, 0.0], True)
    >>> desaturate_to_gamut(rgb, xp=np).round(4).tolist()
    [0.4246, 0.2123, 0.0]
    """
    c = _float(rgb) if xp is jnp else np.asarray(rgb, dtype=float)
    lum = xp.asarray(srgb_luminance() if luminance is None else luminance).astype(c.dtype)
    y = xp.sum(c * lum, axis=-1, keepdims=True)
    lo = c < 0
    t = xp.min(_ratio(y, y - c, lo, xp), axis=-1, keepdims=True)
    if upper is not None:
        hi = c > upper
        t = xp.minimum(t, xp.min(_ratio(upper - y, c - y, hi, xp), axis=-1, keepdims=True))
        y_c = xp.clip(y, 0, upper)
    else:
        y_c = xp.maximum(y, 0)
    t = xp.clip(t, 0, 1)
    out = xp.where(t < 1, y_c + t * (c - y_c), c)  # in-gamut colours bit for bit
    # Only rounding can leave a mapped colour outside the box; untouched colours are inside.
    return xp.clip(out, 0, upper) if upper is not None else xp.maximum(out, 0)


def in_gamut(rgb: Float[ArrayLike, "*batch 3"], *, upper: float | None = 1.0, atol: float = 0.0) -> Bool[Array, "*batch"]:
    """Whether every channel of each colour (…, 3) is in [−atol, upper + atol] (False for NaN).

    >>> import numpy as np
    >>> in_gamut(np.array([[0.5, 0.2, 0.1], [1.2, 0.5, 0.1], [0.5, -0.01, 0.2]])).tolist()
    [True, False, False]
    """
    c = jnp.asarray(rgb)
    ok = c >= -atol
    if upper is not None:
        ok = ok & (c <= upper + atol)
    return jnp.all(ok, axis=-1)


def scale_to_display(
    rgb: Float[ArrayLike, "*batch 3"], luminance: Float[ArrayLike, " 3"] | None = None
) -> tuple[Float[Array, "*batch 3"], Float[Array, ""]]:
    """Scale a scene for display: ``(rgb_display, scale)``.

    1. Negative channels are mapped into the gamut at constant luminance
       (:func:`desaturate_to_gamut` with no upper bound).
    2. One global factor ``scale`` = 1 / (largest channel over all finite pixels) is applied,
       so the brightest pixel — the one whose largest channel is largest — reaches 1, the
       maximum luminance its chromaticity allows on the display; no other pixel exceeds 1.
       (Desaturation at constant luminance commutes with scaling, so the order is immaterial.)
    3. Rounding is removed by a final :func:`desaturate_to_gamut` with ``upper=1``.

    An all-black (or all non-finite) scene gets ``scale = 1``. Differentiable; the gradient
    of ``scale`` flows through the brightest pixel.

    >>> import numpy as np
    >>> shown, scale = scale_to_display(np.array([[2.0, 1.0, 0.5], [0.5, 0.5, 0.5]]))
    >>> float(scale), np.asarray(shown, dtype=float).tolist()  # the brightest channel at 1
    (0.5, [[1.0, 0.5, 0.25], [0.25, 0.25, 0.25]])
    """
    c = desaturate_to_gamut(rgb, luminance, upper=None)
    finite = jnp.all(jnp.isfinite(c), axis=-1, keepdims=True)
    peak = jnp.max(jnp.where(finite, c, 0))
    ok = peak > 0
    scale = jnp.where(ok, 1 / jnp.where(ok, peak, 1), 1)
    return desaturate_to_gamut(c * scale, luminance, upper=1.0), scale
