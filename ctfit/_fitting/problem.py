"""The least-squares problem: free parameters, their constraints, the data layout and the residual.

Free parameters live in a pytree ``u`` (a dict) of coordinates from the one parameter table
(:mod:`ctfit._model.parameters`). A problem's ``spec.space`` says which:

- "box" (the fit): s, F0, n, k, R_d themselves, log m, and stick-breaking fractions of the
  lobe weights (:func:`_weights`), each inside closed bounds that the projected Levenberg–Marquardt
  solver keeps; a parameter may end on its bound (s = 1, F0 = 0, a weight 0).
- "unconstrained" (the sampler): m = exp(u), w = softmax(0, u), s and F0 = sigmoid(u),
  n = n_min + softplus(u), k and R_d = softplus(u).

Parameters not free are taken from ``fixed`` (a :class:`~ctfit.Params`). Parameters the
structure does not have are not in ``u`` at all.

The residual's Jacobian has structure that a generic Jacobian ignores: R = s F(λ) S(m, w) +
(1 − s) R_d(λ), where S (the D·G lobe sum) depends only on the direction and F only on V·H and
the band. :func:`residual` therefore has a ``jax.custom_jvp`` that computes, once per
evaluation, ∂S/∂(m, w) per *direction* and the derivative of each value with respect to its own
band's parameters, and forms any Jacobian–vector product as a cheap contraction of these
columns. ``jax.linearize`` (used by optimistix's Gauss–Newton family) then costs a few model
passes instead of one per parameter.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._model import (
    Geometry,
    Measurement,
    Params,
    Structure,
    box_bounds,
    clip_box,
    combine_parts,
    geometry_from_angles_deg,
    n_lower,
    parameter,
    specular_geometric,
)
from .._runtime import cached_call

__all__ = ["Problem", "LOSSES", "LOG_RATIO_FLOOR", "RELATIVE_FLOOR", "FLOOR_OF_PEAK", "SEED_FLOOR", "ROBUST_SCALE", "loss_floor", "default_loss", "row_floors", "make_problem", "to_params", "from_params", "bounds", "residual", "model_values", "normal_equations", "half_squared_norm", "sum_over_chunks", "map_over_chunks", "bucket", "chunk_rows", "chunk_padding"]

LOSSES = ("absolute", "relative", "robust-relative", "sigma", "cosine", "log", "log-ratio")
RELATIVE_FLOOR = 0.1
"""The relative loss's floor, a fraction of the median positive sample (:func:`loss_floor`;
chosen by measurement, docs/fitting.md)."""
ROBUST_SCALE = 0.05
"""The "robust-relative" loss's scale c: relative residuals well below it count as in "relative",
larger ones grow as √(2|r|c) (SciPy's ``soft_l1``), so a region the model cannot follow (a
retro-reflection, the grazing fringe) does not pull the rest of the fit (docs/fitting.md)."""
FLOOR_OF_PEAK = 1e-6
"""The relative loss's floor is never below this fraction of the largest sample."""
SEED_FLOOR = 1e-3
"""For the losses without a floor of their own (sigma, absolute, cosine, log): the floor, × the
largest value, of the relative weights the seeds are scored with (and of ``rel_rmse``). From the
peak, as before the relative losses' floor moved to the typical sample: with the typical sample's
floor the seeds of σ-weighted synthetic fits fell into wrong basins (docs/stability.md: a
conductor with n(λ) crossing 1; s = 1 in float32)."""
LOG_RATIO_FLOOR = 0.01
"""The "log-ratio" loss's ε as a fraction of the median positive measured value (docs/fitting.md)."""
_SHAPE = ("m", "w")  # parameters of S, the per-direction factor


@dataclasses.dataclass(frozen=True)
class Spec:
    """Static description of a fit: structure, which parameters are free, loss, data layout."""

    structure: Structure
    free: tuple[str, ...]
    loss: str
    grid: bool
    space: str = "box"


class Problem(eqx.Module):
    """Data and static spec of one fit. Arrays are laid out as the model evaluates them:

    grid layout: values (D, W) with a boolean ``mask`` (False for missing (pair, band) cells),
    ``cos_i`` (D, 1) (None unless the loss weights by cos θ_i);
    pairs layout: values (N,) with ``pair`` and ``band`` indices per sample (``mask`` False for
    padding).
    """

    spec: Spec = eqx.field(static=True)
    geom: Geometry
    y: jax.Array
    sigma: jax.Array | None
    cos_i: jax.Array | None
    mask: jax.Array
    pair: jax.Array | None
    band: jax.Array | None
    floor: jax.Array
    fixed: Params
    fixed_bands: int = eqx.field(static=True)


