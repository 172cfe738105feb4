"""Least-squares fit of the Cook–Torrance parameters to BRDF samples, with optimistix.

``fit(data, structure, ...)`` → :class:`FitResult`. Steps:

1. Starting points: a grid over the rms slopes (one value per lobe, ascending), each scored
   by the loss after the best per-band amplitude (a linear least-squares problem) — one
   vmapped pass over the data. The best ``starts`` grid points seed the solver.
2. optimistix Levenberg–Marquardt from each seed in turn (``jax.lax.map``), with the
   Gauss–Newton matrix JᵀJ formed from the factored Jacobian, never the N × P matrix
   (:class:`~ctfit._fitting.solvers.StructuredLevenbergMarquardt`, :func:`~ctfit._fitting.problem.normal_equations`);
   the lowest finite cost wins. optimistix Gauss–Newton, Dogleg (normal equations with
   Cholesky) or BFGS on request; float64 unless float32 is asked for. Seeding, solve and everything the report
   needs are one compiled program (``fit_core``), so a run compiles once; where JAX's
   persistent cache is enabled the executable itself is kept on disk (``_runtime/stored_programs.py``), so a new
   process with the same structure, data shape and options skips tracing and compiling.
3. Standard errors from (JᵀJ)⁻¹ at the optimum (scaled by the residual variance unless the
   loss is sigma-weighted), mapped to the constrained parameters by the delta method, reported
   only where JᵀJ is well conditioned. Near-degenerate solutions are detected and reported.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jax.flatten_util import ravel_pytree

from .._runtime import cached_call
from .._model import normal_reflectance
from .diagnostics import relative_residual_structure
from .._model import Material, Measurement, Params, Structure, f0_from_nk, n_from_f0, parameter
from .solvers import (
    ProjectedDampedNewtonDescent,
    StructuredLevenbergMarquardt,
    active_set,
    predicted_decrease,
)
from .validate import check_fittable, n_free_parameters, nonfinite_reason
from .problem import (
    LOSSES,
    Problem,
    loss_residuals,
    bounds,
    from_params,
    chunk_count,
    half_squared_norm,
    make_problem,
    map_over_chunks,
    model_values,
    normal_equations,
    residual,
    sum_over_chunks,
    to_params,
)

__all__ = ["fit", "FitResult", "SOLVERS", "select_structure", "constrained_quantities", "standard_errors", "undetermined"]

SOLVERS = ("lm", "gauss-newton", "dogleg", "bfgs")
_PARAM_FIELDS = ("s", "m", "w", "f0", "n", "k", "rd")


def _solver(name: str, dtype):
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


@dataclasses.dataclass
class FitResult:
    """A fitted material and how the fit went.

    ``material`` is a full :class:`~ctfit.Material` (usable by every command); ``stats`` holds
    converged, steps, cost, rmse, rel_rmse, time_s, n_samples, n_params, bic; ``stderr`` the
    standard errors of s, m, weight, F0, n, k, R_d (None where not computed); ``warnings``
    plain-language notes on degenerate or suspicious solutions.
    """

    material: Material
    stats: dict
    stderr: dict | None
    warnings: list[str]
    loss: str
    solver: str

    @property
    def converged(self) -> bool:
        return bool(self.stats["converged"])

    @property
    def parameters(self) -> dict:
        """The fitted values under their public names, laid out as in the fit JSON (``s``,
        ``lobes`` [{``m``, ``weight``}], ``F0``, ``n``, ``k``, ``Rd``; lobes in ascending m), the
        same keys and layout as :attr:`parameter_errors`."""
        from .._io import material_to_dict

        doc = material_to_dict(self.material)
        keys = ("s", "lobes", "F0", "n", "k") + (("Rd",) if self.material.structure.diffuse in ("spectrum", "constant") else ())  # R_d = F0/π is not fitted
        return {k: doc[k] for k in keys if k in doc}

    @property
    def parameter_errors(self) -> dict | None:
        """Standard errors of :attr:`parameters`, same keys and layout (NaN where a value has none,
        e.g. on a bound); None when JᵀJ could not be inverted."""
        from .results import stderr_block

        return stderr_block(self)


def _default_start(structure: Structure, data: Measurement) -> Params:
    nb = data.n_bands
    j = structure.lobes
    return Params(
        s=np.asarray(0.5) if structure.has_s else None,
        m=np.geomspace(0.1, 0.3, j) if j else None,
        w=np.full(j, 1.0 / j) if j else None,
        f0=np.full(nb, 0.5) if structure.fresnel == "f0" and structure.needs_fresnel_params else None,
        n=np.full(nb, 1.5) if structure.fresnel != "f0" and structure.needs_fresnel_params else None,
        k=np.full(nb, 2.0) if structure.fresnel == "conductor" and structure.needs_fresnel_params else None,
        rd=(np.full(nb, 0.05) if structure.diffuse == "spectrum" else (np.asarray(0.05) if structure.diffuse == "constant" else None)),
    )


def _m_grid(lobes: int, diffuse: bool = True) -> np.ndarray:
    """The grid of m the seeds are scored on. One lobe: 16 points 0.005–1, and without a diffuse
    part 5 more down to 10⁻⁴ for mirror-like lobes (seen in their tails or sampled closely). With
    a diffuse part those would be traps: a lobe that reaches no sample fits like s = 0."""
    if lobes == 1:
        grid = np.geomspace(0.005, 1.0, 16)
        return (grid if diffuse else np.concatenate([np.geomspace(1e-4, 0.005, 6)[:-1], grid]))[:, None]
    base = {2: np.geomspace(0.01, 0.8, 9), 3: np.geomspace(0.01, 0.8, 7)}.get(lobes, np.geomspace(0.01, 0.8, 5))
    return np.array(list(itertools.combinations(base, lobes)))


@eqx.filter_jit
def _score_grid(problem: Problem, u0: dict, grid):
    """Loss of each grid point of log m after the best per-band amplitude (weighted linear LS):
    the per-band scale Σ w v y / Σ w v², then Σ w (scale · v − y)² — two passes, chunk by chunk,
    on a large grid (:func:`~ctfit._fitting.problem.sum_over_chunks`), one pass otherwise."""

    def band_sum(part, t):
        return jnp.sum(t, axis=0) if part.spec.grid else jax.ops.segment_sum(t, part.band, num_segments=part.fixed_bands)

    def weighted(part, log_m):
        v = model_values(part, dict(u0, m=log_m))
        return v, part.mask / jnp.maximum(jnp.abs(part.y), part.floor) ** 2

    def scale_of(num, den):
        return num / jnp.maximum(den, 1e-300)

    def cost_of(part, log_m, scale, v=None, wgt=None):
        if v is None:
            v, wgt = weighted(part, log_m)
        per_sample = scale if part.spec.grid else scale[part.band]
        return jnp.sum(wgt * (per_sample * v - part.y) ** 2)

    def score(log_m):
        if chunk_count(problem) == 1:
            v, wgt = weighted(problem, log_m)
            scale = scale_of(band_sum(problem, wgt * v * problem.y), band_sum(problem, wgt * v * v))
            cost = cost_of(problem, log_m, scale, v, wgt)
        else:
            def sums(part):
                v, wgt = weighted(part, log_m)
                return band_sum(part, wgt * v * part.y), band_sum(part, wgt * v * v)

            scale = scale_of(*sum_over_chunks(problem, sums))
            cost = sum_over_chunks(problem, lambda part: cost_of(part, log_m, scale))
        return jnp.where(jnp.isfinite(cost), cost, jnp.inf), scale

    return jax.lax.map(score, grid)  # one grid point at a time: memory O(N), not O(grid × N)


def _seed_points(problem: Problem, u0: dict, k: int, grid=None, keep_start: bool = False) -> dict:
    """The ``k`` best distinct starting points from a grid over log m, each with its best per-band scale
    (F0 scaled; for n, k: the index of the scaled normal reflectance, :func:`_index_seed`), and
    with ``keep_start`` the start ``u0`` itself as one more seed.

    Traceable (used inside the jitted fit); ``grid`` is the (G, lobes) grid of log m.
    """
    if "m" not in u0 or k < 1 or grid is None:
        return jax.tree.map(lambda a: jnp.asarray(a)[None], u0)
    costs, scales = _score_grid(problem, u0, grid)
    order = jnp.argsort(costs)
    # Grid points that score the same give the same model (lobes too narrow to reach any
    # sample all look like no lobe): one of each goes first, so the k seeds differ.
    c = costs[order]
    same = jnp.concatenate([jnp.zeros((1,), bool), jnp.abs(c[1:] - c[:-1]) <= 1e-3 * jnp.abs(c[1:])])
    order = order[jnp.argsort(same, stable=True)][: min(k, grid.shape[0])]
    seeds = dict(jax.tree.map(lambda a: jnp.broadcast_to(a, (order.shape[0],) + jnp.shape(a)), u0))
    seeds["m"] = grid[order]
    if "f0" in u0:
        seeds["f0"] = jnp.clip(u0["f0"] * scales[order], 0.005, 0.995)
    elif "n" in u0:
        k0 = u0.get("k", jnp.zeros_like(u0["n"]))
        f0 = jnp.clip(f0_from_nk(u0["n"], k0) * scales[order], 1e-4, 0.995)
        n, kk = _index_seed(f0, jnp.broadcast_to(u0["n"], f0.shape), problem.spec.structure.fresnel == "conductor")
        seeds["n"] = n
        if "k" in u0:
            seeds["k"] = kk
    if keep_start:
        seeds = jax.tree.map(lambda a, b: jnp.concatenate([a, jnp.asarray(b)[None]]), seeds, u0)
    return seeds


def _index_seed(f0, n, conductor: bool):
    """n, k whose normal reflectance is ``f0``: for a conductor, n kept and k from
    F0 = ((n−1)² + k²)/((n+1)² + k²) where that has a root, else k = 0 and the dielectric n of
    F0 (paper §4); for a real index, that n alone."""
    n_diel = n_from_f0(f0)
    if not conductor:
        return n_diel, None
    k2 = (f0 * (n + 1) ** 2 - (n - 1) ** 2) / (1 - f0)
    has_k = k2 > 0
    return jnp.where(has_k, n, n_diel), jnp.sqrt(jnp.where(has_k, k2, 0.0))


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


def judge_converged(ok, finite, gn_decrease, cost, zero_cost, dtype):
    """``converged`` of one fit or of many (arrays): no numerical failure, finite, stationary
    (``STATIONARY_TOLERANCE``) and describing some of the data (:func:`explains_none`)."""
    stationary = np.asarray(gn_decrease) <= STATIONARY_TOLERANCE[jnp.dtype(dtype).name]
    return np.asarray(ok, bool) & np.asarray(finite, bool) & stationary & ~explains_none(cost, zero_cost)


RACE_STEPS = 4
"""Levenberg–Marquardt steps every seed gets in the first phase (``_structured_lm``)."""
RACE_MARGIN = float("inf")
"""A seed goes on after the first phase if its cost is within this factor of the lowest. Every
seed goes on (∞): cutting at 1.5× after 4 (or 8) steps kept wrong basins — an absolute-loss fit
whose right seed was 20× behind after 4 steps (docs/fitting-tradeoffs.md), grazing-only data
and n crossing 1 with 8 (docs/stability.md); the best of the converged seeds is kept."""


def _flat_bounds(problem: Problem, u: dict):
    """The box bounds of the free coordinates, flattened as ``ravel_pytree(u)`` orders them."""
    lower, upper = bounds(problem.spec, u)
    return ravel_pytree(lower)[0], ravel_pytree(upper)[0]


def _with_aux(flat, data):
    return _half_squared_norm(flat, data), None


def _run_solver(solver, y0, data, budget):
    """optimistix's iteration (``solver.init``, then ``step`` until ``terminate``) for at most
    ``budget`` steps — a *traced* count, so one compiled loop serves every phase of the race.
    Returns (value, converged, steps); the solver's own tests decide ``converged``."""
    f_struct = jax.ShapeDtypeStruct((), y0.dtype)
    state = solver.init(_with_aux, y0, data, {}, f_struct, None, frozenset())
    dynamic, static = eqx.partition(state, eqx.is_array)

    def stop_and_result(y, st):
        done, result = solver.terminate(_with_aux, y, data, {}, st, frozenset())
        return done, optx.RESULTS.where(jnp.all(jnp.isfinite(y)), result, optx.RESULTS.nonfinite)

    done, result = stop_and_result(y0, state)

    def cond(carry):
        _, k, _, done, result = carry
        return ~done & (result == optx.RESULTS.successful) & (k < budget)

    def body(carry):
        y, k, dyn, _, _ = carry
        st = eqx.combine(static, dyn)
        y, st, _ = solver.step(_with_aux, y, data, {}, st, frozenset())
        done, result = stop_and_result(y, st)
        return y, k + 1, eqx.partition(st, eqx.is_array)[0], done, result

    y, k, _, done, result = jax.lax.while_loop(cond, body, (y0, jnp.zeros((), jnp.int32), dynamic, done, result))
    sound = result == optx.RESULTS.successful  # no numerical failure (a spent budget is none)
    return y, done & sound, k, sound


