"""The log-posterior of one flat sampling vector: likelihood, priors and log-Jacobians.

The walkers move in the unconstrained coordinates u of :mod:`ctfit._model.parameters` (then log σ_noise
when the noise scale is sampled), laid out by :class:`Layout`. The posterior density in u is

    log p(u | y) = log L(y | θ(u)) + log π(θ(u)) + log |∂θ/∂u|,

with π from :mod:`ctfit._sampling.priors` (proper, cut to each value's physical range) and the
log-Jacobian from the parameter table, so that the prior is the stated density in θ, not in u.

Likelihood (Gaussian), on the fit's residual weighting (:func:`ctfit._fitting.jacobian.residual`) but
for the relative loss:

- "sigma": r_i = (R_i − y_i)/σ_i ~ N(0, 1), log L = −½ Σ r_i²;
- "relative": noise proportional to the model, y_i = R_i (1 + ε_i): r_i = (R_i − y_i)/R_i,
  log L = −Σ log R_i − N log σ_noise − ½ Σ r_i²/σ_noise² (the model, not the data with the
  fit's floor: a floor shrinks the residuals below it and makes σ_noise too small);
- "absolute", "cosine", "log": r_i ~ N(0, σ_noise²), log L = −N log σ_noise − ½ Σ r_i²/σ_noise².

Lobes are kept ordered by m (no label switching): a draw with m not strictly ascending has
probability 0.
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
from jax.flatten_util import ravel_pytree

from .._fitting import Problem, model_values, residual, to_params
from .._model import PARAMETERS
from .priors import log_prior, public_name, support

__all__ = ["Layout", "log_prob_one", "log_jacobian_one", "likelihood_residual", "relative_residual", "relative_scale"]


@dataclasses.dataclass(frozen=True)
class Layout:
    """Static layout of the flat sampling vector: u's entries (ravel_pytree order), then log σ_noise."""

    names: tuple[str, ...]
    shapes: tuple[tuple[int, ...], ...]
    noise: bool
    conductor: bool
    order_lobes: bool
    relative: bool = False  # σ_i = σ_noise · R_i(θ): noise proportional to the model
    plastic: bool = False  # one real index n in PLASTIC_INDEX_RANGE

    @property
    def n_u(self) -> int:
        return int(sum(math.prod(s) for s in self.shapes))

    @property
    def ndim(self) -> int:
        return self.n_u + int(self.noise)

    @property
    def fresnel(self) -> str:
        """The key of the priors' support of n: "conductor", "plastic" or "f0" (n ≥ 1)."""
        return "conductor" if self.conductor else ("plastic" if self.plastic else "f0")

    def unravel(self, x):
        template = {k: jnp.zeros(s, x.dtype) for k, s in zip(self.names, self.shapes)}
        return ravel_pytree(template)[1](x[: self.n_u])

    def labels(self) -> list[str]:
        """Names of the sampled coordinates: "m[0]", "weight[1]" (log(w_1/w_0)), ..., "sigma_noise"."""
        out = []
        for name, shape in zip(self.names, self.shapes):
            pub, size = public_name(name), math.prod(shape)
            if not shape:
                out.append(pub)
            else:
                first = 1 if name == "w" else 0  # u_w[i] is log(w_{i+1}/w_0)
                out += [f"{pub}[{i + first}]" for i in range(size)]
        return out + (["sigma_noise"] if self.noise else [])


def relative_scale(problem: Problem, values):
    """max(R_i, tiny) at the observed samples, 1 at missing cells: σ_i / σ_noise of noise
    proportional to the model."""
    tiny = jnp.finfo(values.dtype).tiny
    return jnp.where(problem.mask > 0, jnp.maximum(values, tiny), jnp.ones((), values.dtype))


def relative_residual(problem: Problem, values):
    """Noise proportional to the model: r_i = (R_i − y_i)/R_i and the normalisation −Σ log R_i of
    the Gaussian with σ_i = σ_noise R_i (the −N log σ_noise part is added by the caller)."""
    scale = relative_scale(problem, values)
    r = (values - problem.y) / scale * problem.mask
    return r.reshape(-1), -jnp.sum(jnp.log(scale))


def likelihood_residual(problem: Problem, layout: Layout, u: dict):
    """The likelihood's residual vector at ``u`` and its extra log-normalisation (0 but for "relative")."""
    if layout.relative:
        return relative_residual(problem, model_values(problem, u))
    return residual(u, (problem.y, problem)), jnp.zeros((), problem.y.dtype)


def log_jacobian_one(layout: Layout, x):
    """log |∂(θ, σ_noise)/∂(u, log σ_noise)| of one flat vector."""
    u = layout.unravel(x)
    out = sum((PARAMETERS[name].log_jacobian(u[name]) for name in layout.names), jnp.zeros((), x.dtype))
    return out + (x[layout.n_u] if layout.noise else 0.0)


def log_prob_one(problem: Problem, layout: Layout, prior: tuple, x):
    """Log-posterior (up to a constant) of one flat sampling vector ``x``; −∞ outside the priors' support."""
    u = layout.unravel(x)
    params = to_params(problem.spec, u, problem.fixed)
    r, log_l = likelihood_residual(problem, layout, u)
    chi2 = jnp.sum(r * r)
    log_p = log_jacobian_one(layout, x)
    for name, kind, args in prior:
        lo, hi = support(name, layout.fresnel)
        if name == "sigma_noise":
            log_sn = x[layout.n_u]
            log_l = log_l - jnp.sum(problem.mask) * log_sn - 0.5 * chi2 * jnp.exp(-2 * log_sn)
            log_p = log_p + log_prior(kind, args, jnp.exp(log_sn), lo, hi)
        else:
            log_p = log_p + log_prior(kind, args, getattr(params, name), lo, hi)
    if not layout.noise:
        log_l = -0.5 * chi2
    ok = jnp.isfinite(log_l) & jnp.isfinite(log_p)
    if layout.order_lobes:
        ok = ok & jnp.all(jnp.diff(u["m"]) > 0)  # m = exp(u_m) is monotone in u_m
    total = log_l + log_p
    return jnp.where(ok & jnp.isfinite(total), total, -jnp.inf)