def _geometry_fields(pairs) -> dict:
    g = geometry_from_angles_deg(pairs[:, 0], pairs[:, 1], pairs[:, 2], pairs[:, 3])
    return {f.name: getattr(g, f.name) for f in dataclasses.fields(g)}


GEOMETRY_BLOCK = 4096
"""Direction pairs per call of the geometry program: any number of pairs is laid out by one
program of this shape (no program per data size)."""


_recent_geometry: dict = {}  # content digest of a small set of pairs → its geometry (host arrays)
RECENT_GEOMETRY_PAIRS = 16384
"""Geometry of at most this many direction pairs is kept for the next fit of the same pairs (the
data-chosen default fits several structures to one screening sample); the last 4 kept."""


def _geometry_deg(pairs, on_host: bool = False) -> Geometry:
    """The :class:`Geometry` of direction pairs (θ_i, φ_i, θ_o, φ_o) in degrees, shape (D, 4),
    through the program store (a stored program loads in a fraction of what compiling the
    trigonometry costs), ``GEOMETRY_BLOCK`` pairs at a time, joined on the host (and left there
    with ``on_host``). The geometry of a few small sets of pairs is kept for their next fit."""
    pairs = np.asarray(pairs)
    n = len(pairs)
    if n == 0:
        return Geometry(**cached_call("geometry", _geometry_fields, jnp.asarray(pairs)))
    put = (lambda a: a) if on_host else jax.device_put  # noqa: E731
    key = (pairs.dtype.str, pairs.shape, hashlib.blake2b(np.ascontiguousarray(pairs).tobytes(), digest_size=16).digest()) if n <= RECENT_GEOMETRY_PAIRS else None
    fields = _recent_geometry.pop(key, None)
    if fields is None:
        blocks = -(-n // GEOMETRY_BLOCK)
        padded = np.concatenate([pairs, np.broadcast_to(pairs[:1], (blocks * GEOMETRY_BLOCK - n, 4))])
        parts = [jax.device_get(cached_call("geometry", _geometry_fields, padded[b * GEOMETRY_BLOCK: (b + 1) * GEOMETRY_BLOCK])) for b in range(blocks)]
        fields = {k: np.concatenate([p[k] for p in parts])[:n] for k in parts[0]}
        for v in fields.values():
            v.setflags(write=False)  # shared by the fits of these pairs
    if key is not None:
        _recent_geometry[key] = fields  # the most recently used last
        for old in list(_recent_geometry)[:-4]:
            _recent_geometry.pop(old, None)  # (a background fit may prune too)
    return Geometry(**{k: put(v) for k, v in fields.items()})


def _weights(u_w, space: str):
    """Lobe weights from J − 1 free values (see the module docstring).

    Box: stick-breaking fractions v ∈ [0, 1]^(J−1), w_0 = 1 − v_1, w_j = v_1⋯v_j (1 − v_(j+1)),
    w_(J−1) = v_1⋯v_(J−1): every lobe's weight reaches 0 on a bound of the box."""
    if space == "box":
        ones = jnp.ones((1,), u_w.dtype)
        return jnp.cumprod(jnp.concatenate([ones, u_w])) * jnp.concatenate([1 - u_w, ones])
    return jax.nn.softmax(jnp.concatenate([jnp.zeros((1,), u_w.dtype), u_w]))


def _stick_fractions(w) -> np.ndarray:
    """Inverse of the box map of :func:`_weights`: v_j = (Σ_(i≥j) w_i) / (Σ_(i≥j−1) w_i)."""
    w = np.clip(np.asarray(w, dtype=float), 0, None)
    w = w / np.sum(w)
    rest = np.cumsum(w[::-1])[::-1]  # r_j = Σ_(i≥j) w_i
    return np.clip(rest[1:] / np.maximum(rest[:-1], 1e-300), 0.0, 1.0)


def to_params(spec: Spec, u: dict, fixed: Params) -> Params:
    """Model parameters from the free coordinates ``u`` (``spec.space``: "box" or "unconstrained").

    Box coordinates are held inside their bounds (:func:`~ctfit._model.parameters.clip_box`), so any
    solver's trial point gives a valid model; the projected solver never leaves them anyway.
    """
    st = spec.structure

    def pick(name):
        if name not in u:
            return getattr(fixed, name)
        row = parameter(name)
        if spec.space == "box":
            lo, hi = box_bounds(name, st.fresnel, st.family)
            value = row.box(clip_box(u[name], lo, hi))
        else:
            value = (n_lower(st.fresnel, st.family) if name == "n" else 0.0) + row.free(u[name])
        if name == "n" and st.shared_index:  # a plastic: one free index, the same in every band
            value = jnp.broadcast_to(value, jnp.shape(fixed.n))
        return value

    w = None
    if st.has_specular:
        if "w" in u:
            w = _weights(clip_box(u["w"], *box_bounds("w")) if spec.space == "box" else u["w"], spec.space)
        elif st.lobes == 1 and fixed.w is None:
            w = jnp.ones((1,), u["m"].dtype if "m" in u else jnp.result_type(float))
        else:
            w = fixed.w
    return Params(
        s=pick("s") if st.has_s else None,
        m=pick("m") if st.has_specular else None,
        w=w,
        f0=pick("f0") if st.fresnel == "f0" and st.needs_fresnel_params else None,
        n=pick("n") if st.fresnel != "f0" and st.needs_fresnel_params else None,
        k=pick("k") if st.fresnel == "conductor" and st.needs_fresnel_params else None,
        rd=pick("rd") if st.has_rd else None,
    )


def from_params(spec: Spec, params: Params) -> dict:
    """Free coordinates ``u`` of ``params`` (inverse of :func:`to_params`; box coordinates are
    clipped into their bounds)."""
    u = {}
    for name in spec.free:
        v = np.asarray(getattr(params, name), dtype=float)
        row = parameter(name)
        if name == "w":
            v = np.clip(v, 1e-12, None)
            u[name] = _stick_fractions(v) if spec.space == "box" else np.log(v[1:]) - np.log(v[0])
            continue
        if name == "n" and spec.structure.shared_index:
            v = np.asarray(np.mean(v))  # a plastic's one index
        if spec.space == "box":
            lo, hi = box_bounds(name, spec.structure.fresnel, spec.structure.family)
            u[name] = np.clip(row.box_inverse(np.maximum(v, 1e-300) if name == "m" else v), lo, hi)
        else:
            offset = n_lower(spec.structure.fresnel, spec.structure.family) if name == "n" else 0.0
            u[name] = row.free_inverse(v - offset)
    return u


def bounds(spec: Spec, u: dict) -> tuple[dict, dict]:
    """Lower and upper bounds of the box coordinates ``u`` (same pytree, arrays of u's shapes)."""
    lo, hi = {}, {}
    for name, v in u.items():
        a, b = box_bounds(name, spec.structure.fresnel, spec.structure.family)
        lo[name] = jnp.full(jnp.shape(v), a, jnp.result_type(v))
        hi[name] = jnp.full(jnp.shape(v), b, jnp.result_type(v))
    return lo, hi


def free_names(structure: Structure, fixed: tuple[str, ...] = ()) -> tuple[str, ...]:
    """The parameters a structure has, minus those held fixed, in a canonical order."""
    names = []
    if structure.has_s:
        names.append("s")
    if structure.has_specular:
        names.append("m")
        if structure.lobes > 1:
            names.append("w")
    if structure.needs_fresnel_params:
        names += ["f0"] if structure.fresnel == "f0" else (["n", "k"] if structure.fresnel == "conductor" else ["n"])
    if structure.has_rd:
        names.append("rd")
    return tuple(n for n in names if n not in fixed)


def make_problem(
    structure: Structure,
    data: Measurement,
    *,
    fixed_params: Params,
    fixed: tuple[str, ...] = (),
    loss: str = "relative",
    dtype=jnp.float64,
    space: str = "box",
    pad: bool = False,
    pad_to: tuple[int, int] | None = None,
    chunk: int | None = None,
) -> Problem:
    """Lay ``data`` out for the model (grid when dense, pairs otherwise) and fix the spec.

    ``space``: the coordinates of the free parameters, "box" (the fit) or "unconstrained" (the
    sampler); see the module docstring. ``pad``: round the number of direction pairs and of
    samples up to a size bucket (:func:`bucket`) with masked-out entries, so that measurements
    of other sizes in the same bucket share one compiled program. ``pad_to``: pad to these sizes
    (direction pairs, samples; at least the data's) instead of the buckets, so that
    measurements of different buckets can be stacked into one batch (``pad`` is implied).
    ``chunk``: pad to whole chunks instead, per-row arrays left on the host (:func:`chunk_padding`)."""
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
    if data.brdf is None:
        raise ValueError(f"{data.source}: the data has no 'brdf' column to fit")
    if loss == "sigma" and data.sigma is None:
        raise ValueError(f"{data.source}: loss 'sigma' needs a 'sigma' column")
    if loss == "sigma":
        bad = np.flatnonzero(~(np.asarray(data.sigma) > 0) | ~np.isfinite(data.sigma))
        if bad.size:
            raise ValueError(f"{data.source}: loss 'sigma' needs every sigma finite and > 0; {bad.size} of {len(data)} samples are not "
                             f"(the first is sample {bad[0]}, sigma = {data.sigma[bad[0]]!r}); drop them or choose another loss")
    pairs, index = data.directions()
    n_pairs, n_bands = len(pairs), data.n_bands
    grid = n_pairs * n_bands <= 1.5 * len(data) and not data.repeats  # a grid cell holds one sample
    pad_to, pad = (chunk_padding(grid, n_pairs, len(data), n_bands, chunk) if chunk else pad_to), pad or pad_to is not None or bool(chunk)
    if pad_to is not None and (pad_to[0] < n_pairs or pad_to[1] < len(data)):
        raise ValueError(f"{data.source}: pad_to={pad_to} is smaller than the data ({n_pairs} direction pairs, {len(data)} samples)")
    if pad and n_pairs:
        pairs = np.concatenate([pairs, np.broadcast_to(pairs[:1], ((pad_to[0] if pad_to else bucket(n_pairs)) - n_pairs, 4))])
    put = (lambda a: a) if chunk else jax.device_put  # noqa: E731 — chunked, the per-row arrays stay on the host
    geom = _geometry_deg(np.asarray(pairs, dtype=jnp.dtype(dtype)), on_host=bool(chunk))
    floor = loss_floor(data.brdf, loss)
    cos_pair = np.cos(np.deg2rad(pairs[:, 0]))
    if grid:
        shape = (len(pairs), n_bands)
        y = np.zeros(shape)
        mask = np.zeros(shape, dtype=bool)
        y[index, data.band] = data.brdf
        mask[index, data.band] = True
        if data.sigma is not None:
            sig = np.ones(shape)
            sig[index, data.band] = data.sigma
        cos_i = cos_pair[:, None] if loss in ("cosine", "log") else None  # broadcast over the bands; only these losses use it
        pair = band = None
    else:
        extra = (pad_to[1] if pad_to else bucket(len(data))) - len(data) if pad and len(data) else 0
        padded = lambda a, fill: np.concatenate([np.asarray(a), np.full(extra, fill, np.asarray(a).dtype)])  # noqa: E731
        y, mask = padded(data.brdf, 0.0), padded(np.ones(len(data), dtype=bool), False)
        sig = padded(data.sigma, 1.0) if data.sigma is not None else None
        cos_i = padded(cos_pair[index], 1.0) if loss in ("cosine", "log") else None
        pair, band = put(padded(index, 0)), put(padded(data.band, 0))  # no conversion program
    spec = Spec(structure=structure, free=free_names(structure, fixed), loss=loss, grid=grid, space=space)
    to = lambda a: None if a is None else jnp.asarray(a, dtype=dtype)  # noqa: E731
    rows = (lambda a: None if a is None else np.asarray(a, dtype=jnp.dtype(dtype))) if chunk else to  # noqa: E731
    return Problem(
        spec=spec,
        geom=geom,
        y=rows(y),
        sigma=rows(sig) if data.sigma is not None else None,
        cos_i=rows(cos_i),
        mask=put(mask),
        pair=pair,
        band=band,
        floor=jax.device_put(np.asarray(floor, dtype=jnp.dtype(dtype))),
        fixed=jax.tree.map(to, fixed_params),
        fixed_bands=n_bands,
    )


def loss_floor(y, loss: str) -> float:
    """The floor of the relative losses, from the typical sample (the median positive value), not
    the peak: for "relative", :data:`RELATIVE_FLOOR` × the median (every sample within a decade
    below it is weighed by its relative error, however high the peak; darker ones — the
    instrument's noise floor, stray zeros — by their absolute error over the floor), never below
    :data:`FLOOR_OF_PEAK` × the largest value (so that relative residuals stay representable);
    for "log-ratio", :data:`LOG_RATIO_FLOOR` × the median. "robust-relative" has the relative floor.
    The other losses have no floor in their residuals; theirs (:data:`SEED_FLOOR` × the largest
    value) weighs the seeds' relative scores and defines their ``rel_rmse``. 1 without a positive value."""
    return float(row_floors(np.asarray(y, dtype=float).reshape(1, -1), loss)[0])


def default_loss(data) -> str:
    """The loss of ``loss="auto"``: "sigma" when the data has a sigma column, else "robust-relative"
    (chosen by measurement on data the model cannot represent, docs/fitting.md)."""
    return "sigma" if getattr(data, "sigma", None) is not None else "robust-relative"


def row_floors(block: np.ndarray, loss: str) -> np.ndarray:
    """:func:`loss_floor` of each row of ``block`` (e.g. texels × samples)."""
    block = np.asarray(block, dtype=float)
    has = np.any(block > 0, axis=1)  # rows without a positive value: floor 1 (no all-NaN slice: fits run in threads, so no warning filters)
    floors = np.ones(block.shape[0])
    if has.any():
        pos = np.where(block[has] > 0, block[has], np.nan)
        peak = np.nanmax(pos, axis=1)
        if loss == "log-ratio":
            floors[has] = LOG_RATIO_FLOOR * np.nanmedian(pos, axis=1)
        elif loss in ("relative", "robust-relative"):
            floors[has] = np.maximum(RELATIVE_FLOOR * np.nanmedian(pos, axis=1), FLOOR_OF_PEAK * peak)
        else:
            floors[has] = SEED_FLOOR * peak
    return np.where(np.isfinite(floors), floors, 1.0)


BUCKET_MIN = 256
"""The smallest size bucket (:func:`bucket`)."""
CHUNK = 1 << 15
"""Rows per chunk: direction pairs of a grid layout, samples of a pairs layout. A problem whose
(padded) number of rows is a multiple of this, and at least ``MIN_CHUNKS`` of them, is summed
chunk by chunk — cost, Jᵀr,
JᵀJ, the seed scores and the residual summary — so the solve's temporaries are a few
chunk-sized arrays instead of a few data-sized ones."""
_FINE = 1 << 18
"""Above this size, buckets are multiples of ``CHUNK``: eight per octave (:func:`bucket`)."""


def bucket(n: int) -> int:
    """The size bucket of ``n``.

    Up to 2¹⁸: the smallest ⌈256 · 2^(k/2)⌉ ≥ n (k = 0, 1, …); buckets grow by √2, so padding
    costs at most 41 % more work and a new file size usually needs no new compiled program.
    Above: ``n`` rounded up to a multiple of 2^(⌊log₂ n⌋ − 3) — eight buckets per octave, at most
    12.5 % padding where the solve dominates the compile, and each a multiple of ``CHUNK``.
    """
    if n > _FINE:
        step = 1 << (int(n).bit_length() - 4)
        return -(-n // step) * step
    k = max(0, math.ceil(2 * math.log2(max(n, 1) / BUCKET_MIN) - 1e-9))
    while math.ceil(BUCKET_MIN * 2 ** (k / 2)) < n:
        k += 1
    while k > 0 and math.ceil(BUCKET_MIN * 2 ** ((k - 1) / 2)) >= n:
        k -= 1
    return math.ceil(BUCKET_MIN * 2 ** (k / 2))


def chunk_padding(grid: bool, n_pairs: int, n_samples: int, n_bands: int, cells: int) -> tuple[int, int]:
    """``pad_to`` of a problem cut into chunks of about ``cells`` cells (``make_problem(chunk=…)``):
    the rows (pairs of a grid, samples otherwise) up to a multiple of :func:`chunk_rows`. Such a
    problem keeps its per-row arrays on the host (NumPy): the fit on chunks of one shape
    (``chunked_fit.py``) sends them to the device chunk by chunk."""
    rows = chunk_rows(grid, n_bands, cells)
    return (-(-max(n_pairs, 1) // rows) * rows, n_samples) if grid else (n_pairs, -(-max(n_samples, 1) // rows) * rows)


def chunk_rows(grid: bool, n_bands: int, cells: int) -> int:
    """Rows of a chunk of about ``cells`` cells: samples in the pairs layout; in the grid layout
    a power of two of direction pairs (each with its ``n_bands`` bands), at least 64."""
    if not grid:
        return cells
    return max(64, 1 << max(0, (cells // max(n_bands, 1)).bit_length() - 1))


MIN_CHUNKS = 16
"""Fewer chunks than this are summed at once: below ~500,000 rows the data's temporaries are
small, and one pass over all of it is a little faster than a loop over chunks."""


def chunk_count(problem: Problem) -> int:
    """How many chunks of ``CHUNK`` rows (direction pairs of a grid, samples otherwise) ``problem``
    is summed over (1: all at once)."""
    n = problem.y.shape[0]
    return n // CHUNK if n % CHUNK == 0 and n // CHUNK >= MIN_CHUNKS else 1


def _parts(problem: Problem, k: int):
    """The per-row arrays of ``problem`` split into ``k`` chunks (a leading axis), and a function
    that makes the problem of one chunk from one slice of them.

    Grid layout: a chunk is ``CHUNK`` direction pairs with all their bands. Pairs layout: a
    chunk is ``CHUNK`` samples, each its own direction pair (their geometry gathered), so S is
    computed per sample — the same work for scattered data, where pairs and samples are about
    as many."""

    def split(a):
        return None if a is None else a.reshape((k, CHUNK) + a.shape[1:])

    cells = (split(problem.y), split(problem.sigma), split(problem.cos_i), split(problem.mask))
    if problem.spec.grid:
        rows = (jax.tree.map(split, problem.geom), *cells)

        def part(x):
            geom, y, sigma, cos_i, mask = x
            return dataclasses.replace(problem, geom=geom, y=y, sigma=sigma, cos_i=cos_i, mask=mask)

        return rows, part
    rows = (split(problem.pair), split(problem.band), *cells)
    own = jnp.arange(CHUNK, dtype=problem.pair.dtype)

    def part(x):
        pair, band, y, sigma, cos_i, mask = x
        geom = jax.tree.map(lambda a: a[pair], problem.geom)
        return dataclasses.replace(problem, geom=geom, pair=own, band=band, y=y, sigma=sigma, cos_i=cos_i, mask=mask)

    return rows, part


def sum_over_chunks(problem: Problem, fn):
    """Σ ``fn(part)`` over the parts of ``problem`` of ``CHUNK`` rows each (:func:`chunk_count`), as a
    ``lax.scan`` — or ``fn(problem)`` when it is not chunked. ``fn`` returns a pytree of arrays that add up: sums over samples (½‖r‖², Jᵀr, JᵀJ, per-band sums)."""
    k = chunk_count(problem)
    if k == 1:
        return fn(problem)
    rows, part = _parts(problem, k)
    first = jax.tree.map(lambda a: a[0], rows)
    total = jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), jax.eval_shape(lambda: fn(part(first))))

    def body(acc, x):
        return jax.tree.map(jnp.add, acc, fn(part(x))), None

    return jax.lax.scan(body, total, rows)[0]


def map_over_chunks(problem: Problem, fn):
    """``fn(part)`` for each part of ``problem`` (:func:`sum_over_chunks`), stacked along a new
    leading axis (length 1 when it is not chunked): ``lax.map``, one chunk's temporaries at a time."""
    k = chunk_count(problem)
    if k == 1:
        return jax.tree.map(lambda a: a[None], fn(problem))
    rows, part = _parts(problem, k)
    return jax.lax.map(lambda x: fn(part(x)), rows)


def _gather_bands(params: Params, band) -> Params:
    def g(a):
        return a if a is None or jnp.ndim(a) == 0 else a[band]

    return Params(s=params.s, m=params.m, w=params.w, f0=g(params.f0), n=g(params.n), k=g(params.k), rd=g(params.rd))


def _per_direction(problem: Problem, u_shape: dict, u_rest: dict):
    """S per unique direction pair (everything in R_s but F)."""
    params = to_params(problem.spec, {**u_shape, **u_rest}, problem.fixed)
    return specular_geometric(problem.spec.structure, params, problem.geom)


def _values_from_s(problem: Problem, s_dir, u_rest: dict, u_shape: dict):
    """Model values in the problem's layout, given S per direction."""
    spec = problem.spec
    params = to_params(spec, {**u_shape, **u_rest}, problem.fixed)
    geom = problem.geom
    transmitted = spec.structure.diffuse == "transmitted"
    if spec.grid:
        valid = geom.valid[:, None]
        spec_v = None if s_dir is None else s_dir[:, None]
        cos_lv = (geom.cos_l[:, None], geom.cos_v[:, None]) if transmitted else None
        return combine_parts(spec.structure, params, valid, spec_v, geom.cos_vh[:, None], cos_lv)
    p = _gather_bands(params, problem.band)
    valid = geom.valid[problem.pair]
    spec_v = None if s_dir is None else s_dir[problem.pair]
    cos_lv = (geom.cos_l[problem.pair], geom.cos_v[problem.pair]) if transmitted else None
    return combine_parts(spec.structure, p, valid, spec_v, geom.cos_vh[problem.pair], cos_lv)


def model_values(problem: Problem, u: dict):
    """The model at every sample (problem layout), from the free values ``u``."""
    u_shape = {k: v for k, v in u.items() if k in _SHAPE}
    u_rest = {k: v for k, v in u.items() if k not in _SHAPE}
    s_dir = _per_direction(problem, u_shape, u_rest) if problem.spec.structure.has_specular else None
    return _values_from_s(problem, s_dir, u_rest, u_shape)


def loss_residuals(problem: Problem, values, y, flat: bool = True):
    """Residuals in the problem's layout for the selected weighting (missing cells give 0)."""
    loss = problem.spec.loss
    if loss == "absolute":
        r = values - y
    elif loss == "relative":
        r = (values - y) / jnp.maximum(y, problem.floor)
    elif loss == "robust-relative":  # soft-L1 of the relative residual: ρ(r) = 2c²(√(1 + (r/c)²) − 1) = r'²
        r = (values - y) / jnp.maximum(y, problem.floor)
        z = r / ROBUST_SCALE
        r = r * jnp.sqrt(2.0 / (jnp.hypot(1.0, z) + 1.0))  # = sign(r)·√ρ(r), smooth at 0 (no cancellation)
    elif loss == "sigma":
        r = (values - y) / problem.sigma
    elif loss == "cosine":
        r = (values - y) * problem.cos_i
    elif loss == "log":  # Löw et al. 2012
        r = jnp.log1p(values * problem.cos_i) - jnp.log1p(y * problem.cos_i)
    else:  # log-ratio: ln((f + ε)/(y + ε)), the relative error where y ≫ ε (ε: loss_floor)
        eps = problem.floor
        r = jnp.log(jnp.maximum(values, 0) + eps) - jnp.log(jnp.maximum(y, 0) + eps)
    r = r * problem.mask
    return r.reshape(-1) if flat else r


def _split(u: dict):
    return {k: v for k, v in u.items() if k in _SHAPE}, {k: v for k, v in u.items() if k not in _SHAPE}


def _band_sum(problem: Problem, x):
    """Σ over the samples of each band: (W, …) from a layout-shaped array (… its trailing axes)."""
    if problem.spec.grid:
        return jnp.sum(x, axis=0)
    return jax.ops.segment_sum(x, problem.band, num_segments=problem.fixed_bands)


def _columns(problem: Problem, u: dict, y):
    """The residual and its Jacobian in factored form, all in the problem's layout.

    Returns ``(res, values, cols)`` with ``res`` the flat residual and ``cols`` a dict name →
    (kind, column): kind "shape" → (a, J_S) with ∂r/∂u_name = a · J_S[direction] (``a`` per
    sample, ``J_S`` (D, size) per direction); kind "scalar" → c with ∂r/∂u_name = c; kind "band"
    → e with ∂r_i/∂u_name[band_i] = e_i (a value depends only on its own band's entry).
    One model pass, one batched JVP for the band and scalar parameters and ∂/∂S, and a
    per-direction Jacobian of S — never an N × P matrix.
    """
    spec = problem.spec
    u_shape, u_rest = _split(u)
    has_spec = spec.structure.has_specular
    s_dir = _per_direction(problem, u_shape, u_rest) if has_spec else None

    def f_rest(s, ur):
        return _values_from_s(problem, s, ur, u_shape)

    # ∂v/∂S (tangent 1 on S) and ∂v/∂u_k for every band/scalar parameter k (tangent 1 on all
    # of u_k: each value sees only its own entry), one JVP each.
    names = tuple(sorted(u_rest))
    zeros = {n: jnp.zeros_like(v) for n, v in u_rest.items()}
    values = f_rest(s_dir, u_rest)
    dvs = {}
    if has_spec and u_shape:
        dvs["__S__"] = jax.jvp(lambda s: f_rest(s, u_rest), (s_dir,), (jnp.ones_like(s_dir),))[1]
    for k in names:
        dvs[k] = jax.jvp(lambda ur: f_rest(s_dir, ur), (u_rest,), (dict(zeros, **{k: jnp.ones_like(u_rest[k])}),))[1]
    res, g = jax.jvp(lambda v: loss_residuals(problem, v, y, flat=False), (values,), (jnp.ones_like(values),))
    cols = {}
    if "__S__" in dvs:
        a = g * dvs["__S__"]
        jac_s = jax.jacfwd(lambda us: _per_direction(problem, us, u_rest))(u_shape)
        for k in u_shape:
            cols[k] = ("shape", (a, jac_s[k].reshape(s_dir.shape[0], -1)))
    for k in names:
        kind = "scalar" if jnp.ndim(u_rest[k]) == 0 else "band"
        cols[k] = (kind, g * dvs[k])
    return res.reshape(-1), values, cols


def normal_equations(problem: Problem, u: dict):
    """½‖r‖², Jᵀr and JᵀJ at ``u``, from the factored Jacobian (no N × P matrix), summed chunk by
    chunk for a large grid (:func:`sum_over_chunks`); see :func:`_normal_equations`."""
    return sum_over_chunks(problem, lambda part: _normal_equations(part, u))


def half_squared_norm(problem: Problem, u: dict):
    """½‖r‖² at ``u``, summed chunk by chunk for a large grid (:func:`sum_over_chunks`)."""

    def one(part):
        r = _residual(u, part.y, part)
        return 0.5 * jnp.sum(r * r)

    return sum_over_chunks(problem, one)


DENSE_BAND_COLUMNS = 12
"""The normal equations are one product JᵀJ of the stacked Jacobian columns while the band
parameters' columns number at most this many (RGB: 3 per parameter); beyond (spectra), their
blocks are per-band sums (:func:`_normal_equations`)."""


def _normal_equations(problem: Problem, u: dict):
    """½‖r‖², Jᵀr and JᵀJ at ``u``, from the factored Jacobian (:func:`_columns`).

    The flat parameter order is that of ``jax.flatten_util.ravel_pytree(u)`` (sorted names,
    each entry flattened). The columns of the shape and scalar parameters are few: they are
    stacked (N × q, a shape parameter's J_S spread to its direction's samples). A band
    parameter's column e has ∂r_i/∂u[b] = e_i for the samples i of band b: with few bands
    (:data:`DENSE_BAND_COLUMNS`) it is spread into one column per band and the whole product
    is one JᵀJ; with many, its blocks are per-band sums and its blocks with band parameters
    diagonal, assembled and put into the flat order by a fixed permutation. Either way a
    handful of operations: the compiled program stays small (it loads and compiles in a
    fraction of the time of one operation per pair of parameters).
    """
    res, _, cols = _columns(problem, u, problem.y)
    names = sorted(u)
    banded = [k for k in names if cols[k][0] == "band"]
    if len(banded) * problem.fixed_bands <= DENSE_BAND_COLUMNS:
        jac = jnp.concatenate([_spread(problem, *cols[k]).reshape(res.shape[0], -1) for k in names] or [jnp.zeros((res.shape[0], 0), res.dtype)], axis=1)
        return 0.5 * jnp.sum(res * res), jac.T @ res, jac.T @ jac
    r = res.reshape(problem.y.shape)
    stacked = [k for k in names if cols[k][0] != "band"]
    jd = jnp.concatenate([_spread(problem, *cols[k]) for k in stacked] or [jnp.zeros((*r.shape, 0), r.dtype)], axis=-1)
    flat_jd = jd.reshape(-1, jd.shape[-1])
    grad = [flat_jd.T @ res] + [_band_sum(problem, cols[k][1] * r) for k in banded]
    sides = [_band_sum(problem, jd * cols[k][1][..., None]) for k in banded]  # (W, q) each
    rows = [jnp.concatenate([flat_jd.T @ flat_jd] + [side.T for side in sides], axis=1)]
    for ki, side in zip(banded, sides):
        rows.append(jnp.concatenate([side] + [jnp.diag(_band_sum(problem, cols[ki][1] * cols[kj][1])) for kj in banded], axis=1))
    order = _flat_order(u, stacked + banded)
    return 0.5 * jnp.sum(res * res), jnp.concatenate(grad)[order], jnp.concatenate(rows, axis=0)[order][:, order]


def _spread(problem: Problem, kind: str, col):
    """A parameter's Jacobian columns in the problem's layout + (size,): a shape parameter's J_S
    at each sample's direction, a band parameter's column one per band (zero off its band)."""
    if kind == "scalar":
        return col[..., None]
    if kind == "band":
        one_hot = jnp.eye(problem.fixed_bands, dtype=col.dtype)
        return col[..., None] * (one_hot[None] if problem.spec.grid else one_hot[problem.band])
    a, js = col
    return a[..., None] * (js[:, None, :] if problem.spec.grid else js[problem.pair])


def _flat_order(u: dict, assembled: list[str]) -> np.ndarray:
    """Indices into the blocks assembled in the order of ``assembled`` (each name's entries
    flattened) that give ``ravel_pytree(u)``'s order (sorted names)."""
    start, at = {}, 0
    for k in assembled:
        start[k], at = at, at + int(np.size(u[k]))
    return np.concatenate([start[k] + np.arange(int(np.size(u[k]))) for k in sorted(u)] or [np.zeros(0, int)])


@jax.custom_jvp
def _residual(u: dict, y, problem: Problem):
    return loss_residuals(problem, model_values(problem, u), y)


@_residual.defjvp
def _residual_jvp(primals, tangents):
    u, y, problem = primals
    tu, ty, _ = tangents  # the problem (geometry, weights) is data: no derivative through it
    res, values, cols = _columns(problem, u, y)
    dres = 0
    for name, (kind, col) in cols.items():
        t = tu[name]
        if kind == "shape":
            a, js = col
            ds = js @ t.reshape(-1)
            dres = dres + a * (ds[:, None] if problem.spec.grid else ds[problem.pair])
        elif kind == "scalar":
            dres = dres + col * t
        else:
            dres = dres + col * (t if problem.spec.grid else t[problem.band])
    dres = jnp.reshape(dres, (-1,)) if cols else jnp.zeros_like(res)
    # Data tangent: ∂r/∂y.
    _, dres_dy = jax.jvp(lambda yy: loss_residuals(problem, values, yy), (y,), (ty,))
    return res, dres + dres_dy


def residual(u: dict, args):
    """optimistix residual function: ``args = (y, problem)``; returns the flat residual vector."""
    y, problem = args
    return _residual(u, y, problem)