def _structured_lm(problem: Problem, seeds: dict, max_steps: int):
    """optimistix Levenberg–Marquardt on the structured normal equations, the seeds raced.

    Every seed gets ``RACE_STEPS`` steps; the seeds whose cost is then within ``RACE_MARGIN``
    of the lowest go on to convergence (a fresh solve from where they stopped, unless converged
    already). The others keep their cost after the race, so they can only lose. With one seed
    this is a plain solve. Both phases are one scan over (seed, phase) tasks around *one*
    instance of the solver loop, which keeps the compiled program small.
    """
    flat_seeds = jax.vmap(lambda s: ravel_pytree(s)[0])(seeds)
    unravel = ravel_pytree(jax.tree.map(lambda a: a[0], seeds))[1]
    rtol, atol = (1e-8, 1e-12) if flat_seeds.dtype == jnp.float64 else (1e-5, 1e-8)
    data = (problem, jax.tree_util.Partial(unravel))
    lower, upper = _flat_bounds(problem, jax.tree.map(lambda a: a[0], seeds))
    descent = ProjectedDampedNewtonDescent(lower=lower, upper=upper)
    gtol = STATIONARY_TOLERANCE[flat_seeds.dtype.name] * 1e-3
    solver = StructuredLevenbergMarquardt(rtol=rtol, atol=atol, data=data, gauss_newton=_gauss_newton, descent=descent, gtol=gtol,
                                          stol=STATIONARY_TOLERANCE[flat_seeds.dtype.name])
    n = flat_seeds.shape[0]
    race = n > 1 and max_steps > RACE_STEPS
    tasks = jnp.arange(2 * n if race else n)

    def task(carry, i):
        values, ok, steps, costs, sound = carry
        j = i % n
        if race:
            second = i >= n
            go = ~ok[j] & (costs[j] <= RACE_MARGIN * jnp.min(costs))
            budget = jnp.where(second, jnp.where(go, max_steps - RACE_STEPS, 0), RACE_STEPS)
        else:
            budget = jnp.asarray(max_steps)
        v, o, k, fine = _run_solver(solver, values[j], data, budget)
        c = _half_squared_norm(v, data)
        keep = k > 0  # a seed that did not go on keeps what it had
        values = values.at[j].set(jnp.where(keep, v, values[j]))
        ok = ok.at[j].set(jnp.where(keep, o, ok[j]))
        sound = sound.at[j].set(jnp.where(keep, fine, sound[j]))
        costs = costs.at[j].set(jnp.where(keep, jnp.where(jnp.isfinite(c), c, jnp.inf), costs[j]))
        return (values, ok, steps.at[j].add(k), costs, sound), None

    init = (flat_seeds, jnp.zeros(n, bool), jnp.zeros(n, jnp.int32), jnp.full(n, jnp.inf, flat_seeds.dtype), jnp.ones(n, bool))
    (values, ok, steps, costs, sound), _ = jax.lax.scan(task, init, tasks)
    # Reported per seed: no numerical failure. Whether the point is a minimum is judged after the
    # solve, by first-order optimality on the free variables (``STATIONARY_TOLERANCE``), so a
    # stationary point reached at the step limit (a flat valley the data does not determine) counts.
    return jax.vmap(unravel)(values), sound, steps, costs


