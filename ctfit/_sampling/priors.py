"""Priors of the sampled parameters, stated per parameter in one place: proper and physical.

A prior is a density in the parameter's *value* θ (s, m, F0, ...), always cut to the value's
physical range, :func:`support` (the table of :mod:`ctfit._model.parameters`):

============  ==========================================  =====================================
parameter     default prior                               support
============  ==========================================  =====================================
s             uniform                                     [0, 1]
m (a lobe)    uniform                                     [M_MIN, M_MAX] = [1e-5, 4]
weight        uniform on the simplex (Dirichlet(1))       w_j ≥ 0, Σ w_j = 1
F0            uniform                                     [0, 1]
n             uniform                                     [n_min, 1000] (n_min 1; 0 conductor)
k             uniform                                     [0, 1000]
Rd            uniform                                     [0, 1000] sr⁻¹
sigma_noise   log-uniform (∝ 1/σ)                         [1e-9, 1e9] (units of the residual)
============  ==========================================  =====================================

Every default is proper: the posterior is a distribution even where the data say nothing (then
the prior is what comes back, and :mod:`ctfit._sampling.checks` says so). Other priors, per
parameter: ``("flat",)`` (uniform on the support), ``("uniform", lo, hi)``, ``("normal", mu,
sd)``, ``("lognormal", mu, sd)`` (log θ ~ N(mu, sd)), ``("log-uniform",)`` or ``("log-uniform",
lo, hi)`` (∝ 1/θ); each applies to every entry (lobe, band) of the parameter, the numbers
scalars or one per entry, and is cut to the support.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._model import PARAMETERS, PUBLIC_NAMES, value_range

__all__ = ["PRIOR_KINDS", "SIGMA_NOISE_RANGE", "support", "public_name", "normalise_priors", "log_prior", "describe_priors", "prior_bounds"]

PRIOR_KINDS = ("flat", "uniform", "normal", "lognormal", "log-uniform")
SIGMA_NOISE_RANGE = (1e-9, 1e9)
"""Support of the noise scale σ_noise (relative, or in the residual's unit): wide enough for
any data, narrow enough to make 1/σ a proper prior."""

_ARITY = {"flat": (0,), "uniform": (2,), "normal": (2,), "lognormal": (2,), "log-uniform": (0, 2)}
_ALIASES = {**PUBLIC_NAMES, "weights": "weight", "R_d": "Rd", "sigma": "sigma_noise"}  # a prior's key → public name


def public_name(name: str) -> str:
    """The JSON/table name of a sampled parameter ("w" → "weight", "sigma_noise" as it is)."""
    return PUBLIC_NAMES.get(name, name)


def support(name: str, fresnel: str = "f0") -> tuple[float, float]:
    """The physical range of a sampled parameter's value (sampled name: "s", "m", "f0", ..., "sigma_noise")."""
    return SIGMA_NOISE_RANGE if name == "sigma_noise" else value_range(name, fresnel)


def _default(name: str) -> tuple[str, tuple]:
    return ("log-uniform", SIGMA_NOISE_RANGE) if name == "sigma_noise" else ("flat", ())


def _checked(key: str, spec) -> tuple[str, tuple]:
    """(kind, args) of one user prior, args floats or tuples of floats; ValueError when malformed."""
    if isinstance(spec, str):
        spec = (spec,)
    if not isinstance(spec, (tuple, list)) or not spec or spec[0] not in PRIOR_KINDS:
        raise ValueError(f"priors[{key!r}]: expected (kind, *args) with kind one of {PRIOR_KINDS}, got {spec!r}")
    kind, args = spec[0], tuple(spec[1:])
    if len(args) not in _ARITY[kind]:
        raise ValueError(f"priors[{key!r}]: {kind!r} takes {' or '.join(map(str, _ARITY[kind]))} numbers, got {len(args)}")
    conv = []
    for a in args:
        v = np.asarray(a, dtype=float)
        if not np.all(np.isfinite(v)):
            raise ValueError(f"priors[{key!r}]: arguments must be finite, got {a!r}")
        conv.append(float(v) if v.ndim == 0 else tuple(float(x) for x in v.reshape(-1)))
    if kind in ("normal", "lognormal") and np.any(np.asarray(conv[1]) <= 0):
        raise ValueError(f"priors[{key!r}]: the standard deviation must be > 0")
    if kind in ("uniform", "log-uniform") and args and np.any(np.asarray(conv[0]) >= np.asarray(conv[1])):
        raise ValueError(f"priors[{key!r}]: lo must be < hi")
    return kind, tuple(conv)


def normalise_priors(priors: dict | None, names: tuple[str, ...], noise: bool) -> tuple:
    """The static prior spec ((sampled name, kind, args), ...): the defaults, with the user's
    ``priors`` ({public or sampled name: (kind, *args)}) in their place."""
    sampled = {public_name(n): n for n in names}
    if noise:
        sampled["sigma_noise"] = "sigma_noise"
    given = {}
    for key, spec in dict(priors or {}).items():
        pub = _ALIASES.get(key, key)
        if pub not in sampled:
            raise ValueError(f"priors: {key!r} is not a sampled parameter here; sampled: {sorted(sampled)}")
        given[sampled[pub]] = _checked(key, spec)
    return tuple((name, *given.get(name, _default(name))) for name in sampled.values())


def log_prior(kind: str, args: tuple, theta, lo: float, hi: float):
    """log π(θ) (up to a constant) summed over the entries of θ; −∞ outside [lo, hi] (the support)."""
    a = [jnp.asarray(v, theta.dtype) for v in args]
    inside = (theta >= lo) & (theta <= hi)
    if kind in ("uniform", "log-uniform") and a:
        inside = inside & (theta >= a[0]) & (theta <= a[1])
    if kind in ("flat", "uniform"):
        dens = jnp.zeros_like(theta)
    elif kind == "normal":
        dens = -0.5 * ((theta - a[0]) / a[1]) ** 2 - jnp.log(a[1])
    elif kind == "lognormal":
        lt = jnp.log(theta)
        dens = -lt - 0.5 * ((lt - a[0]) / a[1]) ** 2 - jnp.log(a[1])
    else:  # log-uniform
        dens = -jnp.log(theta)
    return jnp.sum(jnp.where(inside, dens, -jnp.inf))


def prior_bounds(name: str, kind: str, args: tuple, fresnel: str = "f0") -> tuple[np.ndarray, np.ndarray]:
    """The bounds the prior puts on the value: the support, narrowed by a uniform or log-uniform
    prior's (lo, hi) (arrays, broadcast over the entries)."""
    lo, hi = support(name, fresnel)
    if kind in ("uniform", "log-uniform") and args:
        return np.maximum(lo, np.asarray(args[0], dtype=float)), np.minimum(hi, np.asarray(args[1], dtype=float))
    return np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)


