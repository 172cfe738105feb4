"""Where a fit starts: the default start, a start from a material file, and the grid seeds.

The seeds (``seed_points``): a grid over the rms slopes (one value per lobe, ascending), each
point scored at every split of the light among its lobes (:func:`lobe_weight_grid`, where the
weights are free) by the loss after the best non-negative per-band amplitudes of the model's
specular and diffuse parts (a linear least-squares problem, :func:`grid_amplitudes`); one pass
over the data gives the sums that both the amplitudes and the loss after them are made of, at
every split (:func:`grid_sums`, :func:`grid_costs`). Each grid point keeps its best split
(:func:`best_splits`); the best ``starts`` distinct grid points seed the solver, with those weights.
:func:`~ctfit.seed_params` gives them to analysis code as :class:`~ctfit.Params`.
"""

from __future__ import annotations

import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np

from .._io import MaterialError
from .._model import Material, Measurement, Params, Structure, array_module, f0_from_n, f0_from_nk, n_from_f0, parameter, safe_div
from .chunks import chunk_count, sum_over_chunks
from .coordinates import free_names, weight_coordinates
from .problem import Problem, at_samples, band_sum, per_direction, shape_and_rest, values_from_s

__all__ = ["default_start", "m_grid", "m_points", "m_combinations", "lobe_weight_grid", "seed_points", "seeds_from_scores", "grid_sums",
           "grid_sums_shape", "best_splits", "splits_scored", "linear_parts", "grid_scales", "grid_amplitudes", "grid_costs", "start_from_material"]


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


def m_points(lobes: int, diffuse: bool = True) -> np.ndarray:
    """The values of m the seeds' grid is made of (:func:`m_grid`). One lobe: 16 points 0.005–1,
    and without a diffuse part 5 more down to 10⁻⁴ for mirror-like lobes (seen in their tails or
    sampled closely). With a diffuse part those would be traps: a lobe that reaches no sample fits
    like s = 0. Several lobes: a fixed list of points 0.01–0.8 (at least ``lobes + 1`` of them, so
    every count up to :data:`~ctfit.MAX_LOBES` has a grid)."""
    if lobes == 1:
        grid = np.geomspace(0.005, 1.0, 16)
        return grid if diffuse else np.concatenate([np.geomspace(1e-4, 0.005, 6)[:-1], grid])
    points = {2: 9, 3: 7}.get(lobes, max(5, lobes + 1))  # five and more lobes: lobes + 1 choose lobes
    return np.geomspace(0.01, 0.8, points)


@functools.cache
def m_combinations(values: int, lobes: int) -> np.ndarray:
    """The grid's points as indices into its ``values`` (:func:`m_points`): every ascending choice
    of ``lobes`` of them, (points, lobes)."""
    out = np.array(list(itertools.combinations(range(values), lobes)), dtype=np.int32).reshape(-1, lobes)
    out.flags.writeable = False
    return out


def m_grid(lobes: int, diffuse: bool = True) -> np.ndarray:
    """The grid of m the seeds are scored on, (points, lobes): every ascending choice of ``lobes``
    values of :func:`m_points` (one lobe: each value)."""
    values = m_points(lobes, diffuse)
    return values[m_combinations(values.shape[0], lobes)]


WEIGHT_PARTS = {2: 8}
"""A grid point of several lobes is scored at every split of the light among its lobes into
positive multiples of 1/N (:func:`lobe_weight_grid`): N = 8 for two lobes, 6 (this default) for more."""


