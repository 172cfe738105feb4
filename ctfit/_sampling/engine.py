"""The compiled pieces of one sampling problem, handed to emcee and to the start and report.

:class:`Engine` is emcee's vectorised log-probability (``vectorize=True``: one call per
half-ensemble, a jit-compiled, vmapped JAX function), and gives the fit's normal equations
(:func:`ctfit._fitting.problem.normal_equations`) and reported quantities
(:func:`ctfit._fitting.least_squares.constrained_quantities`) at flat sampling vectors.

Everything but the log-probability is ``eqx.filter_jit``-compiled (traced once per problem
shape and spec; JAX's persistent cache, :mod:`ctfit._runtime.compile_cache`, keeps the executables across
processes). The log-probability, called thousands of times, has the goniometer geometry
compiled in as constants and only the data values as arguments: XLA folds every
data-independent term (the V-cavity G, powers of tan²α, ...), 2–3× fewer operations per walker,
and a call is the bare executable, without pytree filtering. Its programs are kept per geometry
fingerprint, so data sets that share directions (fresh noise on the same goniometer) compile once.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._fitting import Problem, constrained_quantities, model_values, normal_equations
from .logprob import Layout, likelihood_residual, log_jacobian_one, log_prob_one

__all__ = ["Engine"]

_BAKE_MAX_PAIRS = 200_000  # direction pairs up to which the geometry is compiled in as constants


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


class _Keyed:
    """A problem hashed by its geometry fingerprint (the key of :func:`_baked`)."""

    def __init__(self, problem: Problem):
        self.problem, self.key = problem, _geometry_key(problem)

    def __hash__(self):
        return hash(self.key)

    def __eq__(self, other):
        return isinstance(other, _Keyed) and other.key == self.key


@functools.lru_cache(maxsize=16)
def _baked(keyed: _Keyed, layout: Layout, prior: tuple):
    """The log-probability with the problem's geometry as constants: f(data values, xs), one per geometry."""
    problem = keyed.problem
    has_sigma = problem.sigma is not None

    def f(values, xs):
        y, sigma, floor = (values[0], values[1], values[2]) if has_sigma else (values[0], None, values[1])
        q = eqx.tree_at(_data_fields, problem, (y, sigma, floor), is_leaf=lambda x: x is None)
        return jax.vmap(lambda x: log_prob_one(q, layout, prior, x))(xs)

    return jax.jit(f)


@eqx.filter_jit
def _log_prob(problem: Problem, layout: Layout, prior: tuple, xs):
    return jax.vmap(lambda x: log_prob_one(problem, layout, prior, x))(xs)


def _weighted(problem: Problem, values):
    """The problem with loss "sigma" and σ_i = max(R_i, tiny): residuals (R − y)/R at fixed R
    (the relative likelihood's weights, frozen at one θ)."""
    scale = jnp.where(problem.mask > 0, jnp.maximum(values, jnp.finfo(values.dtype).tiny), 1.0)
    return dataclasses.replace(problem, spec=dataclasses.replace(problem.spec, loss="sigma"), sigma=scale)


@eqx.filter_jit
def _normal(problem: Problem, layout: Layout, x, likelihood: bool):
    """½‖r‖², Jᵀr, JᵀJ at a flat u, of the likelihood's residual (the fit's normal equations; for
    the relative loss with the weights frozen at u) or, ``likelihood`` False, of the fit's own."""
    u = layout.unravel(x)
    if layout.relative and likelihood:
        problem = _weighted(problem, model_values(problem, u))
    return normal_equations(problem, u)


_PUBLIC_KEYS = {"w": "weight", "rd": "Rd"}


def _reported(problem: Problem, layout: Layout, x):
    """The fit's reported quantities (s, m, weight, F0, n, k, Rd) of one flat vector, and σ_noise."""
    out = {_PUBLIC_KEYS.get(k, k): v for k, v in constrained_quantities(problem, layout.unravel, x).items()}
    if layout.noise:
        out["sigma_noise"] = jnp.exp(x[layout.n_u])
    return out


def _residual(problem: Problem, layout: Layout, x):
    return likelihood_residual(problem, layout, layout.unravel(x))[0]


