"""The one table of fitted parameters: names, bounds, and the two ways to vary them.

Every free parameter of a fit is a row of :data:`PARAMETERS`. The fit and the sampler vary
different coordinates of the same physical quantity:

- **box** coordinates (the fit): the value itself, or log m for the rms slopes, inside closed
  bounds ``[lower, upper]`` that the solver respects (projected Levenberg–Marquardt,
  :mod:`ctfit._fitting.solvers`). A parameter may *sit on* its bound — s = 1 (no diffuse part),
  F0 = 1, a lobe's weight 0 — and the solver stops there in a few steps instead of crawling
  along a saturating transform.
- **unconstrained** coordinates (the sampler): smooth bijections of ℝ onto the open range
  (exp, sigmoid, softmax, softplus), so that a random walk never leaves the domain.

Lobe weights w (Σ w = 1, paper eq. 5) have J − 1 free values in both: box coordinates are
stick-breaking fractions v ∈ [0, 1] (w_0 = 1 − v_1, w_1 = v_1 (1 − v_2), …; any lobe's weight
reaches 0 on a bound); unconstrained ones are logits, w = softmax(0, u).

Each row also says what the sampler needs of it: the physical range of the value (the support
of its prior, :mod:`ctfit._sampling.priors`), the log-Jacobian log |dθ/du| of the unconstrained map (so
that a prior stated in θ is a density in u), and a line describing both.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from .numerics import array_module

__all__ = ["Parameter", "PARAMETERS", "PUBLIC_NAMES", "PARAMETER_AXES", "M_MIN", "M_MAX", "PLASTIC_INDEX_RANGE", "parameter", "box_bounds", "clip_box",
           "value_range", "value_domain"]


M_MIN, M_MAX = 1e-5, 4.0
"""Range of an rms slope m in a fit (the model is finite down to m → 0; beyond m ≈ 1 the
surface is a near-Lambertian scatterer and the facet model loses its meaning)."""
INDEX_MAX = 1e3
"""Largest n or k in a fit (metals in the visible: n, k ≲ 10)."""
PLASTIC_INDEX_RANGE = (1.2, 2.5)
"""Range of a plastic's one real index n in a fit and its prior: the dielectrics of paints, plastics,
papers, lacquers and rubbers (n ≈ 1.3–1.7), with room for mineral and high-index coatings."""
RD_MAX = 1e3
"""Largest diffuse BRDF R_d in sr⁻¹ (an albedo of 1 is R_d = 1/π)."""


def _ident(x):
    return x


def _exp(x):
    """exp in the array module of ``x``: NumPy for host values, JAX otherwise (:func:`array_module`)."""
    return array_module(x).exp(x)


def _log_sigmoid(x):
    return -jax.nn.softplus(-x)


def _logit_jacobian(u):
    """θ = sigmoid(u): log |dθ/du| = log σ(u) + log σ(−u), summed."""
    return jnp.sum(_log_sigmoid(u) + _log_sigmoid(-u))


def _softplus_jacobian(u):
    """θ = softplus(u): log |dθ/du| = log σ(u), summed."""
    return jnp.sum(_log_sigmoid(u))


def _exp_jacobian(u):
    """θ = exp(u): log |dθ/du| = u, summed."""
    return jnp.sum(u)


def _softmax_jacobian(u):
    """w = softmax(0, u): log |det ∂(w_2..w_J)/∂u| = Σ_j log w_j (all J weights)."""
    return jnp.sum(jax.nn.log_softmax(jnp.concatenate([jnp.zeros((1,), u.dtype), u])))


def _np_logit(p):
    p = np.clip(np.asarray(p, dtype=float), 1e-12, 1 - 1e-12)
    return np.log(p) - np.log1p(-p)


def _np_softplus_inv(x):
    x = np.asarray(x, dtype=float)
    return np.where(x > 30, x, np.log(np.expm1(np.maximum(x, 1e-300))))


@dataclasses.dataclass(frozen=True)
class Parameter:
    """One fitted quantity.

    ``name`` is the :class:`~ctfit.Params` field, ``public`` its name in JSON and tables,
    ``lower``/``upper`` the bounds of its *box* coordinate, ``box``/``box_inverse`` map box
    coordinates to values and back (jnp / NumPy), ``free``/``free_inverse`` the same for the
    sampler's unconstrained coordinates (for n, added to :func:`n_lower`: n ≥ 1 for a real index),
    ``log_jacobian`` the sum of log |dθ/du| over a parameter's entries, ``transform`` says both in
    words, ``log_scale``: its prior and its checks read it in log θ (a scale, like m); ``axis``:
    one value per ``"lobe"`` or per ``"band"`` (R_d when it is a spectrum), or None: one value.
    """

    name: str
    public: str
    description: str
    lower: float
    upper: float
    box: Callable = _ident
    box_inverse: Callable = _ident
    free: Callable = _ident
    free_inverse: Callable = _ident
    log_jacobian: Callable = _softplus_jacobian
    transform: str = ""
    log_scale: bool = False
    axis: str | None = None


PARAMETERS: dict[str, Parameter] = {
    p.name: p
    for p in (
        Parameter("s", "s", "specular fraction, d = 1 − s (paper eq. 1)", 0.0, 1.0,
                  free=jax.nn.sigmoid, free_inverse=_np_logit, log_jacobian=_logit_jacobian,
                  transform="s = sigmoid(u): log|ds/du| = log σ(u) + log σ(−u)"),
        Parameter("m", "m", "rms facet slope of each lobe (paper eqs. 3–4)", float(np.log(M_MIN)), float(np.log(M_MAX)),
                  box=_exp, box_inverse=np.log, free=jnp.exp, free_inverse=np.log, log_jacobian=_exp_jacobian,
                  transform="m = exp(u): log|dm/du| = u", log_scale=True, axis="lobe"),
        Parameter("w", "weight", "lobe weights, Σ w = 1 (paper eq. 5)", 0.0, 1.0, log_jacobian=_softmax_jacobian,
                  transform="w = softmax(0, u): log|det ∂(w_2..w_J)/∂u| = Σ_j log w_j", axis="lobe"),
        Parameter("f0", "F0", "normal reflectance per band (paper eq. 9, k = 0)", 0.0, 1.0,
                  free=jax.nn.sigmoid, free_inverse=_np_logit, log_jacobian=_logit_jacobian,
                  transform="F0 = sigmoid(u): log|dF0/du| = log σ(u) + log σ(−u)", axis="band"),
        Parameter("n", "n", "refractive index per band", 0.0, INDEX_MAX,
                  free=jax.nn.softplus, free_inverse=_np_softplus_inv, transform="n = n_min + softplus(u): log|dn/du| = log σ(u)", axis="band"),
        Parameter("k", "k", "extinction coefficient per band", 0.0, INDEX_MAX,
                  free=jax.nn.softplus, free_inverse=_np_softplus_inv, transform="k = softplus(u): log|dk/du| = log σ(u)", axis="band"),
        Parameter("rd", "Rd", "diffuse BRDF in sr⁻¹ (per band or one constant)", 0.0, RD_MAX,
                  free=jax.nn.softplus, free_inverse=_np_softplus_inv, transform="R_d = softplus(u): log|dR_d/du| = log σ(u)", axis="band"),
    )
}
PUBLIC_NAMES = {name: p.public for name, p in PARAMETERS.items()}
""":class:`~ctfit.Params` field name → the name in material and fit-result files, standard
errors, the posterior summary and parameter maps (``w`` → ``weight``, ``f0`` → ``F0``, ``rd`` → ``Rd``)."""
PARAMETER_AXES = {p.public: p.axis for p in PARAMETERS.values()}
"""Public name → ``"lobe"``, ``"band"`` or None (see :class:`Parameter`)."""


def parameter(name: str) -> Parameter:
    """The row of :data:`PARAMETERS` for a :class:`~ctfit.Params` field name."""
    return PARAMETERS[name]


def value_domain(name: str, fresnel: str = "f0") -> tuple[float, float, bool]:
    """(lower, upper, whether the lower bound is open) of a parameter's value as a material file and
    a fit's start or fixed value take it: s, w, F0 in [0, 1]; m > 0; n > 0, a conductor's n ≥ 0
    (a fit on its bound, F0 = 1); k, R_d ≥ 0. Wider than :func:`value_range` (what a fit or the
    sampler reaches): a material may hold any value that evaluates."""
    if name in ("s", "w", "f0"):
        return 0.0, 1.0, False
    return 0.0, math.inf, name == "m" or (name == "n" and fresnel != "conductor")


def n_lower(fresnel: str, family: str = "metal") -> float:
    """Lower bound of n: 1 for a real (dielectric) index, 0 for a conductor's n + ik, and the
    lower end of :data:`PLASTIC_INDEX_RANGE` for a plastic."""
    if family == "plastic" or fresnel == "plastic":
        return PLASTIC_INDEX_RANGE[0]
    return 0.0 if fresnel == "conductor" else 1.0


def box_bounds(name: str, fresnel: str = "f0", family: str = "metal") -> tuple[float, float]:
    """Bounds of the box coordinate of parameter ``name`` (``family``: "metal" or "plastic";
    ``fresnel="plastic"`` is short for a plastic's real index, as the sampler's layout names it)."""
    p = PARAMETERS[name]
    if fresnel == "plastic":
        fresnel, family = "n", "plastic"
    if name == "n":
        return (n_lower(fresnel, family), PLASTIC_INDEX_RANGE[1] if family == "plastic" else p.upper)
    return p.lower, p.upper


def value_range(name: str, fresnel: str = "f0", family: str = "metal") -> tuple[float, float]:
    """The physical range of a parameter's *value* (not its box coordinate): m in [M_MIN, M_MAX],
    n from :func:`n_lower` (a plastic's inside :data:`PLASTIC_INDEX_RANGE`), the others their box
    bounds. The support of the sampler's priors."""
    return (M_MIN, M_MAX) if name == "m" else box_bounds(name, fresnel, family)


def clip_box(x, lower, upper):
    """``x`` held inside [lower, upper], with derivative 1 *on* a bound (``jnp.clip`` splits the
    derivative of a tie in two, which would halve the gradient of a parameter sitting there);
    NumPy in, NumPy out (:func:`array_module`)."""
    xp = array_module(x)
    return xp.where(x < lower, lower, xp.where(x > upper, upper, x))