@functools.cache
def lobe_weight_grid(lobes: int) -> np.ndarray:
    """The lobes' weights every grid point of ``lobes`` lobes is scored with, (splits, lobes): each
    split of 1 into ``lobes`` positive multiples of 1/N (:data:`WEIGHT_PARTS`), and the equal
    split (the start's); [[1]] for one lobe.

    Scored at the start's weights alone (equal), a pair of slopes with a lobe too narrow to reach
    any sample scored as its other lobe alone, freely scaled, and outranked the pairs that fit
    both widths at half weight each: on files of two lobes (m = 0.2, 0.4, w = 0.6, 0.4) most seeds
    were (0.01 or 0.017, 0.27), and their solves took 15–31 steps to drag the narrow lobe out.

    >>> lobe_weight_grid(2)[:, 0].tolist()
    [0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875]
    >>> lobe_weight_grid(3).shape, lobe_weight_grid(4).shape, lobe_weight_grid(8).tolist() == [[0.125] * 8]
    ((10, 3), (11, 4), True)
    """
    if lobes == 1:
        return np.ones((1, 1))
    n = WEIGHT_PARTS.get(lobes, 6)
    cuts = itertools.combinations(range(1, n), lobes - 1)
    grid = np.array([np.diff([0, *c, n]) for c in cuts], dtype=float).reshape(-1, lobes) / n
    if n % lobes:  # the equal split is not among them
        grid = np.concatenate([grid, np.full((1, lobes), 1.0 / lobes)])
    grid.flags.writeable = False
    return grid


def splits_scored(u0: dict) -> np.ndarray | None:
    """The lobe weights :func:`grid_sums` scores each grid point with (:func:`lobe_weight_grid`),
    or None where the weights are not free (one lobe, or weights held): those of ``u0`` alone."""
    if "w" not in u0 or "m" not in u0 or jnp.shape(u0["m"])[0] < 2:
        return None
    return lobe_weight_grid(jnp.shape(u0["m"])[0])


def linear_parts(part: Problem, u0: dict):
    """What the seeds' sums need of ``part`` at ``u0`` whatever the grid point: the model is
    linear in S, the per-direction factor of its specular term (Eq. 2 and Eq. 4: R = s F S +
    d R_d), so at any rms slopes its specular part s R_s is S there times ∂R/∂S, and its diffuse
    part d R_d is the model at S = 0; both from one JVP of the model at S = 0 (the Fresnel
    term and R_d evaluated once, not once per grid point). Returns (d R_d, ∂R/∂S, the loss's
    weights), each in the problem's layout."""
    u_shape, u_rest = shape_and_rest(u0)
    zero = jnp.zeros(jnp.shape(part.geom.cos_vh), part.y.dtype)  # S per direction (every sample its own in a chunk)
    diffuse, per_s = jax.jvp(lambda s: values_from_s(part, s, u_rest, u_shape), (zero,), (jnp.ones_like(zero),))
    return diffuse, per_s, jnp.where(part.y == 0, 0, part.mask / jnp.maximum(jnp.abs(part.y), part.floor) ** 2)


PRODUCT_BANDS = 128
"""Up to this many bands, the seeds' sums over each band's samples (pairs layout, free lobe
weights) are one product with the samples' band indicators, above it a scatter
(``segment_sum``): on a chunk of 2,048 samples of 31 bands, the 99 columns of two lobes, formed
as rows (one per column, the samples along them), took 0.45 ms as the product and 3.5 ms as the
scatter, and the product's cost grows with the bands. It is a choice of this layout, not of
:func:`~ctfit._fitting.problem.band_sum`: there, on its samples-first columns, the one-lobe
grid's 48 sums took 1.2 ms as the product against 0.9 ms as its scatter."""