def _solve_seeds(problem: Problem, seeds: dict, solver_name: str, max_steps: int):
    """Every seed; values, success flags, steps and final costs per seed."""
    if solver_name == "lm":
        return _structured_lm(problem, seeds, max_steps)
    solver = _solver(solver_name, problem.y.dtype)

    def one(u0):
        if solver_name == "bfgs":
            fn = lambda u, a: 0.5 * jnp.sum(residual(u, a) ** 2)  # noqa: E731
            sol = optx.minimise(fn, solver, u0, (problem.y, problem), max_steps=max_steps, throw=False)
        else:
            sol = optx.least_squares(residual, solver, u0, (problem.y, problem), max_steps=max_steps, throw=False)
        r = residual(sol.value, (problem.y, problem))
        sound = (sol.result == optx.RESULTS.successful) | (sol.result == optx.RESULTS.nonlinear_max_steps_reached)
        return sol.value, sound, sol.stats["num_steps"], 0.5 * jnp.sum(r * r)

    return jax.vmap(one)(seeds)


def _gauss_newton_decrease(jtj, jtr, cost, scale):
    """Relative decrease of ½‖r‖² that one Gauss–Newton step from here predicts,
    ½ gᵀ(JᵀJ)⁺g / max(cost, ε·scale), with ``scale`` the cost of a zero model (so that an exact
    fit, cost → 0, does not divide rounding by rounding).

    Zero at a minimum (g = Jᵀr = 0). Directions the data does not determine (tiny eigenvalues
    of JᵀJ, relative to the largest, below the dtype's rounding) are left out, so a degenerate
    but stationary point still reads as stationary.
    """
    dec = predicted_decrease(jtj, jtr)
    eps = jnp.finfo(cost.dtype).eps
    return dec / jnp.maximum(cost, jnp.maximum(eps * scale, jnp.finfo(cost.dtype).tiny))


