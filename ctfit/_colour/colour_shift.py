"""The colour shift of a reflection with angle: the paper's approximation and the exact spectra.

Cook & Torrance (1982, §4, Figure 5): the Fresnel term depends on wavelength and angle, so a
metal's highlight changes colour towards the light's colour as incidence becomes grazing. The
exact colour integrates the reflectance spectrum F(θ, λ) at every angle. The paper's cheaper
approximation computes two colours only — at normal incidence, from F0(λ), and at grazing
incidence, where F = 1 and the reflection has the light's colour — and interpolates:

    colour(θ) = colour_0 + (colour_light − colour_0) · max(0, F_avg(θ) − F_avg(0)) / (F_avg(π/2) − F_avg(0)),

F_avg the unpolarised dielectric Fresnel reflectance with the index of the average normal
reflectance, n_avg = (1 + √F0_avg)/(1 − √F0_avg) (so F_avg(0) = F0_avg, F_avg(π/2) = 1).
The interpolation is linear, so it may be done in XYZ or in linear RGB alike (not in encoded
RGB). :func:`average_normal_reflectance` gives F0_avg; its luminance-weighted form (the Y of
the F0 spectrum) makes the approximation's luminance exactly max(F_avg(θ), F0_avg). (For a
high index the unpolarised F_avg first dips below F0 — the p-polarised Brewster minimum — so
the max(0, ·) keeps the normal-incidence colour up to the angle where F_avg recovers F0.)

The exact versions, :func:`fresnel_reflectance_spectrum` + :func:`ctfit.spectrum_to_XYZ`, use
either the effective index per wavelength from F0(λ) (the paper's k = 0 model) or the
conductor Fresnel with tabulated n(λ), k(λ).

References
----------
- Cook, R. L. and Torrance, K. E. (1982). A Reflectance Model for Computer Graphics.
  ACM Transactions on Graphics 1(1), 7–24, §4 and appendix. doi:10.1145/357290.357293
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._model import fresnel_conductor, fresnel_dielectric, fresnel_dielectric_f0
from .tristimulus import SpectralWeights, spectrum_to_XYZ

__all__ = [
    "average_normal_reflectance",
    "colour_shift_weight",
    "colour_shift_approximation",
    "fresnel_reflectance_spectrum",
    "colour_shift_spectral",
]


def average_normal_reflectance(f0: Float[ArrayLike, "*batch bands"], weights: SpectralWeights | None = None) -> Float[Array, "*batch"]:
    """F0_avg of a normal-reflectance spectrum (…, λ).

    With ``weights``: the luminance-weighted mean, i.e. Y of the F0 spectrum (Y(white) = 1).
    Without: the plain mean over the listed wavelengths.

    >>> import numpy as np
    >>> from ctfit import spectral_weights
    >>> wl = np.arange(400.0, 701.0, 10.0)
    >>> f0 = np.where(wl > 580, 0.9, 0.4)  # a copper-like step
    >>> round(float(average_normal_reflectance(f0)), 3), round(float(average_normal_reflectance(f0, spectral_weights(wl))), 3)
    (0.594, 0.522)
    """
    f0 = jnp.asarray(f0)
    if weights is None:
        return jnp.mean(f0, axis=-1)
    return spectrum_to_XYZ(f0, weights)[..., 1]


def colour_shift_weight(cos_theta: Float[ArrayLike, "*#batch"], f0_mean: Float[ArrayLike, "*#batch"]) -> Float[Array, "*batch"]:
    """max(0, F_avg(θ) − F0_avg)/(1 − F0_avg): 0 at normal incidence, 1 at grazing.

    F_avg is :func:`ctfit.fresnel_dielectric_f0` — the paper's dielectric F with
    n = (1 + √F0_avg)/(1 − √F0_avg) — finite for F0_avg in [0, 1]; the weight is 0 when
    F0_avg = 1 (then both end colours agree) and when F0_avg = 0 (F ≡ 0).

    >>> import numpy as np
    >>> w = colour_shift_weight(np.array([1.0, 0.5, 0.1, 0.0]), 0.04)  # glass at 0°, 60°, 84°, 90°
    >>> [round(float(v), 3) for v in w]
    [0.0, 0.051, 0.554, 1.0]
    """
    c = jnp.asarray(cos_theta)
    f0 = jnp.asarray(f0_mean)
    f = fresnel_dielectric_f0(c, f0)
    den = 1 - f0
    ok = den > 0
    return jnp.where(ok, jnp.maximum(f - f0, 0) / jnp.where(ok, den, 1), 0)


def colour_shift_approximation(
    rgb_normal: Float[ArrayLike, "*#batch 3"], rgb_light: Float[ArrayLike, "*#batch 3"], f0_mean: Float[ArrayLike, "*#batch"],
    cos_theta: Float[ArrayLike, "*#batch"],
) -> Float[Array, "*batch 3"]:
    """The paper's colour at cos θ (…, 3) between the normal-incidence and the light's colour.

    ``rgb_normal`` and ``rgb_light`` (…, 3) are linear (RGB or XYZ); ``f0_mean`` and
    ``cos_theta`` broadcast against their leading axes. ``rgb_light`` is the colour of a
    perfect reflector under the light: (1, 1, 1) in linear RGB after chromatic adaptation, or
    the illuminant's white XYZ.

    >>> import numpy as np
    >>> rgb = colour_shift_approximation(np.array([0.9, 0.6, 0.5]), np.ones(3), 0.04, np.array([1.0, 0.1, 0.0]))
    >>> np.round(np.asarray(rgb, dtype=float), 3).tolist()  # towards the light's white at grazing
    [[0.9, 0.6, 0.5], [0.955, 0.821, 0.777], [1.0, 1.0, 1.0]]
    """
    w = colour_shift_weight(cos_theta, f0_mean)[..., None]
    a = jnp.asarray(rgb_normal)
    return a + w * (jnp.asarray(rgb_light) - a)


def fresnel_reflectance_spectrum(
    cos_theta: Float[ArrayLike, "*#batch"], *, f0: Float[ArrayLike, "*#batch bands"] | None = None,
    n: Float[ArrayLike, "*#batch bands"] | None = None, k: Float[ArrayLike, "*#batch bands"] | None = None,
) -> Float[Array, "*batch bands"]:
    """F(θ, λ), shape ``cos_theta.shape + (λ,)``, from one kind of spectral Fresnel data (λ,).

    - ``f0``: the paper's effective index per wavelength (k = 0), :func:`ctfit.fresnel_dielectric_f0`;
    - ``n``: a real index, :func:`ctfit.fresnel_dielectric`;
    - ``n`` and ``k``: the conductor Fresnel, :func:`ctfit.fresnel_conductor`.

    >>> import numpy as np
    >>> F = fresnel_reflectance_spectrum(np.array([1.0, 0.0]), f0=np.array([0.04, 0.9]))
    >>> np.round(np.asarray(F, dtype=float), 4).tolist()  # F0 at normal incidence, 1 at grazing
    [[0.04, 0.9], [1.0, 1.0]]
    """
    c = jnp.asarray(cos_theta)[..., None]
    if f0 is not None:
        if n is not None or k is not None:
            raise ValueError("give either f0, or n (and k), not both")
        return fresnel_dielectric_f0(c, jnp.asarray(f0))
    if n is None:
        raise ValueError("give f0, n, or n and k")
    if k is None:
        return fresnel_dielectric(c, jnp.asarray(n))
    return fresnel_conductor(c, jnp.asarray(n), jnp.asarray(k))


def colour_shift_spectral(
    cos_theta: Float[ArrayLike, "*#batch"], weights: SpectralWeights, *, f0: Float[ArrayLike, "*#batch bands"] | None = None,
    n: Float[ArrayLike, "*#batch bands"] | None = None, k: Float[ArrayLike, "*#batch bands"] | None = None,
) -> Float[Array, "*batch 3"]:
    """Exact XYZ (…, 3) of the reflection at cos θ: F(θ, λ) on ``weights.wavelength_nm`` integrated.

    >>> import numpy as np
    >>> from ctfit import spectral_weights
    >>> wl = np.arange(400.0, 701.0, 10.0)
    >>> w = spectral_weights(wl)
    >>> XYZ = colour_shift_spectral(np.array([1.0, 0.0]), w, f0=np.where(wl > 580, 0.9, 0.4))
    >>> round(float(XYZ[0, 1]), 3), bool(np.allclose(XYZ[1], w.white_XYZ, rtol=1e-5))  # Y(0°) = F0_avg; white at 90°
    (0.522, True)
    """
    return spectrum_to_XYZ(fresnel_reflectance_spectrum(cos_theta, f0=f0, n=n, k=k), weights)