def _specular_sums(part: Problem, u0: dict, linear: tuple, values, one_at_a_time: bool = False):
    """(Σ w A y, Σ w A², Σ w A B) per band at the grid's points (:func:`m_combinations` of the
    log m ``values``), A = S ∂R/∂S with the lobes weighted as in ``u0``: shape (G, 1, bands, 3);
    where the weights are free (:func:`splits_scored`), at each of the splits instead:
    (G, splits, bands, 3), from the sums of the lobes of every value alone and of their products
    (S = Σ_j w_j S_j is linear in the weights, Eq. 5). ``one_at_a_time``: those sums formed for
    one grid point (or value) at a time, temporaries of the cells' size (with free weights, the
    lobe of every value at every cell too: V times the cells)."""
    b, per_s, wgt = linear
    u_shape, u_rest = shape_and_rest(u0)
    lobes = jnp.shape(u0["m"])[0]
    combos = m_combinations(values.shape[0], lobes)
    splits = splits_scored(u0)
    wp = wgt * per_s
    if splits is None:
        grid = values[jnp.asarray(combos)]
        if one_at_a_time:
            return jax.lax.map(lambda log_m: _weighted_sums(part, u0, linear, log_m[None])[0], grid)
        return _weighted_sums(part, u0, linear, grid)
    s_dir = jax.vmap(lambda log_m: per_direction(part, dict(u_shape, m=jnp.full((lobes,), log_m)), u_rest))(values)  # each value's lobe alone
    if part.spec.grid:  # cells (pairs, bands), S per pair: sums over the pairs
        s_all = s_dir[..., None]  # (V, pairs, 1)
        sums_of = lambda cols: jnp.sum(cols, axis=-2)
    else:  # cells are samples, each of one band: sums over each band's samples
        s_all = at_samples(part, s_dir.T).T  # (V, samples)
        if part.fixed_bands <= PRODUCT_BANDS:  # as one product with the bands' indicators
            one_hot = (part.band[:, None] == jnp.arange(part.fixed_bands)).astype(per_s.dtype)  # type: ignore[index]  # set when not grid
            sums_of = lambda cols: cols @ one_hot
        else:
            sums_of = lambda cols: band_sum(part, cols.T).T

    v = values.shape[0]
    if one_at_a_time:
        def products(s):  # one value's lobe against the data, the diffuse part and every value's lobe
            return sums_of(jnp.concatenate([(s * (wp * part.y))[None], (s * (wp * b))[None], s * s_all * (wp * per_s)], axis=0))

        sums = jax.lax.map(products, s_all)  # (V, 2 + V, bands)
        ay, ab, aa = sums[:, 0], sums[:, 1], sums[:, 2:]
    else:
        pairs = (s_all[:, None] * s_all[None]).reshape(v * v, *s_all.shape[1:])
        sums = sums_of(jnp.concatenate([s_all * (wp * part.y), s_all * (wp * b), pairs * (wp * per_s)], axis=0))  # (2 V + V², bands)
        ay, ab, aa = sums[:v], sums[v: 2 * v], sums[2 * v:].reshape(v, v, -1)
    # Each grid point's sums at a split w: linear (A y, A B) and quadratic (A²) forms in w of its
    # lobes' sums (static indices: the grid's points into the values).
    w = jnp.asarray(splits, per_s.dtype)
    idx = jnp.asarray(combos)
    a_y, a_b, a_a = ay[idx], ab[idx], aa[idx[:, :, None], idx[:, None, :]]  # (G, lobes, bands), (G, lobes, lobes, bands)
    return jnp.stack([jnp.einsum("sj,gjb->gsb", w, a_y), jnp.einsum("sj,sk,gjkb->gsb", w, w, a_a), jnp.einsum("sj,gjb->gsb", w, a_b)], axis=-1)


def _weighted_sums(part: Problem, u0: dict, linear: tuple, grid):
    """:func:`_specular_sums` at the grid points ``grid`` (G, lobes) of log m, the lobes weighted
    as in ``u0``: (G, 1, bands, 3)."""
    b, per_s, wgt = linear
    u_shape, u_rest = shape_and_rest(u0)
    s_all = jax.vmap(lambda log_m: per_direction(part, dict(u_shape, m=log_m), u_rest))(grid).T  # (directions, G)
    wp = wgt * per_s
    if part.spec.grid:  # cells (pairs, bands), S per pair: products over the pairs
        sums = jnp.stack([s_all.T @ (wp * part.y), (s_all * s_all).T @ (wp * per_s), s_all.T @ (wp * b)], axis=-1)
    else:
        s = at_samples(part, s_all)  # cells are samples, each of one band: (samples, G)
        cols = jnp.stack([s * (wp * part.y)[:, None], s * s * (wp * per_s)[:, None], s * (wp * b)[:, None]], axis=-1)
        sums = jnp.swapaxes(band_sum(part, cols), 0, 1)
    return sums[:, None]


