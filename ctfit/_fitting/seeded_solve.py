"""The solve: optimistix Levenberg–Marquardt from every seed, raced, and when a fit has converged.

Levenberg–Marquardt runs on the structured normal equations (JᵀJ from the factored Jacobian,
never the N × P matrix: :class:`~ctfit._fitting.solvers.StructuredLevenbergMarquardt`,
:func:`~ctfit._fitting.jacobian.normal_equations`) from each seed in one scan; the lowest finite
cost wins. optimistix Gauss–Newton, Dogleg (normal equations with Cholesky) or BFGS on request.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from .coordinates import bounds, flat_host
from .jacobian import half_squared_norm, normal_equations, residual
from .problem import Problem
from .stationarity import cost_scale, predicted_decrease

if TYPE_CHECKING:
    from .solvers import StructuredLevenbergMarquardt

# optimistix, lineax and the solvers built on them are imported where a program is traced, not
# here: a fit whose compiled programs all come from the store never imports them (0.15 s of a
# whole process; :mod:`ctfit._runtime.stored_programs`).

__all__ = ["SOLVERS", "STATIONARY_TOLERANCE", "explains_none", "flat_bounds", "solve_seeds", "gauss_newton_decrease", "lm_solver", "stop_tolerances",
           "RACE_STEPS", "RACE_MARGIN"]

SOLVERS = ("lm", "gauss-newton", "dogleg", "bfgs")


def _solver(name: str, dtype):
    import lineax as lx
    import optimistix as optx

    rtol, atol = (1e-8, 1e-12) if dtype == jnp.float64 else (1e-5, 1e-8)
    if name == "lm":
        return optx.LevenbergMarquardt(rtol=rtol, atol=atol, linear_solver=lx.Normal(lx.Cholesky()))
    if name == "gauss-newton":
        return optx.GaussNewton(rtol=rtol, atol=atol, linear_solver=lx.Normal(lx.Cholesky()))
    if name == "dogleg":
        return optx.Dogleg(rtol=rtol, atol=atol, linear_solver=lx.Normal(lx.Cholesky()))
    if name == "bfgs":
        return optx.BFGS(rtol=rtol, atol=atol)
    raise ValueError(f"solver must be one of {SOLVERS}, got {name!r}")


def _gauss_newton(flat, data):
    """Jᵀr and JᵀJ at the flat free values (one pass of the structured normal equations)."""
    problem, unravel = data
    return normal_equations(problem, unravel(flat))[1:]


def _half_squared_norm(flat, data):
    problem, unravel = data
    return half_squared_norm(problem, unravel(flat))


STATIONARY_TOLERANCE = {"float64": 1e-6, "float32": 1e-3}
"""``converged`` needs one more Gauss–Newton step to promise less than this relative decrease
of the cost: the solver's own tests (small steps, small changes) also pass where it has stalled,
e.g. float32 rounding making every step look useless far from the minimum."""


NO_SIGNAL = 0.99
"""A fit whose cost is at least this fraction of the cost of a model that is 0 everywhere has not
converged, even at a stationary point: it describes none of the data (a lobe far from the
samples, F0 → 0)."""


def explains_none(cost, zero_cost):
    """Whether a fit's cost is at least ``NO_SIGNAL`` of a zero model's (arrays or scalars)."""
    return (np.asarray(zero_cost) > 0) & (np.asarray(cost) >= NO_SIGNAL * np.asarray(zero_cost))


RACE_STEPS = 4
"""Levenberg–Marquardt steps every seed gets in the first phase (``_structured_lm``)."""


RACE_MARGIN = float("inf")
"""A seed goes on after the first phase if its cost is within this factor of the lowest. Every
seed goes on (∞): cutting at 1.5× after 4 (or 8) steps kept wrong basins — an absolute-loss fit
whose right seed was 20× behind after 4 steps (docs/fitting-tradeoffs.md), grazing-only data
and n crossing 1 with 8 (docs/stability.md); the best of the converged seeds is kept."""


def flat_bounds(problem: Problem, u: dict, xp=jnp):
    """The box bounds of the free coordinates, flattened as ``ravel_pytree(u)`` orders them;
    ``xp``: ``jax.numpy`` (traceable) or ``numpy`` (on the host, :func:`~ctfit._fitting.coordinates.flat_host`)."""
    flat = (lambda tree: ravel_pytree(tree)[0]) if xp is jnp else flat_host
    lower, upper = bounds(problem.spec, u)
    return flat(lower), flat(upper)


def _with_aux(flat, data):
    return _half_squared_norm(flat, data), None


def _run_solver(solver, y0, data, budget, paused=None):
    """optimistix's iteration (``solver.init``, then ``step`` until ``terminate``) for at most
    ``budget`` steps — a *traced* count, so one compiled loop serves every phase of the race.
    ``paused``: (whether, state) — where ``whether`` (traced), go on with the solve whose state
    (the array leaves of the solver's state) a run from ``y0`` on the same data returned, instead
    of starting one. Returns (value, converged, steps, sound, state, (½‖r‖², Jᵀr, JᵀJ) at the
    value): the solver holds the last accepted point's cost and normal equations, so the caller
    needs no pass of its own for them (only after a step: before one they are zeros)."""
    import equinox as eqx  # (with optimistix: a fit whose programs are stored imports neither)
    import optimistix as optx

    f_struct = jax.ShapeDtypeStruct((), y0.dtype)
    dynamic, static = eqx.partition(solver.init(_with_aux, y0, data, {}, f_struct, None, frozenset()), eqx.is_array)
    if paused is not None:
        dynamic = jax.tree.map(lambda a, b: jnp.where(paused[0], b, a), dynamic, paused[1])

    def stop_and_result(y, st):
        done, result = solver.terminate(_with_aux, y, data, {}, st, frozenset())
        return done, optx.RESULTS.where(jnp.all(jnp.isfinite(y)), result, optx.RESULTS.nonfinite)

    done, result = stop_and_result(y0, eqx.combine(static, dynamic))

    def cond(carry):
        _, k, _, done, result = carry
        return ~done & (result == optx.RESULTS.successful) & (k < budget)

    def body(carry):
        y, k, dyn, _, _ = carry
        st = eqx.combine(static, dyn)
        y, st, _ = solver.step(_with_aux, y, data, {}, st, frozenset())
        done, result = stop_and_result(y, st)
        return y, k + 1, eqx.partition(st, eqx.is_array)[0], done, result

    y, k, dynamic, done, result = jax.lax.while_loop(cond, body, (y0, jnp.zeros((), jnp.int32), dynamic, done, result))
    sound = result == optx.RESULTS.successful  # no numerical failure (a spent budget is none)
    info = eqx.combine(static, dynamic).f_info  # at y, the last accepted point (after a step at least)
    return y, done & sound, k, sound, dynamic, (info.f, info.grad, info.hessian.as_matrix())


def stop_tolerances(dtype, tolerance: float | None = None) -> tuple[float, float]:
    """(stol, gtol) of :class:`~ctfit._fitting.solvers.StructuredLevenbergMarquardt`: by default
    :data:`STATIONARY_TOLERANCE` and a thousandth of it; with ``tolerance``, stop wherever one more
    Gauss–Newton step promises less than that relative decrease (both ``tolerance``)."""
    if tolerance is not None:
        return tolerance, tolerance
    tol = STATIONARY_TOLERANCE[jnp.dtype(dtype).name]
    return tol, tol * 1e-3


def lm_solver(dtype, lower, upper, data, gauss_newton, stol=None, gtol=None, zero_cost=0.0) -> StructuredLevenbergMarquardt:
    """The fit's projected Levenberg–Marquardt (tolerances of ``dtype``) in the box [lower, upper];
    ``gauss_newton(flat, data)`` gives Jᵀr and JᵀJ. ``stol``, ``gtol`` (scalars, may be traced):
    by default :func:`stop_tolerances`'. ``zero_cost`` (may be traced): the cost of a model that is
    0 everywhere, below ε times which a cost is rounding (the stopping tests' scale, as
    :func:`gauss_newton_decrease`'s): an exact fit stops, where it ran to the step limit."""
    from .solvers import ProjectedDampedNewtonDescent, StructuredLevenbergMarquardt

    rtol, atol = (1e-8, 1e-12) if dtype == jnp.float64 else (1e-5, 1e-8)
    descent = ProjectedDampedNewtonDescent(lower=lower, upper=upper)
    if stol is None or gtol is None:
        stol, gtol = stop_tolerances(dtype)
    return StructuredLevenbergMarquardt(rtol=rtol, atol=atol, data=data, gauss_newton=gauss_newton, descent=descent, gtol=gtol, stol=stol,
                                        zero_cost=zero_cost)


def _structured_lm(problem: Problem, seeds: dict, max_steps: int, zero_cost=0.0):
    """optimistix Levenberg–Marquardt on the structured normal equations, the seeds raced.

    Every seed gets ``RACE_STEPS`` steps; the seeds whose cost is then within ``RACE_MARGIN``
    of the lowest go on to convergence (their solves resumed: the solver's state, its damping
    included, carried over, so a seed takes the steps of one solve), unless converged already.
    The others keep their cost after the race, so they can only lose. With one seed this is a
    plain solve. Both phases are one scan over (seed, phase) tasks around *one* instance of the
    solver loop, which keeps the compiled program small.
    """
    import equinox as eqx

    flat_seeds = jax.vmap(lambda s: ravel_pytree(s)[0])(seeds)
    unravel = ravel_pytree(jax.tree.map(lambda a: a[0], seeds))[1]
    data = (problem, jax.tree_util.Partial(unravel))
    lower, upper = flat_bounds(problem, jax.tree.map(lambda a: a[0], seeds))
    solver = lm_solver(flat_seeds.dtype, lower, upper, data, _gauss_newton, zero_cost=zero_cost)
    n = flat_seeds.shape[0]
    race = n > 1 and max_steps > RACE_STEPS
    tasks = jnp.arange(2 * n if race else n)
    f_struct = jax.ShapeDtypeStruct((), flat_seeds.dtype)
    template = eqx.filter(solver.init(_with_aux, flat_seeds[0], data, {}, f_struct, None, frozenset()), eqx.is_array)
    no_states = jax.tree.map(lambda a: jnp.zeros((n, *a.shape), a.dtype), template)

    def task(carry, i):
        values, ok, steps, costs, sound, states, normal = carry
        j = i % n
        if race:
            second = i >= n
            go = ~ok[j] & (costs[j] <= RACE_MARGIN * jnp.min(costs))
            budget = jnp.where(second, jnp.where(go, max_steps - RACE_STEPS, 0), RACE_STEPS)
            paused = (second & sound[j], jax.tree.map(lambda a: a[j], states))
        else:
            budget, paused = jnp.asarray(max_steps), None
        v, o, k, fine, state, at_v = _run_solver(solver, values[j], data, budget, paused)
        c = at_v[0]
        keep = k > 0  # a seed that did not go on keeps what it had
        values = values.at[j].set(jnp.where(keep, v, values[j]))
        ok = ok.at[j].set(jnp.where(keep, o, ok[j]))
        sound = sound.at[j].set(jnp.where(keep, fine, sound[j]))
        costs = costs.at[j].set(jnp.where(keep, jnp.where(jnp.isfinite(c), c, jnp.inf), costs[j]))
        states = jax.tree.map(lambda a, b: a.at[j].set(jnp.where(keep, b, a[j])), states, state)
        normal = jax.tree.map(lambda a, b: a.at[j].set(jnp.where(keep, b, a[j])), normal, at_v[1:])
        return (values, ok, steps.at[j].add(k), costs, sound, states, normal), None

    p = flat_seeds.shape[1]
    no_normal = (jnp.zeros((n, p), flat_seeds.dtype), jnp.zeros((n, p, p), flat_seeds.dtype))
    init = (flat_seeds, jnp.zeros(n, bool), jnp.zeros(n, jnp.int32), jnp.full(n, jnp.inf, flat_seeds.dtype), jnp.ones(n, bool), no_states, no_normal)
    (values, ok, steps, costs, sound, _, normal), _ = jax.lax.scan(task, init, tasks)
    # Reported per seed: no numerical failure. Whether the point is a minimum is judged after the
    # solve, by first-order optimality on the free variables (``STATIONARY_TOLERANCE``), so a
    # stationary point reached at the step limit (a flat valley the data does not determine) counts.
    return jax.vmap(unravel)(values), sound, steps, costs, normal


def solve_seeds(problem: Problem, seeds: dict, solver_name: str, max_steps: int, zero_cost=0.0):
    """Every seed; values, success flags, steps and final costs per seed, and (Levenberg–Marquardt)
    the flat Jᵀr and JᵀJ there per seed ((seeds, P), (seeds, P, P); valid where a seed took a
    step), else None. ``zero_cost``: the cost of a zero model over ``problem``, Levenberg–Marquardt's
    stopping scale (:func:`lm_solver`)."""
    import optimistix as optx

    if solver_name == "lm":
        return _structured_lm(problem, seeds, max_steps, zero_cost)
    solver = _solver(solver_name, problem.y.dtype)

    def one(u0):
        sol: optx.Solution
        if solver_name == "bfgs":
            fn = lambda u, a: 0.5 * jnp.sum(residual(u, a) ** 2)
            sol = optx.minimise(fn, solver, u0, (problem.y, problem), max_steps=max_steps, throw=False)
        else:
            sol = optx.least_squares(residual, solver, u0, (problem.y, problem), max_steps=max_steps, throw=False)
        r = residual(sol.value, (problem.y, problem))
        sound = (sol.result == optx.RESULTS.successful) | (sol.result == optx.RESULTS.nonlinear_max_steps_reached)
        return sol.value, sound, sol.stats["num_steps"], 0.5 * jnp.sum(r * r)

    return (*jax.vmap(one)(seeds), None)


def gauss_newton_decrease(jtj, jtr, cost, scale, xp=jnp, dec=None):
    """Relative decrease of ½‖r‖² that one Gauss–Newton step from here predicts,
    ½ gᵀ(JᵀJ)⁺g / max(cost, ε·scale), with ``scale`` the cost of a zero model (so that an exact
    fit, cost → 0, does not divide rounding by rounding).

    Zero at a minimum (g = Jᵀr = 0). Directions the data does not determine (tiny eigenvalues
    of JᵀJ, relative to the largest, below the dtype's rounding) are left out, so a degenerate
    but stationary point still reads as stationary. ``xp``: ``jax.numpy`` (traceable) or ``numpy``
    (on the host). ``dec``: the decrease itself, computed by the caller (a projected step's,
    :func:`~ctfit._fitting.stationarity.stationary_decrease`), made relative here.
    """
    dec = predicted_decrease(jtj, jtr, xp=xp) if dec is None else dec
    return dec / cost_scale(cost, scale, xp)
