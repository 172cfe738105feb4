"""Posterior sampling of the Cook–Torrance parameters with emcee (Foreman-Mackey et al. 2013).

``sample(fit_result_or_material, data, ...)`` → :class:`SampleResult`. The posterior is

    p(θ | y) ∝ L(y | θ) · π(θ),

sampled in the unconstrained coordinates ``u`` of :mod:`ctfit._problem` (the same ones the
least-squares fit moves in), with emcee's affine-invariant ensemble sampler and a jit-compiled,
vmapped JAX log-probability (``vectorize=True``: one call per half-ensemble).

Likelihood (Gaussian, on the fit's residual weighting r_i = :func:`ctfit._problem._loss`, but for
the relative loss):

- loss ``"sigma"`` (the data has a ``sigma`` column): r_i = (R_i − y_i)/σ_i ~ N(0, 1),
  log L = −½ Σ r_i² (+ a constant);
- loss ``"relative"`` (no sigma): noise proportional to the model, y_i = R_i (1 + ε_i),
  ε_i ~ N(0, σ_noise²): r_i = (R_i − y_i)/R_i, log L = −Σ log R_i − N log σ_noise
  − ½ Σ r_i²/σ_noise². The scale is the model R_i(θ), not the data y_i with the fit's floor
  max(y_i, floor): a floor shrinks the residuals below it and makes σ_noise too small, and
  dividing by noisy values biases the residual (posterior intervals far too narrow otherwise);
- ``absolute``, ``cosine``, ``log``: r_i ~ N(0, σ_noise²), log L = −N log σ_noise
  − ½ Σ r_i²/σ_noise².

Without sigma the noise scale σ_noise is a sampled parameter; its prior is flat in log σ_noise
(the Jeffreys prior 1/σ_noise), unless ``priors`` says so.

Priors: flat in the *constrained* parameters over their ranges — m > 0, the lobe weights
uniform on the simplex (Dirichlet(1)), s ∈ [0, 1], F0 ∈ (0, 1), n > 1 (n > 0 for a
conductor), k ≥ 0, R_d ≥ 0. Since the walkers move in u, the log-density of u adds the
log-Jacobian of the transforms of :mod:`ctfit._problem`:

- m = exp(u):                 log |dm/du| = u
- s, F0 = sigmoid(u):         log |dθ/du| = log σ(u) + log σ(−u)
- n − n_min, k, R_d = softplus(u): log |dθ/du| = log σ(u)
- w = softmax(0, u_2..u_J):   log |det ∂(w_2..w_J)/∂u| = Σ_j log w_j (all J weights)

so that the prior is flat in θ, not in u. Other priors per parameter: ``("uniform", lo, hi)``,
``("normal", mu, sd)``, ``("lognormal", mu, sd)`` (log θ ~ N(mu, sd)), ``("log-uniform",)``
or ``("log-uniform", lo, hi)`` (density ∝ 1/θ); each applies to every element (lobe, band) of
the parameter, with ``mu``, ``sd``, ``lo``, ``hi`` scalars or one value per element.

Lobes are kept ordered by m (no label switching): a draw with m not strictly ascending has
probability 0.

Walkers start at the least-squares optimum (polished by a few Levenberg–Marquardt steps on
the normal equations; for the relative loss, by least squares weighted by the model, reweighted
until it settles), spread by the Laplace covariance (JᵀJ)⁻¹ (scaled by the residual variance
unless the loss is sigma-weighted); draws whose log-probability is not finite are drawn again,
closer.

References
----------
- Foreman-Mackey, D., Hogg, D. W., Lang, D., Goodman, J. (2013). emcee: The MCMC Hammer.
  PASP 125(925), 306. doi:10.1086/670067
- Goodman, J., Weare, J. (2010). Ensemble samplers with affine invariance. CAMCoS 5(1), 65–80.
  doi:10.2140/camcos.2010.5.65
- Sokal, A. (1997). Monte Carlo methods in statistical mechanics: foundations and new
  algorithms. In Functional Integration, 131–192 (integrated autocorrelation time, the
  "50 τ" rule emcee follows).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import json
import logging
import math
import pathlib
import time
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from ._brdf import diffuse_reflectance, normal_reflectance
from ._fresnel import n_from_f0
from ._interrupt import deferred, note_resumable
from ._material_io import _jsonable
from ._material import Material, Params, Structure
from ._measurement import Measurement
from ._parameters import PARAMETERS
from ._problem import LOSSES, Problem, from_params, make_problem, model_values, normal_equations, residual, to_params

__all__ = ["sample", "SampleResult", "ChainTooShortWarning", "PRIOR_KINDS", "default_walkers"]

PRIOR_KINDS = ("flat", "uniform", "normal", "lognormal", "log-uniform")

# Sampled name in u → public name (docs/formats.md keys), and the public name's allowed range.
_PUBLIC = {name: row.public for name, row in PARAMETERS.items()}
_ALIASES = {"w": "weight", "weights": "weight", "f0": "F0", "rd": "Rd", "R_d": "Rd", "sigma": "sigma_noise"}
_RANGE_TEXT = {
    "s": "[0, 1]",
    "m": "(0, inf)",
    "weight": "simplex (w_j ≥ 0, Σ w_j = 1)",
    "F0": "(0, 1)",
    "n": "(1, inf)",
    "k": "[0, inf)",
    "Rd": "[0, inf)",
    "sigma_noise": "(0, inf)",
}
_JACOBIAN_TEXT = {
    "s": "s = sigmoid(u): log|ds/du| = log σ(u) + log σ(−u)",
    "m": "m = exp(u): log|dm/du| = u",
    "weight": "w = softmax(0, u): log|det ∂(w_2..w_J)/∂u| = Σ_j log w_j",
    "F0": "F0 = sigmoid(u): log|dF0/du| = log σ(u) + log σ(−u)",
    "n": "n = n_min + softplus(u): log|dn/du| = log σ(u)",
    "k": "k = softplus(u): log|dk/du| = log σ(u)",
    "Rd": "R_d = softplus(u): log|dR_d/du| = log σ(u)",
    "sigma_noise": "σ_noise = exp(v): log|dσ/dv| = v",
}


class ChainTooShortWarning(UserWarning):
    """The chain (after burn-in) is shorter than 50 integrated autocorrelation times."""


def default_walkers(ndim: int) -> int:
    """max(2·ndim + 2, 32), rounded up to an even number (emcee's stretch move splits in halves)."""
    n = max(2 * ndim + 2, 32)
    return n + (n % 2)


# --- the log-probability ------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class _Layout:
    """Static layout of the flat sampling vector: u's entries (ravel_pytree order), then log σ_noise."""

    names: tuple[str, ...]
    shapes: tuple[tuple[int, ...], ...]
    noise: bool
    conductor: bool
    order_lobes: bool
    relative: bool = False  # σ_i = σ_noise · R_i(θ): noise proportional to the model


    @property
    def n_u(self) -> int:
        return int(sum(math.prod(s) for s in self.shapes))

    @property
    def ndim(self) -> int:
        return self.n_u + int(self.noise)

    def unravel(self, x):
        template = {k: jnp.zeros(s, x.dtype) for k, s in zip(self.names, self.shapes)}
        _, unravel = ravel_pytree(template)
        return unravel(x[: self.n_u])

    def labels(self) -> list[str]:
        out = []
        for name, shape in zip(self.names, self.shapes):
            pub = _PUBLIC[name]
            size = math.prod(shape)
            if not shape:
                out.append(pub)
            elif name == "w":  # u_w[i] is log(w_{i+1}/w_0)
                out += [f"{pub}[{i + 1}]" for i in range(size)]
            else:
                out += [f"{pub}[{i}]" for i in range(size)]
        if self.noise:
            out.append("sigma_noise")
        return out


def _log_sigmoid(x):
    return -jax.nn.softplus(-x)


def _log_jacobian(name: str, u, theta):
    """log |dθ/du| summed over the entries of one sampled parameter (see the module docstring)."""
    if name == "m":
        return jnp.sum(u)
    if name in ("s", "f0"):
        return jnp.sum(_log_sigmoid(u) + _log_sigmoid(-u))
    if name == "w":
        return jnp.sum(jax.nn.log_softmax(jnp.concatenate([jnp.zeros((1,), u.dtype), u])))
    return jnp.sum(_log_sigmoid(u))  # n, k, rd: softplus


def _prior_density(kind: str, args, theta):
    """log π(θ) (up to a constant) of one prior, summed over the entries of θ."""
    a = [jnp.asarray(v, theta.dtype) for v in args]
    if kind == "flat":
        return jnp.zeros((), theta.dtype)
    if kind == "uniform":
        lo, hi = a
        return jnp.sum(jnp.where((theta >= lo) & (theta <= hi), 0.0, -jnp.inf))
    if kind == "normal":
        mu, sd = a
        return jnp.sum(-0.5 * ((theta - mu) / sd) ** 2 - jnp.log(sd))
    if kind == "lognormal":
        mu, sd = a
        lt = jnp.log(theta)
        return jnp.sum(-lt - 0.5 * ((lt - mu) / sd) ** 2 - jnp.log(sd))
    # log-uniform
    out = -jnp.log(theta)
    if a:
        lo, hi = a
        out = jnp.where((theta >= lo) & (theta <= hi), out, -jnp.inf)
    return jnp.sum(out)


def _theta(name: str, params: Params):
    """The constrained value of sampled parameter ``name`` (what its prior is a density of)."""
    return {"m": params.m, "w": params.w, "s": params.s, "f0": params.f0, "n": params.n, "k": params.k, "rd": params.rd}[name]


def _log_prob_one(problem: Problem, layout: _Layout, prior: tuple, x):
    """Log-posterior (up to a constant) of one flat sampling vector ``x``."""
    u = layout.unravel(x)
    params = to_params(problem.spec, u, problem.fixed)
    if layout.relative:
        r, log_l = _relative_residual(problem, model_values(problem, u))
    else:
        r, log_l = residual(u, (problem.y, problem)), jnp.zeros((), x.dtype)
    chi2 = jnp.sum(r * r)
    kinds = dict((name, (kind, args)) for name, kind, args in prior)
    if layout.noise:
        log_sn = x[layout.n_u]
        n_obs = jnp.sum(problem.mask)
        log_l = log_l - n_obs * log_sn - 0.5 * chi2 * jnp.exp(-2 * log_sn)
        kind, args = kinds["sigma_noise"]
        sn = jnp.exp(log_sn)
        log_p = _prior_density(kind, args, sn) + log_sn  # density in σ, times |dσ/dv|
    else:
        log_l = -0.5 * chi2
        log_p = jnp.zeros((), x.dtype)
    for name in layout.names:
        theta = _theta(name, params)
        kind, args = kinds[name]
        log_p = log_p + _prior_density(kind, args, theta) + _log_jacobian(name, u[name], theta)
    ok = jnp.isfinite(log_l) & jnp.isfinite(log_p)
    if layout.order_lobes:
        ok = ok & jnp.all(jnp.diff(u["m"]) > 0)  # m = exp(u_m) is monotone in u_m
    total = log_l + log_p
    return jnp.where(ok & jnp.isfinite(total), total, -jnp.inf)


def _relative_scale(problem: Problem, values):
    """max(R_i, tiny) at the observed samples, 1 at missing cells."""
    tiny = jnp.finfo(values.dtype).tiny
    return jnp.where(problem.mask > 0, jnp.maximum(values, tiny), jnp.ones((), values.dtype))


def _relative_residual(problem: Problem, values):
    """Noise proportional to the model, y_i = R_i (1 + ε_i): r_i = (R_i − y_i)/R_i and the
    normalisation −Σ log R_i of the Gaussian with σ_i = σ_noise R_i (the −N log σ_noise part is
    added by the caller). R_i, not y_i: dividing by the noisy value biases the residual, and a
    floor (the fit's max(y_i, floor)) shrinks the residuals below it, which makes one σ_noise
    for all residuals too small (docs/uncertainty.md)."""
    scale = _relative_scale(problem, values)
    r = (values - problem.y) / scale * problem.mask
    return r.reshape(-1), -jnp.sum(jnp.log(scale))


_CACHE: dict = {}
_BAKE_MAX_PAIRS = 200_000  # direction pairs up to which the geometry is compiled in as constants


def _cache_put(key, fn):
    if len(_CACHE) > 64:
        _CACHE.clear()
    _CACHE[key] = fn
    return fn


def _jitted(kind: str, problem: Problem, statics: tuple, builder):
    """A ``jax.jit`` function of (the problem's arrays, ...) cached by the problem's static
    structure and ``statics``: a second problem of the same shape and spec reuses the compiled
    code, and a call costs no pytree filtering (cheaper per call than ``eqx.filter_jit``)."""
    dyn, static = eqx.partition(problem, eqx.is_array)
    leaves, tdef = jax.tree_util.tree_flatten(dyn)
    key = (kind, tdef, jax.tree_util.tree_structure(static), statics)
    fn = _CACHE.get(key)
    if fn is None:

        def rebuild(lv):
            return eqx.combine(jax.tree_util.tree_unflatten(tdef, lv), static)

        fn = _cache_put(key, jax.jit(builder(rebuild)))
    return fn, leaves


def _data_fields(q: Problem):
    return q.y, q.sigma, q.floor


def _geometry_key(problem: Problem) -> str:
    """A fingerprint of everything in the problem but the data values (y, sigma, floor)."""
    stripped = eqx.tree_at(_data_fields, problem, (None, None, None), is_leaf=lambda x: x is None)
    leaves, tdef = jax.tree_util.tree_flatten(stripped)
    h = hashlib.sha1(str(tdef).encode())
    for leaf in leaves:
        a = np.asarray(leaf)
        h.update(str((a.dtype, a.shape)).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _jitted_baked(kind: str, problem: Problem, statics: tuple, builder):
    """Like :func:`_jitted`, with the geometry and layout compiled in as constants and only the
    data values (y, sigma, floor) as arguments. XLA then folds every data-independent term (the
    V-cavity G, powers of tan²α, ...) once at compile time: 2–3× fewer operations per walker.
    Cached by a fingerprint of the geometry, so data sets that share directions (fresh noise on
    the same goniometer) compile once."""
    if problem.geom.cos_vh.shape[0] > _BAKE_MAX_PAIRS:
        return _jitted(kind, problem, statics, builder)
    key = (kind + "/baked", _geometry_key(problem), statics)
    fn = _CACHE.get(key)
    args = [a for a in _data_fields(problem) if a is not None]
    if fn is None:
        has_sigma = problem.sigma is not None
        base = problem

        def rebuild(lv):
            y, sigma, floor = (lv[0], lv[1], lv[2]) if has_sigma else (lv[0], None, lv[1])
            return eqx.tree_at(_data_fields, base, (y, sigma, floor), is_leaf=lambda x: x is None)

        fn = _cache_put(key, jax.jit(builder(rebuild)))
    return fn, args


def _build_log_prob(layout: _Layout, prior: tuple):
    def build(rebuild):
        def f(leaves, xs):
            problem = rebuild(leaves)
            return jax.vmap(lambda x: _log_prob_one(problem, layout, prior, x))(xs)

        return f

    return build


def _build_normal(layout: _Layout, dense: bool):
    """½‖r‖², Jᵀr, JᵀJ at a flat u: from the dense Jacobian (jacfwd through the residual's
    structured JVP) when N·P is small, else from ctfit._problem.normal_equations (no N × P)."""

    def build(rebuild):
        def f(leaves, x):
            problem = rebuild(leaves)
            if dense:
                fun = lambda z: residual(layout.unravel(z), (problem.y, problem))  # noqa: E731
                r = fun(x)
                jac = jax.jacfwd(fun)(x)
                return 0.5 * jnp.sum(r * r), jac.T @ r, jac.T @ jac
            return normal_equations(problem, layout.unravel(x))

        return f

    return build


def _build_constrained(layout: _Layout, jac: bool):
    def build(rebuild):
        def f(leaves, xs):
            problem = rebuild(leaves)
            one = lambda x: _constrained_one(problem, layout, x)  # noqa: E731
            return jax.jacfwd(one)(xs) if jac else jax.vmap(one)(xs)

        return f

    return build


class _Engine:
    """The compiled pieces for one problem: emcee's vectorised log-probability, the normal
    equations for the polish and the Laplace covariance, and the constrained quantities.

    emcee calls ``engine(coords)`` with (k, ndim) NumPy arrays; every call is cut into blocks of
    ``chunk`` walkers (half the ensemble: the size of emcee's stretch-move batches), the last one
    padded, so the log-probability compiles once.
    """

    _BLOCK = 512  # rows per call of the constrained-quantities function

    def __init__(self, problem: Problem, layout: _Layout, prior: tuple, chunk: int):
        self.problem, self.layout, self.prior, self.chunk = problem, layout, prior, int(chunk)
        self.dtype = problem.y.dtype
        self._lp, self.leaves = _jitted_baked("log_prob", problem, (layout, prior), _build_log_prob(layout, prior))
        self._shape = (self.chunk, layout.ndim)
        self.calls = 0

    def __call__(self, coords):
        if type(coords) is np.ndarray and coords.shape == self._shape and coords.dtype == np.float64:
            # emcee's stretch move, every call but the first: nothing but the XLA call (the data
            # arrays stay on the device; emcee's float64 coordinates go in as they are).
            self.calls += self.chunk
            return np.asarray(self._lp(self.leaves, coords))
        coords = np.asarray(coords, dtype=float)
        if coords.ndim == 1:
            coords = coords[None]
        k = coords.shape[0]
        self.calls += k
        out = np.empty(k)
        for start in range(0, k, self.chunk):
            block = coords[start : start + self.chunk]
            n = block.shape[0]
            if n < self.chunk:
                block = np.concatenate([block, np.repeat(block[-1:], self.chunk - n, axis=0)])
            out[start : start + n] = np.asarray(self._lp(self.leaves, block), dtype=float)[:n]
        return out

    def normal(self, x_u, problem: Problem | None = None):
        """½‖r‖², Jᵀr, JᵀJ of ``problem``'s residual (default: the engine's) at a flat u."""
        problem = self.problem if problem is None else problem
        p = self.layout.n_u
        dense = int(problem.y.size) * p <= 20_000_000
        fn, leaves = _jitted("normal", problem, (self.layout, dense), _build_normal(self.layout, dense))
        return tuple(np.asarray(a, dtype=float) for a in fn(leaves, jnp.asarray(x_u, dtype=self.dtype)))

    def values(self, x_u) -> np.ndarray:
        """The model at every sample (the problem's layout) at a flat u."""
        layout = self.layout

        def build(rebuild):
            return lambda leaves, x: model_values(rebuild(leaves), layout.unravel(x))

        fn, leaves = _jitted("values", self.problem, (layout,), build)
        return np.asarray(fn(leaves, jnp.asarray(x_u, dtype=self.dtype)), dtype=float)

    def residuals(self, x_u) -> np.ndarray:
        """The flat residual vector (the fit's weighting) at a flat u."""
        layout = self.layout

        def build(rebuild):
            return lambda leaves, x: residual(layout.unravel(x), (rebuild(leaves).y, rebuild(leaves)))

        fn, leaves = _jitted("residual", self.problem, (layout,), build)
        return np.asarray(fn(leaves, jnp.asarray(x_u, dtype=self.dtype)), dtype=float)

    def constrained(self, xs) -> dict:
        xs = np.atleast_2d(np.asarray(xs, dtype=float))
        fn, leaves = _jitted("constrained", self.problem, (self.layout,), _build_constrained(self.layout, False))
        parts = []
        for start in range(0, xs.shape[0], self._BLOCK):
            block = xs[start : start + self._BLOCK]
            n = block.shape[0]
            if n < self._BLOCK:
                block = np.concatenate([block, np.repeat(block[-1:], self._BLOCK - n, axis=0)])
            out = fn(leaves, jnp.asarray(block, dtype=self.dtype))
            parts.append({k: np.asarray(v, dtype=float)[:n] for k, v in out.items()})
        return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}

    def constrained_jac(self, x) -> dict:
        fn, leaves = _jitted("constrained_jac", self.problem, (self.layout,), _build_constrained(self.layout, True))
        return {k: np.asarray(v, dtype=float) for k, v in fn(leaves, jnp.asarray(x, dtype=self.dtype)).items()}


# --- priors -------------------------------------------------------------------------------------


def _canonical_prior_key(key: str) -> str:
    return _ALIASES.get(key, key)


def _normalise_priors(priors: dict | None, layout: _Layout, structure: Structure) -> tuple:
    """The static prior spec: ((sampled name, kind, args), ...) with args tuples of floats."""
    priors = dict(priors or {})
    sampled = {_PUBLIC[n]: n for n in layout.names}
    if layout.noise:
        sampled["sigma_noise"] = "sigma_noise"
    given = {}
    for key, spec in priors.items():
        pub = _canonical_prior_key(key)
        if pub not in sampled:
            raise ValueError(f"priors: {key!r} is not a sampled parameter here; sampled: {sorted(sampled)}")
        if isinstance(spec, str):
            spec = (spec,)
        if not isinstance(spec, (tuple, list)) or not spec or spec[0] not in PRIOR_KINDS:
            raise ValueError(f"priors[{key!r}]: expected (kind, *args) with kind one of {PRIOR_KINDS}, got {spec!r}")
        kind, args = spec[0], tuple(spec[1:])
        want = {"flat": (0,), "uniform": (2,), "normal": (2,), "lognormal": (2,), "log-uniform": (0, 2)}[kind]
        if len(args) not in want:
            raise ValueError(f"priors[{key!r}]: {kind!r} takes {' or '.join(map(str, want))} numbers, got {len(args)}")
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
        given[sampled[pub]] = (kind, tuple(conv))
    out = []
    for name in layout.names:
        kind, args = given.get(name, ("flat", ()))
        out.append((name, kind, args))
    if layout.noise:
        kind, args = given.get("sigma_noise", ("log-uniform", ()))
        out.append(("sigma_noise", kind, args))
    return tuple(out)


def _describe_priors(prior: tuple, layout: _Layout, fixed_names: tuple[str, ...], structure: Structure) -> dict:
    params = {}
    for name, kind, args in prior:
        pub = _PUBLIC.get(name, name)
        rng = _RANGE_TEXT[pub]
        if pub == "n" and layout.conductor:
            rng = "(0, inf)"
        entry = {"kind": kind, "range": rng}
        if kind == "flat":
            entry["density"] = f"uniform in {pub} over {rng}" + (" (improper)" if "inf" in rng else "")
        elif kind == "uniform":
            entry.update(lo=args[0], hi=args[1], density=f"uniform in {pub} on [lo, hi]")
        elif kind == "normal":
            entry.update(mu=args[0], sd=args[1], density=f"{pub} ~ N(mu, sd²), truncated to {rng}")
        elif kind == "lognormal":
            entry.update(mu=args[0], sd=args[1], density=f"log {pub} ~ N(mu, sd²)")
        else:
            if args:
                entry.update(lo=args[0], hi=args[1])
            entry["density"] = f"∝ 1/{pub}" + (" on [lo, hi]" if args else " (flat in log " + pub + "; improper)")
        entry["per_element"] = pub not in ("s", "sigma_noise")
        entry["jacobian"] = _JACOBIAN_TEXT[pub]
        params[pub] = entry
    return {
        "space": "constrained parameters; sampling in the unconstrained u of ctfit._problem with log|∂θ/∂u| added",
        "parameters": params,
        "fixed": [_PUBLIC.get(f, f) for f in fixed_names],
        "ordering": (
            "lobes ascending in m: draws with m not strictly ascending have probability 0 (no label switching)"
            if layout.order_lobes
            else None
        ),
    }


# --- start: polish, Laplace covariance ----------------------------------------------------------


def _polish(normal, x: np.ndarray, max_steps: int = 30) -> tuple[np.ndarray, float, np.ndarray]:
    """A few Levenberg–Marquardt steps from the flat u ``x`` (the fit's optimum: usually already
    converged) on ``normal(x)`` = (½‖r‖², Jᵀr, JᵀJ). Returns the polished x, its cost and JᵀJ."""
    x = np.asarray(x, dtype=float)
    cost, grad, hess = normal(x)
    cost = float(cost)
    lam = 1e-6
    for _ in range(max_steps):
        if not np.isfinite(cost) or x.size == 0:
            break
        d = np.diag(hess).copy()
        d[d <= 0] = 1.0
        try:
            step = -np.linalg.solve(hess + lam * np.diag(d), grad)
        except np.linalg.LinAlgError:
            lam *= 10
            continue
        c_new, g_new, h_new = normal(x + step)
        c_new = float(c_new)
        if np.isfinite(c_new) and c_new <= cost:
            small = cost - c_new <= 1e-14 * max(cost, 1e-300) or np.max(np.abs(step)) < 1e-10
            x, cost, grad, hess = x + step, c_new, g_new, h_new
            lam = max(lam / 10, 1e-12)
            if small:
                break
        else:
            lam *= 10
            if lam > 1e8:
                break
    return x, cost, hess


def _weighted_problem(problem: Problem, values: np.ndarray) -> Problem:
    """The problem with loss "sigma" and σ_i = max(R_i, tiny): residuals (R − y)/R at fixed R."""
    scale = np.asarray(_relative_scale(problem, jnp.asarray(values, dtype=problem.y.dtype)))
    spec = dataclasses.replace(problem.spec, loss="sigma")
    return dataclasses.replace(problem, spec=spec, sigma=jnp.asarray(scale, dtype=problem.y.dtype))


def _polish_relative(engine: _Engine, x: np.ndarray, rounds: int = 10):
    """Start for noise proportional to the model: weighted least squares with σ_i ∝ R_i(θ),
    reweighted at the new θ until it settles (iteratively reweighted least squares). The
    weighted residual is the likelihood's r_i; the fixed point is near the mode (they differ by
    the derivative of the weights and of −Σ log R_i: small terms for small noise), and JᵀJ
    there is the Laplace curvature. Returns x, cost, JᵀJ and the normal-equations function."""
    x = np.asarray(x, dtype=float)
    n_obs = float(np.sum(np.asarray(engine.problem.mask)))
    for _ in range(rounds):
        q = _weighted_problem(engine.problem, engine.values(x))
        normal = functools.partial(engine.normal, problem=q)
        x_new, cost, hess = _polish(normal, x)
        moved = np.abs(x_new - x)
        x = x_new
        sd = np.sqrt(np.maximum(np.diag(_laplace_cov(hess, 2 * cost / max(n_obs - x.size, 1))[0]), 1e-300))
        if np.all(moved <= 1e-3 * sd):
            break
    return x, cost, hess, normal


def _sort_lobes(layout: _Layout, x: np.ndarray) -> tuple[np.ndarray, bool]:
    """Flat u with the lobes reordered by ascending m (m and the weights permuted together)."""
    sizes = [math.prod(sh) for sh in layout.shapes]
    parts = np.split(np.asarray(x[: layout.n_u], dtype=float), np.cumsum(sizes)[:-1])
    u = {k: p.reshape(sh) for k, p, sh in zip(layout.names, parts, layout.shapes)}
    order = np.argsort(u["m"])
    if np.all(order == np.arange(order.size)):
        return x, False
    u["m"] = u["m"][order]
    if "w" in u:
        logw = np.concatenate([[0.0], u["w"]])[order]
        u["w"] = logw[1:] - logw[0]
    flat = np.concatenate([np.ravel(u[k]) for k in layout.names])
    return np.concatenate([flat, x[layout.n_u :]]), True


def _residual_spread(engine: _Engine, x_u: np.ndarray) -> float | None:
    """rms residual of the quarter of the samples (sorted by value) where it is largest, over the
    quarter where it is smallest: ≈ 1 when one noise scale fits every residual. The residuals
    are the likelihood's ((R − y)/R for noise proportional to the model)."""
    if engine.layout.relative:
        problem = engine.problem
        values = jnp.asarray(engine.values(x_u), dtype=problem.y.dtype)
        r = np.asarray(_relative_residual(problem, values)[0], dtype=float)
    else:
        r = engine.residuals(x_u)
    y = np.asarray(engine.problem.y, dtype=float).reshape(-1)
    keep = np.asarray(engine.problem.mask, dtype=float).reshape(-1) > 0
    r, y = r[keep], y[keep]
    if r.size < 40:
        return None
    groups = np.array_split(np.argsort(y, kind="stable"), 4)
    rms = np.array([np.sqrt(np.mean(r[g] ** 2)) for g in groups])
    return float(np.max(rms) / np.min(rms)) if np.min(rms) > 0 else float("inf")


def _laplace_cov(hess: np.ndarray, scale2: float) -> tuple[np.ndarray, bool]:
    """(JᵀJ)⁻¹ · scale², with tiny eigenvalues regularised; also whether JᵀJ was well conditioned."""
    hess = 0.5 * (hess + hess.T)
    ev, vec = np.linalg.eigh(hess)
    top = float(np.max(ev)) if ev.size else 1.0
    well = bool(ev.size) and float(np.min(ev)) > 1e-12 * top
    ev = np.maximum(ev, 1e-12 * max(top, 1e-300))
    return (vec / ev) @ vec.T * scale2, well


def _constrained_one(problem: Problem, layout: _Layout, x):
    """Every reported quantity of one flat vector: s, m, weight, F0, n, k, Rd, sigma_noise."""
    st = problem.spec.structure
    u = layout.unravel(x)
    p = to_params(problem.spec, u, problem.fixed)
    out = {}
    if st.has_s:
        out["s"] = p.s
    if st.has_specular:
        out["m"] = p.m
        out["weight"] = p.w
    if st.needs_fresnel_params:
        f0 = normal_reflectance(st, p)
        out["F0"] = f0
        out["n"] = n_from_f0(f0) if st.fresnel == "f0" else p.n
        if st.fresnel == "conductor":
            out["k"] = p.k
    if st.has_diffuse:
        out["Rd"] = diffuse_reflectance(st, p)
    if layout.noise:
        out["sigma_noise"] = jnp.exp(x[layout.n_u])
    return out


def _laplace_stderr(engine: _Engine, x0, cov: np.ndarray) -> dict:
    layout = engine.layout
    jac = engine.constrained_jac(x0)
    out = {}
    for k, jk in jac.items():
        if k == "sigma_noise":
            continue
        jk = np.asarray(jk, dtype=float).reshape(-1, len(x0))[:, : layout.n_u]
        var = np.einsum("ij,jk,ik->i", jk, cov, jk)
        out[k] = np.sqrt(np.maximum(var, 0))
    return out


def _start_walkers(logp: _Engine, x0: np.ndarray, cov: np.ndarray, nwalkers: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Walkers from N(x0, cov), sd capped at 1 in u; draws without a finite log-prob are redrawn closer."""
    ev, vec = np.linalg.eigh(0.5 * (cov + cov.T))
    ev = np.clip(ev, 0, 1.0)
    root = vec * np.sqrt(ev)
    lp0 = logp(x0[None])[0]
    if not np.isfinite(lp0):
        raise ValueError(
            "the log-probability is not finite at the optimum (parameters outside the prior's range, "
            "or lobes with equal m); check the fit and the priors"
        )
    coords = x0 + rng.standard_normal((nwalkers, x0.size)) @ root.T
    lp = logp(coords)
    scale = 1.0
    for attempt in range(60):
        bad = ~np.isfinite(lp)
        if not bad.any():
            break
        if attempt % 6 == 5:
            scale *= 0.5
        coords[bad] = x0 + scale * rng.standard_normal((int(bad.sum()), x0.size)) @ root.T
        lp[bad] = logp(coords[bad])
    else:
        raise RuntimeError("could not start every walker with a finite log-probability near the optimum")
    return coords, lp


# --- the result ---------------------------------------------------------------------------------


_QUANTILES = (("p2.5", 2.5), ("p16", 16.0), ("median", 50.0), ("p84", 84.0), ("p97.5", 97.5))


def _summary(a: np.ndarray) -> dict | list:
    """{"median", "p16", "p84", "p2.5", "p97.5", "mean", "std"} per entry of draws (n, ...)."""
    a = np.asarray(a, dtype=float)
    q = np.percentile(a, [p for _, p in _QUANTILES], axis=0)
    mean, std = np.mean(a, axis=0), np.std(a, axis=0)

    def one(idx):
        d = {"median": float(q[2][idx]), "p16": float(q[1][idx]), "p84": float(q[3][idx])}
        d.update({"p2.5": float(q[0][idx]), "p97.5": float(q[4][idx]), "mean": float(mean[idx]), "std": float(std[idx])})
        return d

    if a.ndim == 1:
        return one(())
    return [one(i) for i in range(a.shape[1])]


@dataclasses.dataclass
class SampleResult:
    """Posterior draws and their summaries.

    - ``chain``: constrained draws after burn-in and thinning, all walkers flattened: a dict
      ``s`` (n,), ``m`` (n, J), ``weight`` (n, J), ``F0``/``n``/``k``/``Rd`` (n, W) (``Rd`` (n,)
      when constant), ``sigma_noise`` (n,) when the noise scale is sampled.
    - ``chain_u``: the raw chain (steps, walkers, ndim) in the sampled coordinates (``labels``);
      ``log_prob``: (steps, walkers).
    - ``summary``: per quantity ``{"median", "p16", "p84", "p2.5", "p97.5", "mean", "std"}``
      (lists over lobes/bands); ``colour``: the same for sRGB and CIELAB under D65 (or None).
    - ``diagnostics``: walkers, steps, burn, thin, draws, acceptance fraction, integrated
      autocorrelation time τ and effective sample size per sampled coordinate, ...
    - ``likelihood``, ``priors``: descriptions (also written to the JSON).
    - ``laplace_stderr``: the Laplace (JᵀJ)⁻¹ standard errors at the optimum (delta method),
      None when JᵀJ is ill conditioned; ``optimum``: the constrained optimum the walkers started
      from; ``warnings``: plain-language notes (chain too short, low acceptance, ...).
    """

    material: Material
    chain: dict
    chain_u: np.ndarray
    log_prob: np.ndarray
    labels: list[str]
    summary: dict
    colour: dict | None
    diagnostics: dict
    likelihood: dict
    priors: dict
    laplace_stderr: dict | None
    optimum: dict
    warnings: list[str]

    def to_dict(self) -> dict:
        """The fit JSON's ``uncertainty`` section (``docs/uncertainty.md``), JSON-ready."""
        out: dict = {"method": "emcee affine-invariant ensemble sampler (stretch move)"}
        sm = self.summary
        if "s" in sm:
            out["s"] = sm["s"]
        if "m" in sm:
            out["lobes"] = [{"m": sm["m"][j], "weight": sm["weight"][j]} for j in range(len(sm["m"]))]
        for key in ("F0", "n", "k", "Rd", "sigma_noise"):
            if key in sm:
                out[key] = sm[key]
        if self.colour is not None:
            out["colour"] = self.colour
        out["diagnostics"] = self.diagnostics
        out["likelihood"] = self.likelihood
        out["priors"] = self.priors
        out["warnings"] = list(self.warnings)
        return _jsonable(out)



# --- colour of the draws ------------------------------------------------------------------------


def _interp_matrix(src, dst) -> np.ndarray:
    """A (len(dst), len(src)) matrix doing np.interp (linear, held at the ends) from src to dst."""
    src = np.asarray(src, dtype=float)
    eye = np.eye(src.size)
    return np.stack([np.interp(dst, src, eye[j]) for j in range(src.size)], axis=1)


@functools.partial(jax.jit, static_argnums=0)
def _normal_fresnel(structure: Structure, params: Params):
    from ._brdf import fresnel

    return fresnel(structure, params, jnp.ones((), params.f0.dtype if params.f0 is not None else params.n.dtype))


@jax.jit
def _xyz_to_srgb_lab(XYZ, matrix, luminance, white):
    """Encoded, gamut-mapped sRGB and CIELAB of XYZ (…, 3): colour_report's steps, in one kernel."""
    from ._colour import XYZ_to_Lab, eotf_inverse_sRGB
    from ._gamut import desaturate_to_gamut

    lin = XYZ @ matrix.T
    return eotf_inverse_sRGB(desaturate_to_gamut(lin, luminance, upper=1.0)), XYZ_to_Lab(XYZ, white)


def draw_colours(material: Material, chain: dict, *, illuminant="D65", max_draws: int = 2000) -> dict:
    """sRGB (encoded, gamut-mapped as in :func:`ctfit._colour_report.colour_report`) and CIELAB
    under ``illuminant`` of every draw (at most ``max_draws``, evenly spaced): arrays (n, 3).

    The colour is that of ``colour_report`` at normal incidence: the normal reflectance F0(λ)
    when there is a specular part (F(0) from the interpolated F0, n or n and k, as the report
    computes it), π R_d(λ) otherwise.
    """
    from ._colour import DEFAULT_OBSERVER, _cmfs, rgb_conversion, spectral_weights

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
        to_bands = lambda a: a[:, order]  # noqa: E731
        n_out = 3
    else:
        grid = np.asarray(_cmfs(DEFAULT_OBSERVER).wavelengths, dtype=float)
        A = _interp_matrix(material.wavelength_nm, grid)
        to_bands = lambda a: a @ A.T  # noqa: E731
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
    srgb, lab = _xyz_to_srgb_lab(XYZ, np.asarray(conv.matrix, dtype=float), np.asarray(conv.luminance, dtype=float), white)
    return {"sRGB": np.asarray(srgb, dtype=float), "Lab": np.asarray(lab, dtype=float), "XYZ": XYZ, "illuminant": illum, "draws": int(idx.size)}


def _colour_summary(material: Material, chain: dict) -> tuple[dict | None, str | None]:
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
        "sRGB": _summary(c["sRGB"]),
        "sRGB_hex_median": hexs,
        "Lab": _summary(c["Lab"]),
        "draws": c["draws"],
        "note": "as ctfit color (colour_report) at normal incidence, for each posterior draw",
    }, None


# --- the driver ---------------------------------------------------------------------------------


def _fingerprint(problem: Problem, labels: list[str]) -> str:
    h = hashlib.sha1()
    h.update(np.asarray(problem.y).tobytes())
    h.update(problem.spec.loss.encode())
    h.update(json.dumps(labels).encode())
    return h.hexdigest()


@contextlib.contextmanager
def _quiet_emcee_log():
    """emcee logs its own "chain too short" message; ctfit raises ChainTooShortWarning instead."""
    logger = logging.getLogger("emcee")
    old = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(old)


def _resolve(fit_result_or_material, loss, fixed):
    mat = getattr(fit_result_or_material, "material", fit_result_or_material)
    if not isinstance(mat, Material):
        raise TypeError(f"sample() takes a FitResult or a Material, got {type(fit_result_or_material).__name__}")
    if loss is None:
        loss = getattr(fit_result_or_material, "loss", None)
        if loss is None and isinstance(mat.meta.get("fit"), dict):
            loss = mat.meta["fit"].get("loss")
    if fixed is None:
        fixed = tuple(mat.meta.get("fixed", ()))
    return mat, loss or "auto", tuple(fixed)


def sample(
    fit_result_or_material,
    data: Measurement,
    *,
    walkers: int | None = None,
    steps: int = 2000,
    burn: int | None = None,
    thin: int = 1,
    seed: int = 0,
    backend=None,
    resume: bool = False,
    overwrite: bool = False,
    progress: bool = False,
    priors: dict | None = None,
    loss: str | None = None,
    fixed: tuple[str, ...] | None = None,
    colour: bool = True,
) -> SampleResult:
    """Sample the posterior of the material's parameters given ``data`` (see the module docstring).

    ``fit_result_or_material``: a :class:`~ctfit.FitResult` or a :class:`~ctfit.Material` (e.g.
    a loaded fit JSON) fitted to ``data``; its parameters start the walkers. ``loss``: the
    residual weighting (default: the fit's, else "sigma" when the data has sigma, else
    "relative"); ``fixed``: parameters held fixed (default: the material's ``fixed`` key).

    ``walkers`` (default :func:`default_walkers`), ``steps`` per walker (the total, also when
    resuming), ``burn`` steps discarded (default: max(2 τ_max, steps/10), at most steps/2),
    ``thin``: keep every ``thin``-th step. ``seed`` fixes the start and emcee's generator: the
    same seed gives the same chain. ``backend``: path of an HDF5 file holding the chain
    (emcee's ``HDFBackend``); with ``resume=True`` a run found there is continued to ``steps``
    (only the missing steps are run; the random state is restored, so the result equals an
    uninterrupted run); a file that exists already is refused unless ``resume`` or
    ``overwrite`` (start again) is given. ``progress``: emcee's tqdm bar. ``priors``: {name: (kind, *args)}.
    ``colour``: also summarise the reflectance colour (sRGB, CIELAB under D65) of the draws.

    Raises :class:`ChainTooShortWarning` (a warning) when steps − burn < 50 τ_max.
    """
    import emcee

    t0 = time.perf_counter()
    if steps < 1 or thin < 1:
        raise ValueError(f"steps and thin must be ≥ 1, got steps={steps}, thin={thin}")
    if resume and backend is None:
        raise ValueError("resume=True needs a backend (the HDF5 file of the run to continue)")
    if backend is not None:
        from ._outputs import check_backend

        check_backend(backend, resume=resume, overwrite=overwrite, flags=("resume=True", "overwrite=True"), option="backend")
    material, loss, fixed = _resolve(fit_result_or_material, loss, fixed)
    if loss == "auto":
        loss = "sigma" if data.sigma is not None else "relative"
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
    st = material.structure
    dtype = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
    start = material.params_at(data.wavelength_nm if data.channels is None else None, data.channels)
    if st.needs_fresnel_params and st.fresnel == "f0" and start.f0 is None and start.n is not None:
        from ._fresnel import f0_from_n

        start = dataclasses.replace(start, f0=np.asarray(f0_from_n(start.n)))
    problem = make_problem(st, data, fixed_params=start, fixed=fixed, loss=loss, dtype=dtype, space="unconstrained")
    u0 = {k: jnp.asarray(v, dtype=dtype) for k, v in from_params(problem.spec, start).items()}
    if not u0:
        raise ValueError("nothing to sample: every parameter of the material is fixed")

    names = tuple(sorted(u0))
    noise = loss != "sigma"
    layout = _Layout(
        names=names,
        shapes=tuple(tuple(np.shape(u0[k])) for k in names),
        noise=noise,
        conductor=st.fresnel == "conductor",
        order_lobes=st.lobes > 1 and "m" in u0,
        relative=loss == "relative",
    )
    prior = _normalise_priors(priors, layout, st)
    ndim = layout.ndim
    nwalkers = default_walkers(ndim) if walkers is None else int(walkers)
    if nwalkers < 2 * ndim or nwalkers % 2:
        raise ValueError(f"walkers must be even and ≥ 2·ndim = {2 * ndim}, got {nwalkers}")
    engine = _Engine(problem, layout, prior, nwalkers // 2)

    # Optimum and Laplace covariance.
    x_fit = np.asarray(ravel_pytree(u0)[0], dtype=float)
    if layout.relative:  # the likelihood's mode is not the fit's (which divides by max(y, floor))
        x_u, cost, hess, normal = _polish_relative(engine, x_fit)
    else:
        normal = engine.normal
        x_u, cost, hess = _polish(normal, x_fit)
    if layout.order_lobes:  # keep lobes ascending in m (the polish may have swapped them)
        x_u, changed = _sort_lobes(layout, x_u)
        if changed:
            cost, _, hess = normal(x_u)
            cost = float(cost)
    n_obs = int(np.sum(np.asarray(problem.mask)))
    scale2 = 1.0 if not noise else 2 * cost / max(n_obs - x_u.size, 1)
    cov_u, well = _laplace_cov(hess, scale2)
    cov = np.zeros((ndim, ndim))
    cov[: x_u.size, : x_u.size] = cov_u
    x0 = x_u
    if noise:  # σ_noise² = Σ r²/N at the optimum; Laplace variance of log σ: 1/(2N)
        x0 = np.concatenate([x_u, [0.5 * math.log(max(2 * cost / max(n_obs, 1), 1e-300))]])
        cov[-1, -1] = 1.0 / (2 * max(n_obs, 1))
    labels = layout.labels()
    spread = _residual_spread(engine, x_u) if noise else None
    laplace = _laplace_stderr(engine, x0, cov_u) if well else None
    optimum = {k: v[0] for k, v in engine.constrained(x0[None]).items()}
    logp = engine

    # Backend: fresh, or continued.
    be = None
    done = 0
    fingerprint = _fingerprint(problem, labels)
    if backend is not None:
        path = pathlib.Path(backend)
        be = _open_backend(path, overwrite=overwrite)
        if resume and path.exists() and be.initialized and be.iteration > 0:
            if be.shape != (nwalkers, ndim):
                raise ValueError(
                    f"{path}: the stored run has (walkers, ndim) = {be.shape}, this one {(nwalkers, ndim)}; "
                    "pass the same walkers, or start again (overwrite=True; ctfit: --overwrite)"
                )
            stored = _read_attr(path, "ctfit_fingerprint")
            if stored is not None and stored != fingerprint:
                raise ValueError(
                    f"{path}: the stored run was sampled for other data, loss or parameters; "
                    "start again (overwrite=True; ctfit: --overwrite)"
                )
            done = int(be.iteration)
            if done > steps:
                raise ValueError(f"{path}: the stored run already has {done} steps, more than steps={steps}")
        else:
            with deferred():  # a Ctrl-C in the ctfit command waits: no half-made file
                be.reset(nwalkers, ndim)
                _write_attrs(path, {"ctfit_fingerprint": fingerprint, "ctfit_labels": json.dumps(labels), "ctfit_seed": int(seed)})
        note_resumable(path)
    sampler = emcee.EnsembleSampler(nwalkers, ndim, logp, vectorize=True, backend=be)
    if done == 0:
        rng = np.random.default_rng(seed)
        coords, lp = _start_walkers(logp, x0, cov, nwalkers, rng)
        sampler.random_state = np.random.RandomState(seed).get_state()
        state = emcee.State(coords, log_prob=lp)
        todo = steps
    else:
        state = None  # continue from the backend's last sample and random state
        todo = steps - done
    t_run = time.perf_counter()
    if todo > 0:
        sampler.run_mcmc(state, todo, progress=progress)
    run_s = time.perf_counter() - t_run

    chain_u = np.asarray(sampler.get_chain())
    log_prob = np.asarray(sampler.get_log_prob())
    n_steps = chain_u.shape[0]
    with _quiet_emcee_log():
        tau_all = np.asarray(emcee.autocorr.integrated_time(chain_u[n_steps // 2 :], quiet=True))
    tau_max0 = float(np.nanmax(tau_all)) if np.all(np.isfinite(tau_all)) else float(n_steps)
    if burn is None:
        burn = int(min(n_steps // 2, max(math.ceil(2 * tau_max0), n_steps // 10)))
    if not 0 <= burn < n_steps:
        raise ValueError(f"burn must be in [0, steps), got {burn} with steps={n_steps}")
    with _quiet_emcee_log():
        tau = np.asarray(sampler.get_autocorr_time(discard=burn, quiet=True), dtype=float)
    kept = n_steps - burn
    tau_max = float(np.max(tau))
    ess = nwalkers * kept / np.maximum(tau, 1.0)
    acc = np.asarray(sampler.acceptance_fraction, dtype=float)
    flat = np.asarray(sampler.get_chain(discard=burn, thin=thin, flat=True))
    chain = engine.constrained(flat)
    summary = {k: _summary(v) for k, v in chain.items()}

    notes: list[str] = []
    if kept < 50 * tau_max:
        msg = (
            f"the chain is too short for reliable intervals: {kept} steps after burn-in < 50 τ_max = "
            f"{50 * tau_max:.0f} (τ_max = {tau_max:.1f} steps, for {labels[int(np.argmax(tau))]}); run more steps"
        )
        warnings.warn(msg, ChainTooShortWarning, stacklevel=2)
        notes.append(msg)
    if np.mean(acc) < 0.15 or np.mean(acc) > 0.7:
        notes.append(f"mean acceptance fraction {np.mean(acc):.2f} is outside 0.15–0.7: the posterior may be multimodal or badly scaled")
    if laplace is None:
        notes.append("Laplace standard errors not computed: JᵀJ is singular or ill conditioned")
    if spread is not None and spread > 2:
        notes.append(
            f"the residuals' scale varies by ×{spread:.3g} between the lowest and highest quarter of the data "
            f"(by value): one σ_noise for all of them is a poor noise model, and the intervals may be too narrow; "
            "give the data a sigma column (loss 'sigma'), or use a loss whose residuals have one scale"
        )
    col = None
    if colour:
        col, note = _colour_summary(material, chain)
        if note:
            notes.append(note)

    if loss == "sigma":
        likelihood = {
            "model": "gaussian",
            "loss": loss,
            "residual": "r_i = (R_i − y_i)/sigma_i",
            "log_likelihood": "−½ Σ r_i² + const",
            "noise": "the data's sigma column",
            "n_samples": n_obs,
        }
    else:
        res_text = {
            "absolute": "r_i = R_i − y_i",
            "relative": "r_i = (R_i − y_i)/R_i, R_i the model at θ (max(R_i, tiny))",
            "cosine": "r_i = (R_i − y_i) cos θ_i",
            "log": "r_i = log(1 + R_i cos θ_i) − log(1 + y_i cos θ_i)",
        }[loss]
        likelihood = {
            "model": "gaussian",
            "loss": loss,
            "residual": res_text,
            "log_likelihood": "−N log σ_noise − ½ Σ r_i²/σ_noise² + const",
            "noise": "σ_noise sampled (parameter sigma_noise); prior as in priors.parameters.sigma_noise",
            "n_samples": n_obs,
        }
        if loss == "relative":
            likelihood.update(
                log_likelihood="−Σ log R_i − N log σ_noise − ½ Σ r_i²/σ_noise² + const",
                noise=(
                    "proportional to the model: y_i ~ N(R_i, (σ_noise R_i)²), σ_noise (a relative noise) sampled "
                    "(parameter sigma_noise); prior as in priors.parameters.sigma_noise"
                ),
                note=(
                    "the fit's relative loss divides by max(y_i, floor) (floor = "
                    f"{float(problem.floor):.6g}); the likelihood divides by the model, without a floor, so its mode "
                    "is near, not at, the fit's optimum, and samples far below the peak count with their relative noise"
                ),
            )
    diagnostics = {
        "walkers": nwalkers,
        "ndim": ndim,
        "steps": n_steps,
        "steps_run_now": int(max(todo, 0)),
        "resumed_from": done,
        "burn": int(burn),
        "thin": int(thin),
        "draws": int(flat.shape[0]),
        "seed": int(seed),
        "acceptance_fraction": {"mean": float(np.mean(acc)), "min": float(np.min(acc)), "max": float(np.max(acc))},
        "autocorr_time": dict(zip(labels, map(float, tau))),
        "autocorr_time_max": tau_max,
        "ess": dict(zip(labels, map(float, ess))),
        "ess_min": float(np.min(ess)),
        "chain_long_enough": bool(kept >= 50 * tau_max),
        "time_s": time.perf_counter() - t0,
        "sampling_time_s": run_s,
        "walker_steps_per_s": (nwalkers * max(todo, 0) / run_s) if run_s > 0 and todo > 0 else None,
        "backend": None if backend is None else str(backend),
        "residual_scale_ratio": spread,
        "autocorr_note": "τ in steps, per sampled coordinate (u of ctfit._problem); ESS = walkers · (steps − burn)/τ",
    }
    return SampleResult(
        material=material,
        chain=chain,
        chain_u=chain_u,
        log_prob=log_prob,
        labels=labels,
        summary=summary,
        colour=col,
        diagnostics=diagnostics,
        likelihood=likelihood,
        priors=_describe_priors(prior, layout, fixed, st),
        laplace_stderr=laplace,
        optimum=optimum,
        warnings=notes,
    )


def _open_backend(path: pathlib.Path, *, overwrite: bool):
    """emcee's HDF5 backend on ``path`` (checked by :func:`~ctfit._outputs.check_backend`)."""
    import h5py

    if overwrite and path.is_file() and not h5py.is_hdf5(path):
        with deferred(), h5py.File(path, "w"):  # start again in a file h5py cannot open (through a link, if one)
            pass
    return _whole_steps_backend()(str(path), name="ctfit")


@functools.cache
def _whole_steps_backend():
    import emcee

    class WholeStepsHDFBackend(emcee.backends.HDFBackend):
        """Steps written whole: a Ctrl-C in the ``ctfit`` command waits for the one under way."""

        def save_step(self, *args, **kwargs):
            with deferred():
                return super().save_step(*args, **kwargs)

        def grow(self, *args, **kwargs):
            with deferred():
                return super().grow(*args, **kwargs)

    return WholeStepsHDFBackend


def _write_attrs(path: pathlib.Path, attrs: dict) -> None:
    import h5py

    with h5py.File(path, "a") as f:
        for k, v in attrs.items():
            f["ctfit"].attrs[k] = v


def _read_attr(path: pathlib.Path, key: str):
    import h5py

    with h5py.File(path, "r") as f:
        v = f["ctfit"].attrs.get(key)
    return v.decode() if isinstance(v, bytes) else (None if v is None else str(v))