def grid_sums(part: Problem, u0: dict, values, at_once: bool = True):
    """Per grid point of log m (:func:`m_combinations` of the log m ``values``) and split of the
    lobes' weights (:func:`splits_scored`; the start's weights alone where they are not free),
    the per-band sums of ``part`` over the model's two parts A = s R_s and B = d R_d and the data
    y, w the loss's weights: (Σ w A y, Σ w B y, Σ w y²) and (Σ w A², Σ w A B, Σ w B²), shapes
    (G, splits, bands, 3) and (G, splits, bands, 3). All the seeds' scores need
    (:func:`grid_amplitudes`, :func:`grid_costs`), in one pass, summable over chunks. The model's
    Fresnel term and diffuse part are evaluated once (:func:`linear_parts`: A = S ∂R/∂S), the sums
    of B and y alone once, and those of A for every grid point at once, or with ``at_once`` False
    one grid point (or value) at a time (temporaries of the cells' size; with free weights, V times it)."""
    linear = linear_parts(part, u0)
    b, _, wgt = linear
    fixed = band_sum(part, jnp.stack([wgt * b * part.y, wgt * part.y * part.y, wgt * b * b], axis=-1))  # (bands, 3)
    varying = _specular_sums(part, u0, linear, values, one_at_a_time=not at_once)
    fixed = jnp.broadcast_to(fixed, varying.shape)
    num = jnp.stack([varying[..., 0], fixed[..., 0], fixed[..., 1]], axis=-1)
    den = jnp.stack([varying[..., 1], varying[..., 2], fixed[..., 2]], axis=-1)
    return num, den


def grid_sums_shape(u0: dict, values, bands: int) -> tuple[int, int, int, int]:
    """The shape of each of :func:`grid_sums`' two results for the log m ``values``: grid points,
    splits of the lobes' weights (:func:`splits_scored`), bands, 3."""
    splits = splits_scored(u0)
    points = m_combinations(values.shape[0], jnp.shape(u0["m"])[0]).shape[0]
    return points, 1 if splits is None else splits.shape[0], bands, 3


def score_columns(u0: dict, values: int) -> int:
    """Products per cell that :func:`grid_sums` forms for ``values`` values of m (the memory of
    forming them all at once): 3 per grid point, or with free weights (:func:`splits_scored`)
    2 + V per value."""
    if splits_scored(u0) is None:
        return 3 * m_combinations(values, jnp.shape(u0["m"])[0]).shape[0]
    return values * (2 + values)


def best_splits(num, den):
    """Each grid point's scores at its best split of the lobes' weights, from :func:`grid_sums`'
    totals: (costs (G,), the whole model's scales (G, bands), the parts' amplitudes
    (G, bands, 2), the index of the split (G,)). NumPy in, NumPy out (the chunked fit chooses its
    seeds on the host); traceable otherwise."""
    xp = array_module(num, den)
    amplitudes = grid_amplitudes(num, den)
    costs = grid_costs(num, den, amplitudes)  # (G, splits)
    pick = xp.argmin(costs, axis=1)

    def take(a):
        return xp.take_along_axis(a, pick.reshape((-1, 1) + (1,) * (a.ndim - 2)), axis=1)[:, 0]

    return xp.min(costs, axis=1), grid_scales(take(num), take(den)), take(amplitudes), pick


def grid_scales(num, den):
    """The best per-band amplitude of the whole model A + B from :func:`grid_sums`' totals: the
    seeds' scale of F0 (or of the normal reflectance)."""
    total = den[..., 0] + 2 * den[..., 1] + den[..., 2]
    return safe_div(num[..., 0] + num[..., 1], total)[0]