def _density_text(pub: str, kind: str, rng: str, narrowed: bool) -> str:
    if pub == "weight" and kind == "flat":
        return "uniform on the simplex (Dirichlet(1))"
    cut = f"[lo, hi] ∩ {rng}" if narrowed else rng
    return {
        "flat": f"uniform in {pub} on {rng}",
        "uniform": f"uniform in {pub} on {cut}",
        "normal": f"{pub} ~ N(mu, sd²), cut to {rng}",
        "lognormal": f"log {pub} ~ N(mu, sd²), cut to {rng}",
        "log-uniform": f"∝ 1/{pub} on {cut}",
    }[kind]


def describe_priors(prior: tuple, fixed: tuple[str, ...], fresnel: str, order_lobes: bool) -> dict:
    """The ``priors`` section of the JSON: per parameter its kind, numbers, support, density and
    the log-Jacobian of the sampled coordinate."""
    params = {}
    for name, kind, args in prior:
        pub = public_name(name)
        lo, hi = support(name, fresnel)
        rng = "simplex (w_j ≥ 0, Σ w_j = 1)" if name == "w" else f"[{lo:g}, {hi:g}]"
        narrowed = kind in ("uniform", "log-uniform") and bool(args) and tuple(args) != (lo, hi)
        entry = {"kind": kind, "range": rng, "density": _density_text(pub, kind, rng, narrowed), "proper": True}
        if kind in ("uniform", "log-uniform") and args:
            entry.update(lo=args[0], hi=args[1])
        elif kind in ("normal", "lognormal"):
            entry.update(mu=args[0], sd=args[1])
        entry["per_element"] = pub not in ("s", "sigma_noise")
        entry["jacobian"] = PARAMETERS[name].transform if name in PARAMETERS else "σ_noise = exp(v): log|dσ/dv| = v"
        params[pub] = entry
    return {
        "space": "constrained parameters; sampling in the unconstrained u of ctfit._model.parameters with log|∂θ/∂u| added",
        "parameters": params,
        "fixed": [public_name(f) for f in fixed],
        "ordering": "lobes ascending in m: draws with m not strictly ascending have probability 0 (no label switching)" if order_lobes else None,
    }