def _effective_index(f0):
    """The paper's effective index of a fitted F0, finite where F0 rounds to 1 (about 10¹⁶ in
    float64, 10⁸ in float32, instead of :func:`~ctfit._model.fresnel_equations.n_from_f0`'s infinity)."""
    f0 = jnp.asarray(f0)
    return n_from_f0(jnp.minimum(f0, 1 - jnp.finfo(f0.dtype).eps))


def constrained_quantities(problem: Problem, unravel, f):
    """The reported (constrained) parameters as a dict, from the flat free values."""
    spec = problem.spec
    p = to_params(spec, unravel(f), problem.fixed)
    f0 = normal_reflectance(spec.structure, p) if spec.structure.needs_fresnel_params else None
    out = {k: getattr(p, k) for k in ("s", "m", "w", "n", "k", "rd") if getattr(p, k) is not None}
    if f0 is not None:
        out["F0"] = f0
        if spec.structure.fresnel == "f0":
            out["n"] = _effective_index(f0)
    return out


def fit_core(problem: Problem, u0: dict, grid, starts: int, solver_name: str, max_steps: int, keep_start: bool = False):
    """Seeds, solve, pick the best, and everything the report needs, in one compiled program.
    ``keep_start``: the start ``u0`` is a seed too (a start the caller chose)."""
    seeds = _seed_points(problem, u0, starts, grid, keep_start)
    values, ok, steps, costs = _solve_seeds(problem, seeds, solver_name, max_steps)
    costs = jnp.where(jnp.isfinite(costs), costs, jnp.inf)
    best = jnp.argmin(costs)
    u = jax.tree.map(lambda a: a[best], values)
    cost, jtr, jtj = normal_equations(problem, u)
    flat, unravel = ravel_pytree(u)
    lower, upper = _flat_bounds(problem, u)
    on_bound = active_set(flat, jtr, lower, upper)  # held on a bound: a result, not a failure
    keep = ~on_bound
    jtr = jnp.where(keep, jtr, 0)
    jtj = jnp.where(keep[:, None] & keep[None, :], jtj, 0)
    jt = jax.jacfwd(lambda f: constrained_quantities(problem, unravel, f))(flat) if flat.size else None
    params = to_params(problem.spec, u, problem.fixed)
    params = {k: getattr(params, k) for k in _PARAM_FIELDS}  # plain containers: the executable's output is stored (_runtime/stored_programs.py)
    if problem.spec.structure.needs_fresnel_params and problem.spec.structure.fresnel == "f0":
        params["n"] = _effective_index(params["f0"])  # reported beside F0
    zero_cost = sum_over_chunks(problem, lambda part: 0.5 * jnp.sum(loss_residuals(part, jnp.zeros_like(part.y), part.y) ** 2))  # the cost of a model that is 0
    return dict(u=u, ok=ok, steps=steps, costs=costs, best=best, jtj=jtj, on_bound=on_bound, gn_decrease=_gauss_newton_decrease(jtj, jtr, cost, zero_cost),
                zero_cost=zero_cost, jt=jt, params=params, **_residual_summary(problem, u))