def grid_amplitudes(num, den):
    """The best non-negative per-band amplitudes (α, β) of the two parts, α A + β B, from
    :func:`grid_sums`' totals (a two-variable non-negative least-squares problem, solved in closed
    form): what each grid point is scored with. Scoring with the whole model's one amplitude ranked
    a lobe too narrow to reach any sample (the diffuse part alone, freely scaled) above every lobe
    that is held to the start's mix of specular and diffuse light, a seed that then slid on a
    plateau for over a hundred steps."""
    xp = array_module(num, den)
    ay, by = num[..., 0], num[..., 1]
    aa, ab, bb = den[..., 0], den[..., 1], den[..., 2]
    det = aa * bb - ab * ab
    both_ok = det > np.sqrt(np.finfo(det.dtype).eps) * aa * bb  # the parts not (nearly) proportional
    det = xp.where(both_ok, det, 0)
    alpha, beta = safe_div(ay * bb - by * ab, det)[0], safe_div(by * aa - ay * ab, det)[0]
    both_ok = both_ok & (alpha >= 0) & (beta >= 0)
    a_only = safe_div(xp.maximum(ay, 0), aa)[0]  # 0 for a part that is 0 at every sample
    b_only = safe_div(xp.maximum(by, 0), bb)[0]
    a_better = a_only * xp.maximum(ay, 0) >= b_only * xp.maximum(by, 0)  # the decrease of the loss, Σ w y² − cost
    alpha = xp.where(both_ok, alpha, xp.where(a_better, a_only, 0.0))
    beta = xp.where(both_ok, beta, xp.where(a_better, 0.0, b_only))
    return xp.stack([alpha, beta], axis=-1)


def grid_costs(num, den, amplitudes):
    """Per grid point, the weighted loss Σ w (α A + β B − y)² after its parts' ``amplitudes``
    (α, β) (:func:`grid_amplitudes`), from :func:`grid_sums`' totals: the loss is quadratic in
    (α, β), so its sums give it without a second pass over the data (Σ w y² − 2α Σ w A y − 2β Σ w B y
    + α² Σ w A² + 2αβ Σ w A B + β² Σ w B², per band, summed over the bands; at least 0). The
    difference of sums loses digits where a grid point fits almost exactly (float32: about
    10⁻⁷ Σ w y²), which only reorders grid points that fit alike."""
    xp = array_module(num, den, amplitudes)
    alpha, beta = amplitudes[..., 0], amplitudes[..., 1]
    cost = (num[..., 2] - 2 * alpha * num[..., 0] - 2 * beta * num[..., 1]
            + alpha * alpha * den[..., 0] + 2 * alpha * beta * den[..., 1] + beta * beta * den[..., 2])
    return xp.maximum(xp.sum(cost, axis=-1), 0)


@functools.cache
def _score_grid():
    """:func:`_grid_scores` through ``eqx.filter_jit`` (Equinox imported here, where a program
    is traced: a fit whose programs are stored does not import it)."""
    import equinox as eqx

    return eqx.filter_jit(_grid_scores)


VECTOR_CELLS = 3 << 22
"""Products of cells (cells × :func:`score_columns`) up to which the seeds' sums are formed for
every grid point at once (:func:`grid_sums`: temporaries of that many values); above, one grid
point (or value of m) at a time (``at_once`` False: memory of the cells' size, or with free
weights V times it)."""


def _grid_scores(problem: Problem, u0: dict, grid):
    """Loss of each grid point of log m after the best amplitudes of its two parts (weighted
    linear least squares, :func:`grid_amplitudes`, :func:`grid_costs`) at its best split of the
    lobes' weights, the whole model's best per-band scale there, and that split
    (:func:`best_splits`) — one pass, chunk by chunk on a large grid
    (:func:`~ctfit._fitting.chunks.sum_over_chunks`)."""

    def sums(part: Problem):
        return grid_sums(part, u0, grid, at_once=part.y.size * score_columns(u0, grid.shape[0]) <= VECTOR_CELLS)

    num, den = sums(problem) if chunk_count(problem) == 1 else sum_over_chunks(problem, sums)
    return best_splits(num, den)


def seed_points(problem: Problem, u0: dict, k: int, grid=None, keep_start: bool = False) -> dict:
    """The ``k`` best distinct starting points from a grid over log m, each with its best per-band scale
    (F0 scaled; for n, k: the index of the scaled normal reflectance, :func:`_index_seed`), and
    with ``keep_start`` the start ``u0`` itself as one more seed.

    Traceable (used inside the jitted fit); ``grid`` holds the (V,) values of log m the grid's
    points are made of (:func:`m_points`, :func:`m_combinations`).
    """
    if "m" not in u0 or k < 1 or grid is None:
        return jax.tree.map(lambda a: jnp.asarray(a)[None], u0)
    costs, scales, amplitudes, split = _score_grid()(problem, u0, grid)
    return seeds_from_scores(problem, u0, k, grid, costs, scales, keep_start, amplitudes, split)


