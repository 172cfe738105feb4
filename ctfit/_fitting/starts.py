"""Where a fit starts: the default start, a start from a material file, and the grid seeds.

The seeds (``seed_points``): a grid over the rms slopes (one value per lobe, ascending), each
scored by the loss after the best per-band amplitude (a linear least-squares problem), one
vmapped pass over the data; the best ``starts`` distinct grid points seed the solver.
:func:`~ctfit.seed_params` gives them to analysis code as :class:`~ctfit.Params`.
"""

from __future__ import annotations

import itertools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._io import MaterialError
from .._model import Material, Measurement, Params, Structure, f0_from_n, f0_from_nk, n_from_f0
from .chunks import chunk_count, sum_over_chunks
from .coordinates import free_names
from .problem import Problem, band_sum, model_values

__all__ = ["default_start", "m_grid", "seed_points", "seeds_from_scores", "grid_sums", "grid_scales", "grid_costs", "start_from_material"]


def default_start(structure: Structure, data: Measurement) -> Params:
    nb = data.n_bands
    j = structure.lobes
    return Params(
        s=np.asarray(0.5) if structure.has_s else None,
        m=np.geomspace(0.1, 0.3, j) if j else None,
        w=np.full(j, 1.0 / j) if j else None,
        f0=np.full(nb, 0.5) if structure.fresnel == "f0" and structure.needs_fresnel_params else None,
        n=np.full(nb, 1.5) if structure.fresnel != "f0" and structure.needs_fresnel_params else None,
        k=np.full(nb, 2.0) if structure.fresnel == "conductor" and structure.needs_fresnel_params else None,
        rd=(np.full(nb, 0.05) if structure.diffuse in ("spectrum", "transmitted") else (np.asarray(0.05) if structure.diffuse == "constant" else None)),
    )


def m_grid(lobes: int, diffuse: bool = True) -> np.ndarray:
    """The grid of m the seeds are scored on. One lobe: 16 points 0.005–1, and without a diffuse
    part 5 more down to 10⁻⁴ for mirror-like lobes (seen in their tails or sampled closely). With
    a diffuse part those would be traps: a lobe that reaches no sample fits like s = 0. Several
    lobes: every ascending choice of ``lobes`` values from a fixed list of points 0.01–0.8 (at
    least ``lobes + 1`` of them, so every count up to :data:`~ctfit.MAX_LOBES` has a grid)."""
    if lobes == 1:
        grid = np.geomspace(0.005, 1.0, 16)
        return (grid if diffuse else np.concatenate([np.geomspace(1e-4, 0.005, 6)[:-1], grid]))[:, None]
    points = {2: 9, 3: 7}.get(lobes, max(5, lobes + 1))  # five and more lobes: lobes + 1 choose lobes
    return np.array(list(itertools.combinations(np.geomspace(0.01, 0.8, points), lobes)))


def _weighted(part: Problem, u0: dict, log_m):
    v = model_values(part, dict(u0, m=log_m))
    return v, part.mask / jnp.maximum(jnp.abs(part.y), part.floor) ** 2


def _scale_of(num, den):
    return num / jnp.maximum(den, 1e-300)


def _cost_of(part: Problem, u0: dict, log_m, scale, v=None, wgt=None):
    if v is None:
        v, wgt = _weighted(part, u0, log_m)
    per_sample = scale if part.spec.grid else scale[part.band]
    return jnp.sum(wgt * (per_sample * v - part.y) ** 2)


def _amplitude_sums(part: Problem, u0: dict, log_m):
    v, wgt = _weighted(part, u0, log_m)
    return band_sum(part, wgt * v * part.y), band_sum(part, wgt * v * v)


def grid_sums(part: Problem, u0: dict, grid):
    """Per grid point of log m, the per-band sums (Σ w v y, Σ w v²) of ``part``: the first pass of
    the seeds' scores, summable over chunks; the scale is their ratio (:func:`grid_scales`)."""
    return jax.lax.map(lambda log_m: _amplitude_sums(part, u0, log_m), grid)


def grid_scales(num, den):
    """The best per-band amplitude of each grid point from :func:`grid_sums`' totals."""
    return _scale_of(num, den)


def grid_costs(part: Problem, u0: dict, grid, scales):
    """Per grid point, the weighted loss of ``part`` after its amplitude ``scales`` (the second
    pass; summable over chunks)."""
    return jax.lax.map(lambda ms: _cost_of(part, u0, ms[0], ms[1]), (grid, scales))


@eqx.filter_jit
def _score_grid(problem: Problem, u0: dict, grid):
    """Loss of each grid point of log m after the best per-band amplitude (weighted linear LS):
    the per-band scale Σ w v y / Σ w v², then Σ w (scale · v − y)² — two passes, chunk by chunk,
    on a large grid (:func:`~ctfit._fitting.chunks.sum_over_chunks`), one pass otherwise."""

    def score(log_m):
        if chunk_count(problem) == 1:
            v, wgt = _weighted(problem, u0, log_m)
            scale = _scale_of(band_sum(problem, wgt * v * problem.y), band_sum(problem, wgt * v * v))
            cost = _cost_of(problem, u0, log_m, scale, v, wgt)
        else:
            scale = _scale_of(*sum_over_chunks(problem, lambda part: _amplitude_sums(part, u0, log_m)))
            cost = sum_over_chunks(problem, lambda part: _cost_of(part, u0, log_m, scale))
        return cost, scale

    return jax.lax.map(score, grid)  # one grid point at a time: memory O(N), not O(grid × N)


def seed_points(problem: Problem, u0: dict, k: int, grid=None, keep_start: bool = False) -> dict:
    """The ``k`` best distinct starting points from a grid over log m, each with its best per-band scale
    (F0 scaled; for n, k: the index of the scaled normal reflectance, :func:`_index_seed`), and
    with ``keep_start`` the start ``u0`` itself as one more seed.

    Traceable (used inside the jitted fit); ``grid`` is the (G, lobes) grid of log m.
    """
    if "m" not in u0 or k < 1 or grid is None:
        return jax.tree.map(lambda a: jnp.asarray(a)[None], u0)
    costs, scales = _score_grid(problem, u0, grid)
    return seeds_from_scores(problem, u0, k, grid, costs, scales, keep_start)


def seeds_from_scores(problem: Problem, u0: dict, k: int, grid, costs, scales, keep_start: bool = False) -> dict:
    """:func:`seed_points` from the grid's scores: ``costs`` (G,) and ``scales`` (G, bands)
    (only ``problem.spec`` is used)."""
    costs = jnp.where(jnp.isfinite(costs), costs, jnp.inf)
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
    elif "n" in u0 and not problem.spec.structure.shared_index:  # a plastic's one n starts where u0 has it
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


def start_from_material(base: Material, structure: Structure, data: Measurement) -> tuple[Params, tuple[str, ...]]:
    """Starting values on the data's bands and the names of fixed parameters (key ``fixed``)."""
    fixed = tuple(base.meta.get("fixed", ()))
    allowed = set(free_names(structure))
    bad = [f for f in fixed if f not in allowed]
    if bad:
        raise MaterialError(f"material {base.name!r}: key 'fixed' names {bad}; this structure's parameters are {sorted(allowed)}")
    params = base.params_at(data.wavelength_nm if data.channels is None else None, data.channels)
    if structure.fresnel == "f0" and params.f0 is None and params.n is not None:
        f0 = f0_from_nk(params.n, params.k) if params.k is not None else f0_from_n(params.n)
        params = Params(s=params.s, m=params.m, w=params.w, f0=np.asarray(f0), rd=params.rd)
    return params, fixed