def _residual_summary(problem: Problem, u: dict) -> dict:
    """What the report needs of the model at ``u``, chunk by chunk on a large problem
    (:func:`~ctfit._fitting.problem.map_over_chunks`): the relative residuals ``rel``, stacked by chunk
    (the host reshapes them to the problem's layout; 0 where nothing is measured; float32, for
    the residual diagnostics), ``rmse`` and ``rel_rmse`` (as max|e| · rms(e / max|e|), so that
    squares cannot overflow), and ``bad``, how many measured cells have a model value that is
    not finite."""

    def one(part):
        pred = model_values(part, u)
        err = jnp.where(part.mask, pred - part.y, 0)
        rel = err / jnp.maximum(jnp.abs(part.y), part.floor)
        stats = [_scaled_squares(e) for e in (err, rel)]
        big = jnp.asarray(jnp.finfo(jnp.float32).max, rel.dtype)
        return jnp.clip(rel, -big, big).astype(jnp.float32), stats, jnp.sum(part.mask & ~jnp.isfinite(pred))

    rel, stats, bad = map_over_chunks(problem, one)
    n = jnp.maximum(jnp.sum(problem.mask), 1)
    rmse, rel_rmse = (_combined_rms(big, sq, n) for big, sq in stats)
    return dict(rel=rel, rmse=rmse, rel_rmse=rel_rmse, bad=jnp.sum(bad))  # rel reshaped on the host: no copy


def _scaled_squares(e):
    """(max|e|, Σ (e / max|e|)²) of one chunk."""
    big = jnp.max(jnp.abs(e))
    return big, jnp.sum((e / jnp.where(big > 0, big, 1)) ** 2)


def _combined_rms(big, sq, n):
    """The rms of all chunks from their (max|e|, Σ (e / max|e|)²): rescaled to the largest max."""
    top = jnp.max(big)
    safe = jnp.where(top > 0, top, 1)
    return jnp.where(top == 0, jnp.zeros((), big.dtype), top * jnp.sqrt(jnp.sum(sq * (big / safe) ** 2) / n))  # NaN stays NaN


def _sorted_lobes(params: Params) -> tuple[Params, np.ndarray | None]:
    if params.m is None:
        return params, None
    order = np.argsort(np.asarray(params.m))
    return dataclasses.replace(params, m=np.asarray(params.m)[order], w=np.asarray(params.w)[order]), order


def standard_errors(jtj, jt: dict | None, scale2: float, order, free=None) -> dict | None:
    """Standard errors of the constrained parameters from JᵀJ and their Jacobian ``jt``.

    Only the ``free`` coordinates enter (not those held on a bound, nor those the data does not
    determine); a parameter that depends on no free coordinate gets NaN: it has no standard
    error (a bound that holds is the result)."""
    jtj = np.asarray(jtj)
    if jtj.size == 0 or jt is None:
        return None
    free = np.ones(jtj.shape[0], bool) if free is None else np.asarray(free, bool)
    sub = jtj[np.ix_(free, free)]
    if sub.size:
        try:
            cond = np.linalg.cond(sub)
        except np.linalg.LinAlgError:
            return None
        if not np.isfinite(cond) or cond > 1e12:
            return None
    cov_u = np.zeros_like(jtj)
    if sub.size:
        cov_u[np.ix_(free, free)] = np.linalg.inv(sub) * scale2
    se = {}
    for k, jk in jt.items():
        jk = np.asarray(jk).reshape(-1, jtj.shape[0])
        var = np.einsum("ij,jk,ik->i", jk, cov_u, jk)
        v = np.sqrt(np.maximum(var, 0))
        v = np.where(np.any(jk[:, ~free] != 0, axis=1) & ~np.any(jk[:, free] != 0, axis=1), np.nan, v)
        if k in ("m", "w") and order is not None:
            v = v[order]
        se[k] = v
    return {("weight" if k == "w" else k): v for k, v in se.items()}


