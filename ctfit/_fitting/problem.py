"""The least-squares problem: the data laid out as the model evaluates it, with the static
description of the fit, and the model's values in that layout.

The residual's Jacobian (:mod:`ctfit._fitting.jacobian`), the free coordinates
(:mod:`ctfit._fitting.coordinates`), the losses (:mod:`ctfit._fitting.losses`) and the chunks
(:mod:`ctfit._fitting.chunks`) have modules of their own.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._model import STATIC, Geometry, Measurement, Params, Structure, combine_parts, format_value, geometry_from_angles_deg, pytree, specular_geometric
from .chunks import bucket, chunk_padding
from .coordinates import free_names, to_params
from .losses import LOSSES, loss_floor
from .validate import sample_error

__all__ = ["Spec", "Problem", "SHAPE_PARAMETERS", "at_samples", "band_sum", "geometry_deg", "make_problem", "model_parts", "model_values", "per_direction",
           "shape_and_rest", "values_from_s"]

SHAPE_PARAMETERS = ("m", "w")
"""The parameters of S, the per-direction factor of the specular term (everything in R_s but F)."""


@dataclasses.dataclass(frozen=True)
class Spec:
    """Static description of a fit: structure, which parameters are free, loss, data layout."""

    structure: Structure
    free: tuple[str, ...]
    loss: str
    grid: bool
    space: str = "box"


@pytree
@dataclasses.dataclass(frozen=True, eq=False)
class Problem:
    """Data and static spec of one fit. Arrays are laid out as the model evaluates them:

    grid layout: values (D, W) with a boolean ``mask`` (False for missing (pair, band) cells),
    ``cos_i`` (D, 1) (None unless the loss weights by cos θ_i);
    pairs layout: values (N,) with ``pair`` and ``band`` indices per sample (``mask`` False for
    padding); ``pair`` None where each sample has its own direction pair (the geometry per
    sample: the fit's chunks), so nothing is gathered or summed per pair.
    """

    spec: Spec = dataclasses.field(metadata=STATIC)
    geom: Geometry
    y: jax.Array
    sigma: jax.Array | None
    cos_i: jax.Array | None
    mask: jax.Array
    pair: jax.Array | None
    band: jax.Array | None
    floor: jax.Array
    fixed: Params
    fixed_bands: int = dataclasses.field(metadata=STATIC)



def _geometry_fields(pairs) -> dict:
    g = geometry_from_angles_deg(pairs[:, 0], pairs[:, 1], pairs[:, 2], pairs[:, 3], xp=np)
    return {f.name: getattr(g, f.name) for f in dataclasses.fields(g)}


GEOMETRY_BLOCK = 1 << 16
"""Direction pairs whose geometry is computed at once on the host (:func:`geometry_deg`): a few
MB of NumPy temporaries, however many pairs a file has."""


_recent_geometry: dict = {}  # content digest of a small set of pairs → its geometry (host arrays)
RECENT_GEOMETRY_PAIRS = 16384
"""Geometry of at most this many direction pairs is kept for the next fit of the same pairs (the
data-chosen default fits several structures to one screening sample); the last 4 kept."""


def geometry_deg(pairs, on_host: bool = False) -> Geometry:
    """The :class:`Geometry` of direction pairs (θ_i, φ_i, θ_o, φ_o) in degrees, shape (D, 4), in
    the pairs' dtype: computed on the host in NumPy (:func:`~ctfit.geometry_from_angles_deg`),
    :data:`GEOMETRY_BLOCK` pairs at a time, and left there with ``on_host`` (else on the device).
    As a program (per dtype, made in every first run), it took 0.25 s of a first fit's time,
    before any other program could start. The geometry of a few small sets of pairs is kept for
    their next fit."""
    pairs = np.asarray(pairs)
    n = len(pairs)
    put = (lambda a: a) if on_host else jax.device_put
    key = (pairs.dtype.str, pairs.shape, hashlib.blake2b(np.ascontiguousarray(pairs).tobytes(),
                                                         digest_size=16).digest()) if 0 < n <= RECENT_GEOMETRY_PAIRS else None
    fields = _recent_geometry.pop(key, None)
    if fields is None:
        blocks = [pairs[b: b + GEOMETRY_BLOCK] for b in range(0, n, GEOMETRY_BLOCK)] or [pairs]
        with np.errstate(divide="ignore", invalid="ignore"):  # (stand-ins make every value finite; NumPy's checks are not needed)
            parts = [_geometry_fields(block) for block in blocks]
        fields = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        for v in fields.values():
            v.setflags(write=False)  # shared by the fits of these pairs
    if key is not None:
        _recent_geometry[key] = fields  # the most recently used last
        for old in list(_recent_geometry)[:-4]:
            _recent_geometry.pop(old, None)  # (a background fit may prune too)
    return Geometry(**{k: put(v) for k, v in fields.items()})


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
    _check_fittable_by(data, loss)
    pairs, index = data.directions()
    n_pairs, n_bands = len(pairs), data.n_bands
    grid = n_pairs * n_bands <= 1.5 * len(data) and not data.repeats  # a grid cell holds one sample
    own = not grid and n_pairs == len(data)  # every sample its own direction pair (scattered data): ``pair`` None
    pad_to, pad = (chunk_padding(grid, n_pairs, len(data), n_bands, chunk) if chunk else pad_to), pad or pad_to is not None or bool(chunk)
    if pad_to is not None and (pad_to[0] < n_pairs or pad_to[1] < len(data)):
        raise ValueError(f"{data.source}: pad_to={pad_to} is smaller than the data ({n_pairs} direction pairs, {len(data)} samples)")
    if own:  # the geometry in the samples' order, padded as they are
        pairs, pad_to = pairs[index], None if pad_to is None else (pad_to[1], pad_to[1])
    if pad and n_pairs:
        pairs = np.concatenate([pairs, np.broadcast_to(pairs[:1], ((pad_to[0] if pad_to else bucket(n_pairs)) - n_pairs, 4))])
    put = (lambda a: a) if chunk else jax.device_put  # chunked, the per-row arrays stay on the host
    geom = geometry_deg(np.asarray(pairs, dtype=jnp.dtype(dtype)), on_host=bool(chunk))
    floor = loss_floor(data.brdf, loss)
    cos_pair = np.cos(np.deg2rad(pairs[:, 0]))
    sig: np.ndarray | None = None
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
        padded = lambda a, fill: np.concatenate([np.asarray(a), np.full(extra, fill, np.asarray(a).dtype)])
        y, mask = padded(data.brdf, 0.0), padded(np.ones(len(data), dtype=bool), False)
        sig = padded(data.sigma, 1.0) if data.sigma is not None else None
        cos_i = padded(cos_pair[: len(data)] if own else cos_pair[index], 1.0) if loss in ("cosine", "log") else None
        pair, band = None if own else put(padded(index, 0)), put(padded(data.band, 0))  # no conversion program
    spec = Spec(structure=structure, free=free_names(structure, fixed), loss=loss, grid=grid, space=space)
    to = lambda a: None if a is None else jnp.asarray(a, dtype=dtype)
    rows: Callable[[Any], Any] = (lambda a: None if a is None else np.asarray(a, dtype=jnp.dtype(dtype))) if chunk else to
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
        fixed=jax.tree.map(to, used_params(structure, fixed_params)),
        fixed_bands=n_bands,
    )


def used_params(structure: Structure, params: Params) -> Params:
    """``params`` with the fields ``structure`` does not use set to None (the convention of
    :class:`~ctfit.Params`): what a fit holds fixed. A fit's result reports the effective index
    n beside F0; a fit started from it must compile and load the programs of a fit started from
    anywhere else (the data-chosen default's final fit and its candidate's: one ``fit_ne``).

    >>> import numpy as np, ctfit
    >>> p = ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.9]), n=np.array([37.0]))
    >>> used_params(ctfit.Structure(lobes=1, diffuse=None), p).n is None
    True
    """
    used = set(free_names(structure)) | ({"w"} if structure.has_specular else set())
    return dataclasses.replace(params, **{f.name: None for f in dataclasses.fields(params) if f.name not in used})


def _check_fittable_by(data: Measurement, loss: str) -> None:
    """A ``ValueError`` naming the file where ``data`` cannot be fitted with ``loss`` at all."""
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
    if data.brdf is None:
        raise ValueError(f"{data.source}: the data has no 'brdf' column to fit")
    if loss == "sigma" and data.sigma is None:
        raise ValueError(f"{data.source}: loss 'sigma' needs a 'sigma' column")
    if loss == "sigma":
        bad = np.flatnonzero(~(np.asarray(data.sigma) > 0) | ~np.isfinite(data.sigma))
        if bad.size:  # (a Measurement refuses them when made: these were changed in place since)
            raise sample_error(data, int(bad[0]), "sigma", f"{format_value(data.sigma[bad[0]])}: loss 'sigma' needs every sigma finite and > 0; "
                               f"{bad.size} of {len(data)} samples are not; drop them or choose another loss")


def _gather_bands(params: Params, band) -> Params:
    def g(a):
        return a if a is None or jnp.ndim(a) == 0 else a[band]

    return Params(s=params.s, m=params.m, w=params.w, f0=g(params.f0), n=g(params.n), k=g(params.k), rd=g(params.rd))


def per_direction(problem: Problem, u_shape: dict, u_rest: dict):
    """S per unique direction pair (everything in R_s but F)."""
    params = to_params(problem.spec, {**u_shape, **u_rest}, problem.fixed)
    return specular_geometric(problem.spec.structure, params, problem.geom)


def values_from_s(problem: Problem, s_dir, u_rest: dict, u_shape: dict):
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
    at = lambda a: at_samples(problem, a)
    spec_v = None if s_dir is None else at(s_dir)
    cos_lv = (at(geom.cos_l), at(geom.cos_v)) if transmitted else None
    return combine_parts(spec.structure, p, at(geom.valid), spec_v, at(geom.cos_vh), cos_lv)


def at_samples(problem: Problem, x):
    """A per-direction array (pairs layout) at every sample: ``x[pair]``, or ``x`` itself where
    ``pair`` is None (each sample its own direction pair: the fit's chunks)."""
    return x if problem.pair is None else x[problem.pair]


def band_sum(problem: Problem, x):
    """Σ over the samples of each band: (W, …) from a layout-shaped array (… its trailing axes)."""
    if problem.spec.grid:
        return jnp.sum(x, axis=0)
    return jax.ops.segment_sum(x, problem.band, num_segments=problem.fixed_bands)  # type: ignore[arg-type]  # set when not grid


def shape_and_rest(u: dict) -> tuple[dict, dict]:
    """``u`` split into the free values of S (:data:`SHAPE_PARAMETERS`) and the others."""
    return {k: v for k, v in u.items() if k in SHAPE_PARAMETERS}, {k: v for k, v in u.items() if k not in SHAPE_PARAMETERS}


def _split(problem: Problem, u: dict):
    """(S per direction or None, the free values of S, the others)."""
    u_shape, u_rest = shape_and_rest(u)
    s_dir = per_direction(problem, u_shape, u_rest) if problem.spec.structure.has_specular else None
    return s_dir, u_shape, u_rest


def model_values(problem: Problem, u: dict):
    """The model at every sample (problem layout), from the free values ``u``."""
    s_dir, u_shape, u_rest = _split(problem, u)
    return values_from_s(problem, s_dir, u_rest, u_shape)


def model_parts(problem: Problem, u: dict):
    """The model's two parts at every sample, (s R_s, d R_d) (Eq. 2's terms; the second is the
    model with its specular factor zeroed, 0 without a diffuse part; the first 0 without a
    specular part); their sum is :func:`model_values`."""
    s_dir, u_shape, u_rest = _split(problem, u)
    v = values_from_s(problem, s_dir, u_rest, u_shape)
    diffuse = v if s_dir is None else values_from_s(problem, jnp.zeros_like(s_dir), u_rest, u_shape)
    return v - diffuse, diffuse