def seeds_from_scores(problem: Problem, u0: dict, k: int, grid, costs, scales, keep_start: bool = False, amplitudes=None, split=None) -> dict:
    """:func:`seed_points` from the grid's scores at each point's best split of the lobes' weights
    (:func:`best_splits`): ``costs`` (G,), ``scales`` (G, bands), the parts' ``amplitudes``
    (G, bands, 2) (:func:`grid_amplitudes`) and the index of the ``split`` (G,) of
    :func:`splits_scored` (only ``problem.spec`` is used). Where given, with s and F0 free and
    R_d = F0/π, a seed's s is the specular share of the light at the amplitudes its grid point was
    scored with (:func:`_mixed_s`), not the start's; with free weights, a seed's weights are its
    grid point's best split. NumPy in (``costs``, ``scales``, ``u0`` and the rest), NumPy out: the
    chunked fit chooses its seeds on the host; traceable otherwise."""
    xp = array_module(costs, scales)
    costs = xp.where(xp.isfinite(costs), costs, xp.inf)
    order = xp.argsort(costs, stable=True)
    # Grid points that score the same give the same model (lobes too narrow to reach any
    # sample all look like no lobe): one of each goes first, so the k seeds differ.
    c = costs[order]
    same = xp.concatenate([xp.zeros((1,), bool), xp.abs(c[1:] - c[:-1]) <= 1e-3 * xp.abs(c[1:])])
    order = order[xp.argsort(same, stable=True)][: min(k, grid.shape[0])]
    seeds = dict(jax.tree.map(lambda a: xp.broadcast_to(a, (order.shape[0],) + xp.shape(a)), u0))
    seeds["m"] = grid[xp.asarray(m_combinations(grid.shape[0], xp.shape(u0["m"])[0]))[order]]
    splits = splits_scored(u0)
    if splits is not None and split is not None:
        weights = xp.asarray(splits, u0["w"].dtype)[split[order]]
        seeds["w"] = weight_coordinates(weights, problem.spec.space, xp).astype(u0["w"].dtype)
    if "f0" in u0:
        seeds["f0"] = xp.clip(u0["f0"] * scales[order], 0.005, 0.995)
        if amplitudes is not None and "s" in u0 and "rd" not in u0:  # R_d = F0/π: s sets the parts' mix
            seeds["s"] = _mixed_s(u0, amplitudes[order])
    elif "n" in u0 and not problem.spec.structure.shared_index:  # a plastic's one n starts where u0 has it
        k0 = u0.get("k", xp.zeros_like(u0["n"]))
        f0 = xp.clip(f0_from_nk(u0["n"], k0) * scales[order], 1e-4, 0.995)
        n, kk = _index_seed(f0, xp.broadcast_to(u0["n"], f0.shape), problem.spec.structure.fresnel == "conductor")
        seeds["n"] = n
        if "k" in u0:
            seeds["k"] = kk
    elif "n" in u0:  # a plastic's one index: the seeds spread over PLASTIC_INDEX_SEEDS
        n = xp.asarray([PLASTIC_INDEX_SEEDS[j % len(PLASTIC_INDEX_SEEDS)] for j in range(order.shape[0])], seeds["n"].dtype)
        seeds["n"] = xp.broadcast_to(n.reshape((-1,) + (1,) * (seeds["n"].ndim - 1)), seeds["n"].shape)
    if amplitudes is not None and "rd" in u0:  # a diffuse part of its own: at its grid point's best amplitude
        seeds["rd"] = _diffuse_seed(u0["rd"], amplitudes[order])
    if keep_start:
        seeds = jax.tree.map(lambda a, b: xp.concatenate([a, xp.asarray(b)[None]]), seeds, u0)
    return seeds