def undetermined(jtj) -> np.ndarray:
    """Coordinates the data does not constrain at all: their row of JᵀJ is zero (to rounding,
    relative to the largest diagonal entry), e.g. R_d when s = 1 or the m of a lobe of weight 0."""
    d = np.abs(np.diag(np.asarray(jtj)))
    return d <= np.finfo(np.asarray(jtj).dtype).eps * 1e-2 * (np.max(d) if d.size else 0.0)


def _labelled(u: dict, flags) -> list[str]:
    """Public labels ("s", "F0[2]", "weight[1]") of the flat coordinates where ``flags`` is set."""
    out, i = [], 0
    for k in sorted(u):
        size = int(np.size(u[k]))
        for j in range(size):
            if flags[i]:
                out.append(parameter(k).public + (f"[{j}]" if np.ndim(u[k]) else ""))
            i += 1
    return out


def _coordinate_names(u: dict) -> list[str]:
    """The parameter name of every flat coordinate (``ravel_pytree`` order: sorted names)."""
    return [k for k in sorted(u) for _ in range(int(np.size(u[k])))]




def _warnings(structure: Structure, params: Params, stderr, not_determined=()) -> list[str]:
    out = []
    if params.m is not None and len(params.m) > 1:
        m = np.asarray(params.m)
        for a, b in zip(m[:-1], m[1:]):
            if abs(b - a) <= 0.02 * max(a, b):
                out.append(f"degenerate: two lobes with nearly equal m ({a:.4g}, {b:.4g}); one lobe may suffice")
        for j, w in enumerate(np.asarray(params.w)):
            if w == 0.0:
                out.append(f"degenerate: lobe {j} has weight 0 (on its bound): the data needs fewer lobes, and this lobe's m = {m[j]:.4g} means nothing")
            elif w < 1e-3:
                out.append(f"degenerate: lobe {j} (m = {m[j]:.4g}) has weight {w:.2g} → 0; fewer lobes may suffice")
            elif stderr is not None and "weight" in stderr and w < 2 * np.asarray(stderr["weight"])[j]:
                out.append(f"degenerate: lobe {j} (m = {m[j]:.4g}) has weight {w:.2g} ± {np.asarray(stderr['weight'])[j]:.2g}, "
                           "not significantly above 0; fewer lobes may suffice")
    if params.s is not None:
        s = float(params.s)
        if s == 0.0:
            out.append("s = 0 (on its bound): the data shows no specular part, and m, F0 are not determined by it")
        elif s == 1.0:
            out.append("s = 1 (on its bound): the data shows no diffuse part")
        elif s < 1e-4:
            out.append(f"s = {s:.2g} is near its lower bound: the data shows almost no specular part")
        elif s > 1 - 1e-4:
            out.append(f"s = {s:.6g} is near its upper bound: the data shows almost no diffuse part")
    if params.f0 is not None:
        f0 = np.asarray(params.f0)
        if np.any(f0 < 1e-6) or np.any(f0 > 1 - 1e-6):
            out.append("F0 at a bound (0 or 1) in some bands: the effective index is at its limit there")
    if not_determined:
        names = ", ".join(parameter(k).public for k in dict.fromkeys(not_determined))
        out.append(f"degenerate: the data does not determine {names} (no standard error there): the model has more freedom than the data shows")
    if stderr is None:
        out.append("standard errors not computed: JᵀJ is singular or ill-conditioned (cond > 1e12)")
    return out


@dataclasses.dataclass
class PreparedFit:
    """One measurement made ready for ``fit_core`` (checked, started, laid out): what :func:`fit`
    and :func:`~ctfit._fitting.batch.fit_batch` share."""

    data: Measurement
    structure: Structure
    loss: str
    dtype: object
    start: Params
    fixed: tuple[str, ...]
    problem: Problem
    u0: dict
    grid: object
    k: int
    given_start: bool

    def options(self, solver: str, max_steps: int) -> tuple:
        """The arguments of ``fit_core`` after (problem, u0, grid)."""
        return (self.k, solver, max_steps, self.given_start)

    def padded(self, pad_to: tuple[int, int]) -> PreparedFit:
        """The same fit with its problem padded to ``pad_to`` (direction pairs, samples)."""
        problem = make_problem(self.structure, self.data, fixed_params=self.start, fixed=self.fixed, loss=self.loss, dtype=self.dtype, pad=True, pad_to=pad_to)
        return dataclasses.replace(self, problem=problem)


