"""The compiled pieces of one sampling problem, handed to emcee and to the start and report.

:class:`Engine` is emcee's vectorised log-probability (``vectorize=True``: one call per
half-ensemble, a jit-compiled, vmapped JAX function), and gives the fit's normal equations
(:func:`ctfit._fitting.jacobian.normal_equations`) and reported quantities
(:func:`ctfit._fitting.fit_report.constrained_quantities`) at flat sampling vectors.

Everything but the log-probability is ``eqx.filter_jit``-compiled (traced once per problem
shape and spec; JAX's persistent cache, :mod:`ctfit._runtime.compile_cache`, keeps the executables across
processes). The log-probability, called thousands of times, has the goniometer geometry
compiled in as constants and only the data values as arguments: XLA folds every
data-independent term (the V-cavity G, powers of tan²α, ...), 2–3× fewer operations per walker,
and a call is the bare executable, without pytree filtering. Its programs are kept in the
runtime's memory (:func:`ctfit._runtime.stored_programs.kept_program`) under a key that holds
the geometry's values, so data sets that share directions (fresh noise on the same goniometer)
compile once.
"""

from __future__ import annotations

import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._fitting import Problem, constrained_quantities, model_values, normal_equations
from .._model import PUBLIC_NAMES
from .._runtime import kept_program
from .logprob import Layout, likelihood_residual, log_jacobian_one, log_prob_one, relative_scale

__all__ = ["Engine"]

_BAKE_MAX_PAIRS = 200_000  # direction pairs up to which the geometry is compiled in as constants
_BAKED_KEPT = 16  # baked log-probabilities kept in memory (each holds its geometry)


def _data_fields(q: Problem):
    return q.y, q.sigma, q.floor


def _without_data(problem: Problem) -> Problem:
    """The problem without its data values (y, sigma, floor): what a baked program compiles in."""
    return eqx.tree_at(_data_fields, problem, (None, None, None), is_leaf=lambda x: x is None)


def _baked(problem: Problem, layout: Layout, prior: tuple):
    """The log-probability with the problem's geometry as constants: f(data values, xs), one per
    geometry (the last :data:`_BAKED_KEPT` kept)."""
    geometry, has_sigma = _without_data(problem), problem.sigma is not None

    def build():
        def f(values, xs):
            y, sigma, floor = values if has_sigma else (values[0], None, values[1])
            q = eqx.tree_at(_data_fields, geometry, (y, sigma, floor), is_leaf=lambda x: x is None)
            return jax.vmap(lambda x: log_prob_one(q, layout, prior, x))(xs)

        return jax.jit(f)

    return kept_program("sample_log_prob", build, (layout, prior, has_sigma), geometry, limit=_BAKED_KEPT)


@eqx.filter_jit
def _log_prob(problem: Problem, layout: Layout, prior: tuple, xs):
    return jax.vmap(lambda x: log_prob_one(problem, layout, prior, x))(xs)


def _weighted(problem: Problem, values):
    """The problem with loss "sigma" and σ_i = max(R_i, tiny): residuals (R − y)/R at fixed R
    (the relative likelihood's weights, frozen at one θ)."""
    return dataclasses.replace(problem, spec=dataclasses.replace(problem.spec, loss="sigma"), sigma=relative_scale(problem, values))


@eqx.filter_jit
def _normal(problem: Problem, layout: Layout, x, likelihood: bool):
    """½‖r‖², Jᵀr, JᵀJ at a flat u, of the likelihood's residual (the fit's normal equations; for
    the relative loss with the weights frozen at u) or, ``likelihood`` False, of the fit's own."""
    u = layout.unravel(x)
    if layout.relative and likelihood:
        problem = _weighted(problem, model_values(problem, u))
    return normal_equations(problem, u)


def _reported(problem: Problem, layout: Layout, x):
    """The fit's reported quantities (s, m, weight, F0, n, k, Rd) of one flat vector, and σ_noise."""
    out = {PUBLIC_NAMES.get(k, k): v for k, v in constrained_quantities(problem, layout.unravel, x).items()}
    if layout.noise:
        out["sigma_noise"] = jnp.exp(x[layout.n_u])
    return out


def _residual(problem: Problem, layout: Layout, x):
    u = layout.unravel(x)
    return likelihood_residual(problem, layout, u)[0], model_values(problem, u).reshape(-1)


@eqx.filter_jit
def _per_draw(one, args: tuple, xs):
    """``one(*args, x)`` for every row x of ``xs``."""
    return jax.vmap(lambda x: one(*args, x))(xs)


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
        self.problem, self.layout, self.chunk = problem, layout, int(chunk)
        self.dtype = problem.y.dtype
        if problem.geom.cos_vh.shape[0] > _BAKE_MAX_PAIRS:
            self._lp = functools.partial(_log_prob, problem, layout, prior)
        else:
            self._lp = functools.partial(_baked(problem, layout, prior), [a for a in _data_fields(problem) if a is not None])
        self._shape = (self.chunk, layout.ndim)

    def __call__(self, coords):
        if type(coords) is np.ndarray and coords.shape == self._shape and coords.dtype == np.float64:
            # emcee's stretch move, every call but the first: nothing but the XLA call.
            return np.asarray(self._lp(coords))
        return self._blocks(self._lp, np.atleast_2d(np.asarray(coords, dtype=float)), self.chunk)

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

    def _draws(self, one, xs, size: int, *args):
        """``one(*args, x)`` for every row x of ``xs``, in blocks of ``size``."""
        xs = np.atleast_2d(np.asarray(xs, dtype=float))
        return self._blocks(lambda block: _per_draw(one, args, block), xs, size)

    def normal(self, x_u, likelihood: bool = True):
        """½‖r‖², Jᵀr, JᵀJ at a flat u: of the likelihood's residual, or (``likelihood`` False) of the
        fit's (they differ for the relative loss only)."""
        out = _normal(self.problem, self.layout, jnp.asarray(x_u, dtype=self.dtype), likelihood)
        return tuple(np.asarray(a, dtype=float) for a in out)

    def residuals(self, x_u) -> tuple[np.ndarray, np.ndarray]:
        """The likelihood's residual vector (flat, missing cells 0) at a flat u, and the model's
        values there (flat, the same order)."""
        r, values = self._draws(_residual, x_u, 1, self.problem, self.layout)
        return r[0], values[0]

    def constrained(self, xs) -> dict:
        """The reported quantities of every row of ``xs``: {"m": (n, J), "F0": (n, W), ...}."""
        return self._draws(_reported, xs, self._BLOCK, self.problem, self.layout)

    def log_jacobian(self, xs) -> np.ndarray:
        """log |∂θ/∂u| of every row of ``xs`` (the log-probability in u minus the density in θ)."""
        return self._draws(log_jacobian_one, xs, self._BLOCK, self.layout)

    def constrained_jac(self, x) -> dict:
        """∂(reported quantity)/∂(flat vector) at ``x``."""
        out = _reported_jac(self.problem, self.layout, jnp.asarray(x, dtype=self.dtype))
        return {k: np.asarray(v, dtype=float) for k, v in out.items()}