PLASTIC_INDEX_SEEDS = (1.5, 2.0, 1.3)
"""A plastic's (one, shared) index n in its seeds, in turn: the best grid point at 1.5, the next
at 2.0 and 1.3. The cost is not convex in n: with every seed at 1.5, a smooth plastic of n = 2.2
(ctfit's own noise-free data, and Mitsuba's ``plastic`` of ``int_ior`` 1.9 and 2.2) ended at
n = 1.33 (1.50), a local minimum reported as converged with a standard error 500 times smaller
than its distance from the truth."""


MIX_LIMITS = (0.05, 0.95)
"""The range of s a seed takes from its grid point's amplitudes (:func:`_mixed_s`): at s = 0 the
lobes' slopes have no gradient, and at s = 1 the diffuse part's values none."""


def _mixed_s(u0: dict, amplitudes):
    """The s of seeds (R_d = F0/π) whose grid points scored best with the amplitudes (α, β) per band
    of the model's parts at ``u0`` (α s R_s + β d R_d, :func:`grid_amplitudes`): the specular
    part's share of the light, Σ α s / Σ (α s + β d) over the bands, within :data:`MIX_LIMITS`.
    Seeds at the start's s (½) spent their first steps moving light between the two parts:
    fitting 64 files of s = 0.9 (2,000 samples, 31 bands, two lobes) took 837 steps of the best
    seeds against 1,116, 3.7 s against 4.3 s, every file at the same minimum. Its F0 stays the
    whole model's scale (:func:`grid_scales`): taking F0 from α and β as well (F0 (α s + β d))
    started seeds lower still, but seeds with a lobe too narrow to reach any sample then kept it
    and ended in a one-lobe minimum (cost 34.5 against 0.399) or slid for 40–96 steps."""
    xp = array_module(amplitudes)
    alpha, beta = amplitudes[..., 0], amplitudes[..., 1]  # (seeds, bands)
    s = u0["s"]
    share = safe_div(xp.sum(alpha, axis=-1) * s, xp.sum(alpha * s + beta * (1 - s), axis=-1))[0]
    return xp.clip(share, *MIX_LIMITS).astype(xp.result_type(s))


RD_SEED_FLOOR = 1e-2
"""The least R_d of a seed, as a fraction of the start's (:func:`_diffuse_seed`): a seed at R_d = 0
would start on its bound."""


def _diffuse_seed(rd0, amplitudes):
    """The R_d of seeds whose diffuse part is their own (a spectrum, a constant, transmitted): the
    start's ``rd0``, times the best amplitude β of the diffuse part at each seed's grid point
    (:func:`grid_amplitudes`; per band, or their mean for one constant R_d), held within
    [:data:`RD_SEED_FLOOR` × rd0, R_d's upper bound]. Seeds at the start's R_d (0.05 sr⁻¹, a rubber's is
    0.019) put the light of every band's diffuse part back in their first steps; with a tenth of
    a rubber's values 0 (not measured) one band's R_d went on to 4·10⁻⁴ on the way, and all three
    seeds ended there, converged, at 1.4× the cost of the fit from the truth."""
    xp = array_module(amplitudes)
    beta = amplitudes[..., 1]  # (seeds, bands)
    if xp.ndim(rd0) == 0:
        beta = xp.mean(beta, axis=-1)
    return xp.clip(rd0 * beta, RD_SEED_FLOOR * rd0, parameter("rd").upper).astype(xp.result_type(rd0))


def _index_seed(f0, n, conductor: bool):
    """n, k whose normal reflectance is ``f0``: for a conductor, n kept and k from
    F0 = ((n−1)² + k²)/((n+1)² + k²) where that has a root, else k = 0 and the dielectric n of
    F0 (paper §4); for a real index, that n alone."""
    xp = array_module(f0, n)
    n_diel = n_from_f0(f0)
    if not conductor:
        return n_diel, None
    k2 = (f0 * (n + 1) ** 2 - (n - 1) ** 2) / (1 - f0)
    has_k = k2 > 0
    return xp.where(has_k, n, n_diel), xp.sqrt(xp.where(has_k, k2, 0.0))


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