def prepare_fit(data: Measurement, structure: Structure | None, *, start: Params | None, fixed: tuple[str, ...], loss: str, dtype, starts: int,
             pad_to: tuple[int, int] | None = None) -> PreparedFit:
    """The checks, start, problem (padded to its size bucket, or to ``pad_to`` (direction pairs,
    samples)), free start ``u0`` and m grid of a fit."""
    if dtype == jnp.float64 and not jax.config.jax_enable_x64:
        raise RuntimeError("float64 fitting needs jax_enable_x64 (jax.config.update('jax_enable_x64', True)); or pass dtype=jnp.float32")
    structure = structure or Structure(lobes=1, diffuse="F0/pi")
    if loss == "auto":
        loss = "sigma" if data.sigma is not None else "relative"
    if loss not in LOSSES:
        raise ValueError(f"loss must be 'auto' or one of {LOSSES}, got {loss!r}")
    default = _default_start(structure, data)
    given_start = start is not None
    if start is None:
        start = default
    else:  # anything the structure needs but ``start`` lacks comes from the defaults
        start = Params(**{k: (getattr(start, k) if getattr(start, k) is not None else getattr(default, k)) for k in ("s", "m", "w", "f0", "n", "k", "rd")})
    check_fittable(data, structure, fixed=fixed, loss=loss, dtype=dtype)
    problem = make_problem(structure, data, fixed_params=start, fixed=fixed, loss=loss, dtype=dtype, pad=True, pad_to=pad_to)
    u0 = {k: jnp.asarray(v, dtype=dtype) for k, v in from_params(problem.spec, start).items()}
    k = starts if "m" in u0 else 1
    grid = jnp.asarray(np.log(_m_grid(structure.lobes, structure.diffuse is not None)), dtype=dtype) if ("m" in u0 and k >= 1) else None
    return PreparedFit(data, structure, loss, dtype, start, tuple(fixed), problem, u0, grid, k, given_start)


def fit(
    data: Measurement,
    structure: Structure | None = None,
    *,
    start: Params | None = None,
    fixed: tuple[str, ...] = (),
    loss: str = "auto",
    solver: str = "lm",
    dtype=jnp.float64,
    starts: int = 3,
    max_steps: int = 256,
) -> FitResult:
    """Fit ``structure`` (default: one Beckmann lobe, V-cavity G, effective index, R_d = F0/π).

    ``start`` gives starting values (and the values of the ``fixed`` parameters); ``loss`` is
    one of ``LOSSES`` or "auto" (sigma-weighted when the data has sigma, else relative).
    Per-band parameters of ``start`` must already be on the data's bands.
    """
    t0 = time.perf_counter()
    prep = prepare_fit(data, structure, start=start, fixed=fixed, loss=loss, dtype=dtype, starts=starts)
    out = jax.device_get(cached_call("fit", fit_core, prep.problem, prep.u0, prep.grid, *prep.options(solver, max_steps)))
    return finish_fit(prep, out, solver, t0)


def finish_fit(prep: PreparedFit, out: dict, solver: str, t0: float) -> FitResult:
    """The :class:`FitResult` of a prepared fit from ``fit_core``'s output (host arrays); ``t0``: when it began."""
    data, structure, loss, dtype, problem = prep.data, prep.structure, prep.loss, prep.dtype, prep.problem
    costs, ok, steps, best = out["costs"], out["ok"], out["steps"], int(out["best"])
    u = out["u"]
    params = Params(**{k: None if v is None else np.asarray(v) for k, v in out["params"].items()})
    mask = np.asarray(problem.mask)
    floor = float(problem.floor)
    n, p = int(mask.sum()), int(sum(np.size(v) for v in u.values()))
    cost = float(costs[best])
    rss_like = 2 * cost
    scale2 = 1.0 if loss == "sigma" else rss_like / max(n - p, 1)
    params, order = _sorted_lobes(params)
    on_bound = np.asarray(out["on_bound"], bool)
    loose = undetermined(out["jtj"]) & ~on_bound  # coordinates the data does not determine
    stderr = standard_errors(out["jtj"], out["jt"], scale2, order, ~on_bound & ~loose)
    pairs, index = data.directions()
    rel = np.reshape(out["rel"], problem.y.shape)
    if problem.spec.grid:
        structure_notes = relative_residual_structure(pairs, rel[: len(pairs)], mask=mask[: len(pairs)])
    else:
        structure_notes = relative_residual_structure(pairs, rel[: len(data)], index=index)
    gn_decrease = float(out["gn_decrease"])
    stationary = gn_decrease <= STATIONARY_TOLERANCE[jnp.dtype(dtype).name]
    rmse = float(out["rmse"])
    not_finite = nonfinite_reason(cost, rmse, int(out["bad"]), n, dtype)  # a result that is not finite has not converged
    zero_cost = float(out["zero_cost"])
    explains_nothing = bool(explains_none(cost, zero_cost))
    converged = bool(judge_converged(np.asarray(ok)[best], not_finite is None, gn_decrease, cost, zero_cost, dtype))
    bic = (rss_like if loss == "sigma" else n * math.log(max(rss_like, 1e-300) / n)) + p * math.log(n)
    stats = {
        "converged": converged,
        "steps": int(np.asarray(steps)[best]),
        "cost": cost,
        "rmse": rmse,
        "rel_rmse": float(out["rel_rmse"]),
        "time_s": time.perf_counter() - t0,
        "n_samples": n,
        "n_params": p,
        "bic": bic,
        "loss": loss,
        "solver": solver,
        "dtype": jnp.dtype(dtype).name,
        "starts": int(np.asarray(costs).size),
        "relative_floor": floor,
        "gauss_newton_decrease": gn_decrease,
        "on_bound": _labelled(u, on_bound),
        "no_stderr": [f"{k}[{i}]" for k, v in (stderr or {}).items() for i in np.flatnonzero(~np.isfinite(np.asarray(v, dtype=float)))],
    }
    full = Params(**{k: getattr(params, k) for k in ("s", "m", "w", "f0", "n", "k", "rd")})
    material = Material(
        structure=structure,
        params=full,
        wavelength_nm=data.wavelength_nm,
        channels=data.channels,
        name=f"fit of {data.source}",
        band_unknown=data.band_unknown,
    )
    names = _coordinate_names(u)
    not_determined = [names[i] for i in np.flatnonzero(loose)]
    notes = ([not_finite] if not_finite else []) + _warnings(structure, params, stderr, not_determined)
    if not stationary:
        hint = " (float32 rounding: fit in float64)" if jnp.dtype(dtype).name == "float32" else " (more --max-steps, or another start)"
        notes.append(f"not a minimum: the solver stopped where a Gauss–Newton step still promises a {gn_decrease:.2%} lower cost{hint}")
    if explains_nothing:
        notes.append(f"no fit: the model explains almost none of the data (its cost is {cost / zero_cost:.1%} of a model that is 0 everywhere); "
                     "the solver stalled where the lobe misses the data — try other --lobes, starting values (--material) or another --loss")
    if not bool(np.asarray(ok)[best]):
        notes.append("the solver stopped on a numerical failure (a singular or non-finite step); fit in float64 (without --float32), from another start, or with fewer lobes")
    return FitResult(material=material, stats=stats, stderr=stderr, warnings=notes + structure_notes, loss=loss, solver=solver)


