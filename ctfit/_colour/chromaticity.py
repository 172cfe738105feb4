"""Chromaticity: CIE xy (JAX), and dominant wavelength and excitation purity (CIE 15:2004 §9.1;
NumPy, for reports) against the spectral locus of colour-science's colour-matching functions."""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._model import float_dtype, safe_div
from .tristimulus import DEFAULT_OBSERVER, observer_cmfs

__all__ = ["XYZ_to_xy", "dominant_wavelength", "excitation_purity"]


def XYZ_to_xy(XYZ: Float[ArrayLike, "*batch 3"], xy_n: Float[ArrayLike, " 2"] | None = None) -> Float[Array, "*batch 2"]:
    """CIE xy chromaticity (…, 2). Where X + Y + Z = 0 (black) it is ``xy_n`` if given, else (0, 0).

    >>> import numpy as np
    >>> [round(float(v), 4) for v in XYZ_to_xy(np.array([0.9505, 1.0, 1.089]))]  # D65's white point
    [0.3127, 0.329]
    """
    x = jnp.asarray(XYZ)
    x = x.astype(float_dtype(x))
    s = jnp.sum(x, axis=-1, keepdims=True)
    xy, ok = safe_div(x[..., :2], s)
    if xy_n is not None:
        xy = jnp.where(ok, xy, jnp.asarray(xy_n).astype(x.dtype))
    return xy



@functools.cache
def _locus(observer: str) -> tuple[np.ndarray, np.ndarray]:
    cmfs = observer_cmfs(observer)
    v = np.asarray(cmfs.values, dtype=float)
    return v[:, :2] / v.sum(1, keepdims=True), np.asarray(cmfs.wavelengths, dtype=float)


def _first_hit(origin: np.ndarray, direction: np.ndarray, observer: str, *, purple: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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


def _dominant(xy: ArrayLike, xy_n: ArrayLike, observer: str) -> tuple[np.ndarray, np.ndarray]:
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


def dominant_wavelength(
    xy: Float[ArrayLike, "*batch 2"], xy_n: Float[ArrayLike, " 2"], observer: str = DEFAULT_OBSERVER
) -> Float[np.ndarray, "*batch"]:
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


def excitation_purity(
    xy: Float[ArrayLike, "*batch 2"], xy_n: Float[ArrayLike, " 2"], observer: str = DEFAULT_OBSERVER
) -> Float[np.ndarray, "*batch"]:
    """Excitation purity |xy − xy_n| / |xy_b − xy_n|, xy_b the locus or purple-line point. NumPy.

    0 for achromatic colours; greater than 1 outside the spectral locus; NaN for non-finite input.

    >>> import numpy as np
    >>> d65 = np.array([0.3127, 0.3290])
    >>> [round(float(v), 3) for v in excitation_purity(np.array([[0.5, 0.4], [0.3127, 0.3290]]), d65)]
    [0.722, 0.0]
    """
    return _dominant(xy, xy_n, observer)[1]