def _log_jacobian(problem: Problem, layout: Layout, x):
    return log_jacobian_one(layout, x)


@eqx.filter_jit
def _per_draw(problem: Problem, layout: Layout, one, xs):
    return jax.vmap(lambda x: one(problem, layout, x))(xs)


@eqx.filter_jit
def _reported_jac(problem: Problem, layout: Layout, x):
    return jax.jacfwd(lambda z: _reported(problem, layout, z))(x)


class Engine:
    """The compiled pieces for one problem (see the module docstring).

    emcee calls ``engine(coords)`` with (k, ndim) NumPy arrays; every call is cut into blocks of
    ``chunk`` walkers (half the ensemble), the last one padded, so the log-probability compiles once.
    """

    _BLOCK = 512  # rows per call of the per-draw functions

    def __init__(self, problem: Problem, layout: Layout, prior: tuple, chunk: int):
        self.problem, self.layout, self.prior, self.chunk = problem, layout, prior, int(chunk)
        self.dtype = problem.y.dtype
        if problem.geom.cos_vh.shape[0] > _BAKE_MAX_PAIRS:
            self._lp, self.leaves = functools.partial(_log_prob, problem, layout, prior), None
        else:
            baked = _baked(_Keyed(problem), layout, prior)
            self.leaves = [a for a in _data_fields(problem) if a is not None]
            self._lp = functools.partial(baked, self.leaves)
        self._shape = (self.chunk, layout.ndim)
        self.calls = 0

    def __call__(self, coords):
        if type(coords) is np.ndarray and coords.shape == self._shape and coords.dtype == np.float64:
            # emcee's stretch move, every call but the first: nothing but the XLA call.
            self.calls += self.chunk
            return np.asarray(self._lp(coords))
        coords = np.atleast_2d(np.asarray(coords, dtype=float))
        self.calls += coords.shape[0]
        return self._blocks(self._lp, coords, self.chunk)

    def _blocks(self, fn, xs, size: int):
        """``fn`` over the rows of ``xs`` in padded blocks of ``size``; a dict or an array out."""
        parts = []
        for start in range(0, xs.shape[0], size):
            block = xs[start : start + size]
            n = block.shape[0]
            if n < size:
                block = np.concatenate([block, np.repeat(block[-1:], size - n, axis=0)])
            parts.append(jax.tree.map(lambda a: np.asarray(a, dtype=float)[:n], fn(jnp.asarray(block, dtype=self.dtype))))
        return jax.tree.map(lambda *a: np.concatenate(a), *parts)

    def _draws(self, one, xs, size: int):
        xs = np.atleast_2d(np.asarray(xs, dtype=float))
        return self._blocks(lambda block: _per_draw(self.problem, self.layout, one, block), xs, size)

    def normal(self, x_u, likelihood: bool = True):
        """½‖r‖², Jᵀr, JᵀJ at a flat u: of the likelihood's residual, or (``likelihood`` False) of the
        fit's (they differ for the relative loss only)."""
        out = _normal(self.problem, self.layout, jnp.asarray(x_u, dtype=self.dtype), likelihood)
        return tuple(np.asarray(a, dtype=float) for a in out)

    def residuals(self, x_u) -> np.ndarray:
        """The likelihood's residual vector (flat, missing cells 0) at a flat u."""
        return self._draws(_residual, x_u, 1)[0]

    def constrained(self, xs) -> dict:
        """The reported quantities of every row of ``xs``: {"m": (n, J), "F0": (n, W), ...}."""
        return self._draws(_reported, xs, self._BLOCK)

    def log_jacobian(self, xs) -> np.ndarray:
        """log |∂θ/∂u| of every row of ``xs`` (the log-probability in u minus the density in θ)."""
        return self._draws(_log_jacobian, xs, self._BLOCK)

    def constrained_jac(self, x) -> dict:
        """∂(reported quantity)/∂(flat vector) at ``x``."""
        out = _reported_jac(self.problem, self.layout, jnp.asarray(x, dtype=self.dtype))
        return {k: np.asarray(v, dtype=float) for k, v in out.items()}