def select_structure(
    data: Measurement, candidates: list[Structure], *, progress=None, **kwargs
) -> tuple[FitResult, list[tuple[Structure, FitResult]]]:
    """Fit each candidate structure and keep the one with the lowest BIC (Schwarz 1978).

    Candidates nest: a candidate that contains an earlier one (one lobe more, or a diffuse part
    added) also starts from that one's fit, embedded so that it gives the same model (the new
    lobe with weight 0, or s = 1), so its cost is never above the smaller candidate's.
    Candidates with more free parameters than the data has samples are left out (all of them
    too many: the first one's error). ``progress`` wraps the candidate loop (e.g. a progress
    bar); ``kwargs`` go to :func:`fit`."""
    enough = [st for st in candidates if n_free_parameters(st, data.n_bands, kwargs.get("fixed", ())) <= len(data)]
    results: list[tuple[Structure, FitResult]] = []
    for st in (progress or (lambda it: it))(enough or candidates[:1]):
        inner = [r for sm, r in results if _contains(st, sm) and np.isfinite(r.stats["cost"])]
        start = None
        if inner and "start" not in kwargs:
            start = _embedded_start(min(inner, key=lambda r: r.stats["cost"]), st)
        results.append((st, fit(data, st, start=start, **kwargs)))
    ok = [(st, r) for st, r in results if np.isfinite(r.stats["bic"])]
    best = min(ok or results, key=lambda sr: sr[1].stats["bic"])[1]
    return best, results


def _contains(big: Structure, small: Structure) -> bool:
    """Whether ``small``'s models are ``big``'s with one lobe's weight 0 or with s = 1."""
    same = all(getattr(big, a) == getattr(small, a) for a in ("distribution", "geometry", "fresnel", "normalization"))
    one_more_lobe = big.lobes == small.lobes + 1 and big.diffuse == small.diffuse and small.lobes >= 1
    diffuse_added = big.lobes == small.lobes >= 1 and small.diffuse is None and big.diffuse is not None
    return same and (one_more_lobe or diffuse_added)


def _embedded_start(inner: FitResult, big: Structure) -> Params:
    """``inner``'s fitted parameters as a start of the larger structure ``big``, same model:
    the new lobe gets weight 0 and the slope of the m grid farthest (in log) from the fitted
    ones; a new diffuse part gets s = 1 (its R_d then starts at the default)."""
    p, small = inner.material.params, inner.material.structure
    m, w = np.asarray(p.m, dtype=float), np.asarray(p.w, dtype=float)
    if big.lobes > small.lobes:
        grid = np.geomspace(0.01, 0.8, 9)
        new = grid[np.argmax(np.min(np.abs(np.log(grid)[:, None] - np.log(m)[None, :]), axis=1))]
        m, w = np.append(m, new), np.append(w, 0.0)
    s = np.asarray(p.s) if small.has_s else (np.asarray(1.0) if big.has_s else None)
    return Params(s=s, m=m, w=w, f0=p.f0 if big.fresnel == "f0" else None, n=p.n if big.fresnel != "f0" else None, k=p.k, rd=p.rd)
