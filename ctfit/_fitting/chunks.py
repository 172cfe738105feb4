"""Sizes and chunks: the size buckets of a compiled program's data, the chunks a fit is cut into,
and sums and maps over the chunks of a problem inside one program."""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp

if TYPE_CHECKING:
    from .problem import Problem

__all__ = ["BUCKET_MIN", "CHUNK", "MIN_CHUNKS", "bucket", "chunk_padding", "chunk_rows", "chunk_count", "sum_over_chunks", "map_over_chunks"]


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

        def grid_part(x):
            geom, y, sigma, cos_i, mask = x
            return dataclasses.replace(problem, geom=geom, y=y, sigma=sigma, cos_i=cos_i, mask=mask)

        return (jax.tree.map(split, problem.geom), *cells), grid_part
    if problem.pair is None:  # each sample its own direction pair: the geometry is cut as the samples are

        def own_part(x):
            geom, band, y, sigma, cos_i, mask = x
            return dataclasses.replace(problem, geom=geom, band=band, y=y, sigma=sigma, cos_i=cos_i, mask=mask)

        return (jax.tree.map(split, problem.geom), split(problem.band), *cells), own_part
    rows = (split(problem.pair), split(problem.band), *cells)

    def part(x):
        pair, band, y, sigma, cos_i, mask = x
        geom = jax.tree.map(lambda a: a[pair], problem.geom)  # each sample its own pair's geometry (``pair`` None)
        return dataclasses.replace(problem, geom=geom, pair=None, band=band, y=y, sigma=sigma, cos_i=cos_i, mask=mask)

    return rows, part


def sum_over_chunks(problem: Problem, fn):
    """Σ ``fn(part)`` over the parts of ``problem`` of ``CHUNK`` rows each (:func:`chunk_count`), as a
    ``lax.scan`` — or ``fn(problem)`` when it is not chunked. ``fn`` returns a pytree of arrays that
    add up: sums over samples (½‖r‖², Jᵀr, JᵀJ, per-band sums)."""
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

