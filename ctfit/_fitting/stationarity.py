"""What a fit's stationarity is judged by: the variables held on a bound (:func:`active_set`)
and the decrease of the cost one Gauss–Newton step promises (:func:`predicted_decrease`).

The solver's programs call them at every step (traced, ``xp=jax.numpy``); the light report of the
data-chosen default's candidates calls them on the host (``xp=numpy``: no program per structure,
and no optimistix imported, :mod:`~ctfit._fitting.solvers`).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.linalg import solve_triangular

__all__ = ["active_set", "cost_scale", "held_by_bound", "predicted_decrease", "stationary_decrease"]


def cost_scale(cost, zero_cost, xp: Any = jnp):
    """What a predicted decrease of the cost is relative to: the cost, or ε times ``zero_cost`` (the
    cost of a model that is 0 everywhere) where that is larger, so that at an exact fit (cost → 0)
    rounding is not divided by rounding; never below the dtype's smallest normal number."""
    finfo = np.finfo(cost.dtype)
    return xp.maximum(cost, xp.maximum(finfo.eps * zero_cost, finfo.tiny))


def active_set(y, grad, lower, upper):
    """Variables held on a bound: at the lower bound with the gradient > 0 (the cost falls
    only by going below it) or at the upper bound with the gradient < 0 (JAX or NumPy arrays)."""
    return ((y <= lower) & (grad > 0)) | ((y >= upper) & (grad < 0))


def held_by_bound(y, grad, hess_diag, lower, upper, xp: Any = jnp):
    """Variables that a projected Gauss–Newton step holds at a bound: those of :func:`active_set`,
    and those so near a bound that their own Newton step, −g_i/H_ii, reaches it (a conductor's
    k of 2.6·10⁻⁸ with g = 1.3·10⁻⁴ and H_ii = 2.8·10⁻⁷: F depends on k², so the curvature
    vanishes at k = 0). The step stops at the bound: what it gains there is at most
    |g_i|·(the distance to it) (:func:`stationary_decrease`), not the g_i²/H_ii of a step
    through it. ``xp``: as for :func:`predicted_decrease`."""
    distance = xp.where(grad > 0, y - lower, upper - y)  # to the bound the gradient leads to (the cost falls along −g)
    bounded = xp.isfinite(distance)
    near = bounded & (grad != 0) & (xp.where(bounded, distance, 0) * hess_diag <= xp.abs(grad))
    return active_set(y, grad, lower, upper) | near


def stationary_decrease(y, grad, jtj, lower, upper, xp: Any = jnp):
    """The decrease of ½‖r‖² that one projected Gauss–Newton step from ``y`` promises: the
    others :func:`predicted_decrease`, and each variable :func:`held_by_bound` what a step of its
    own can take, at most |g_i|·(the distance to its bound) and at most its regularised share
    g_i²/(H_ii + μ) (μ as in :func:`predicted_decrease`: a direction the data does not determine
    promises no more than it did free). What a stopping test compares with its tolerance: with
    those variables free the decrease is that of a step through the bound (a fit started at the
    truth ran to its step limit on a promise of 7.6·10⁻⁶ of the cost, where the step can gain
    10⁻¹⁴ of it). ``xp``: as for :func:`predicted_decrease`."""
    diag = xp.diag(jtj)
    held = held_by_bound(y, grad, diag, lower, upper, xp)
    distance = xp.where(held, xp.where(grad > 0, y - lower, upper - y), 0)
    mu = xp.max(xp.abs(diag)) * _cut(jtj) if jtj.size else 0
    share = held & (diag + mu > 0)  # (no share where JᵀJ is 0: nothing determined)
    alone = xp.where(share, grad * grad / xp.where(share, diag + mu, 1), 0)
    gain = xp.sum(xp.minimum(xp.abs(grad) * distance, alone))
    return predicted_decrease(jtj, grad, ~held, xp) + gain


def predicted_decrease(jtj, jtr, free=None, xp: Any = jnp):
    """½ gᵀ(JᵀJ + μI)⁻¹g over the ``free`` variables, μ = 10·P·ε·max diag JᵀJ: the decrease of
    ½‖r‖² one Gauss–Newton step promises. Directions JᵀJ does not determine are left out, so a
    degenerate but stationary point reads as one: this is a Tikhonov-regularised pseudo-inverse,
    a direction of eigenvalue e counting e/(e + μ) of its share (all of it where e ≫ μ, none
    where e ≪ μ, and g = Jᵀr lies in the range of JᵀJ, so what μ leaves out there is rounding).

    Computed as ½‖L⁻¹g‖², L the Cholesky factor of JᵀJ + μI: 12 µs against an ``eigh``'s 186 µs
    at 35 parameters (float64, in a compiled loop), and this runs at every accepted step. Where
    it does not factor (rounding makes JᵀJ indefinite by more than μ), the eigendecomposition's
    truncated pseudo-inverse instead (:func:`_eigen_decrease`). ``xp``: ``jax.numpy`` (traceable)
    or ``numpy`` (on the host)."""
    if jtj.size == 0:
        return xp.zeros((), jtj.dtype)
    if free is not None:
        jtr = xp.where(free, jtr, 0)
        jtj = xp.where(free[:, None] & free[None, :], jtj, 0)
    mu = xp.max(xp.abs(xp.diag(jtj))) * _cut(jtj)
    shifted = jtj + mu * xp.eye(jtj.shape[0], dtype=jtj.dtype)
    if xp is not jnp:
        try:
            z = np.linalg.solve(np.linalg.cholesky(shifted), jtr)  # L⁻¹g (L is triangular; 35 × 35)
            dec = 0.5 * np.sum(z * z)
        except np.linalg.LinAlgError:  # not positive definite: NumPy raises where JAX gives NaN
            dec = np.nan
        return dec if np.isfinite(dec) and mu > 0 else _eigen_decrease(jtj, jtr, np)
    factor = jnp.linalg.cholesky(shifted)  # NaN where it fails
    traced = 0.5 * jnp.sum(solve_triangular(factor, jtr, lower=True) ** 2)
    return jax.lax.cond(jnp.isfinite(traced) & (mu > 0), lambda: traced, lambda: _eigen_decrease(jtj, jtr))


def _cut(jtj):
    """The relative size of an eigenvalue that JᵀJ does not determine: 10·P·ε."""
    return np.finfo(jtj.dtype).eps * jtj.shape[0] * 10


def _eigen_decrease(jtj, jtr, xp: Any = jnp):
    """½ gᵀ(JᵀJ)⁺g from the eigendecomposition, eigenvalues below :func:`_cut` of the largest left out."""
    evals, evecs = xp.linalg.eigh(jtj)
    keep = evals > xp.max(xp.abs(evals)) * _cut(jtj)
    proj = evecs.T @ jtr
    return 0.5 * xp.sum(xp.where(keep, proj**2 / xp.where(keep, evals, 1), 0))
