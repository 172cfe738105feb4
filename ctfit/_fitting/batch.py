"""Many measurements in one compiled program: ``fit_batch(measurements, structure, ...)``.

Each measurement is prepared as :func:`~ctfit.fit` prepares it (checks, start, problem, free
start, grid of m). Measurements whose problems have the same layout — structure, loss, grid or
pairs layout, bands, which data columns exist, dtype — form a group; inside a group every
problem is padded to the group's largest number of direction pairs and samples (masked-out
entries, as ``make_problem(pad=True)`` pads to a size bucket) and stacked along a new leading
axis, and one program maps the single fit's program (``fit_core``) over them: ``width``
members side by side (``jax.vmap``), those groups in sequence (:func:`mapped`). Groups are
split into calls of at most :data:`SAMPLE_BUDGET` padded cells, and a call's batch size is
rounded up to a size of the series ⌈2^(k/2)⌉ (1, 2, 3, 4, 6, 8, 12, 16, 23, 32, …) with
inactive copies of its first member, so that a folder of 37 files and one of 40 share one
compiled program (stored on disk like a single fit's, :mod:`ctfit._runtime.stored_programs`). A group of one runs
the single-fit program itself.

With the solver "lm" and ``width`` 1 (the default on a CPU), the measurements are fitted one
after the other, each on chunks of one shape (:mod:`~ctfit._fitting.chunked_fit`): every size
shares the structure's compiled programs, and nothing is padded to the group's largest. Groups
of measurements of one geometry (:func:`~ctfit._fitting.shared_geometry.shared_groups`) are
fitted together instead, many to a program call (:func:`~ctfit._fitting.shared_geometry.fit_shared`).

Members side by side share one ``while_loop``: it ends when the slowest of them is done
(finished members are carried unchanged) and both sides of the solver's branches are computed
for all, which is correct and pays on an accelerator; on a CPU the members run one after the
other by default (:func:`default_width`). The report of each measurement (statistics, standard
errors, warnings, residual structure) is made exactly as :func:`~ctfit.fit` makes it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, TypeVar

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._model import Measurement, Structure
from .._runtime import cached_call
from .chunked_fit import ROWS
from .least_squares import FitResult, PreparedFit, finish_fit, fit, fit_core, prepare_fit, solve_prepared
from .options import takes_fit_options
from .problem import Problem

if TYPE_CHECKING:  # texels imports this module
    from .texels import TexelFits

__all__ = ["fit_batch", "mapped", "default_width", "batch_size", "SAMPLE_BUDGET"]

SAMPLE_BUDGET = 2**21
"""Padded samples (grid cells or pairs-layout samples) per batched call, all members together:
bounds the memory of one call (a few hundred bytes per cell in the solver's intermediates)."""


@takes_fit_options(fit)
def fit_batch(
    measurements: Sequence[Measurement],
    structure: Structure | None = None,
    *,
    values: Float[np.ndarray, "texels samples"] | None = None,
    return_errors: bool = False,
    width: int | None = None,
    **options: Any,
) -> list[FitResult | Exception] | TexelFits:
    """Fit ``structure`` to every measurement, in as few compiled programs as possible.

    Returns one :class:`~ctfit.FitResult` per measurement, in input order, each what
    :func:`~ctfit.fit` gives for it alone (to the solver's tolerance); ``stats["time_s"]`` is
    the batch's wall time shared equally. ``start``: one :class:`~ctfit.Params` for all, or a
    sequence with one (or None) per measurement; the other arguments as for :func:`~ctfit.fit`.
    ``return_errors``: a measurement that cannot be fitted (its ``ValueError``) is returned in
    its place instead of raised, so the others still go on. ``width``: fits solved side by side
    (vmapped) inside a program, the rest in sequence; None: :func:`default_width`. With
    ``values`` (texels × samples) and one measurement, the per-texel fit
    :func:`~ctfit.fit_texels` of that geometry: returns its :class:`~ctfit.TexelFits`.

    >>> import numpy as np, ctfit
    >>> def gold(m):
    ...     return ctfit.Material(ctfit.Structure(lobes=1, diffuse=None),
    ...                           ctfit.Params(m=np.array([m]), w=np.ones(1), f0=np.array([0.4, 0.9])),
    ...                           wavelength_nm=np.array([450.0, 650.0]))
    >>> results = ctfit.fit_batch([ctfit.simulate(gold(m), n_pairs=300, seed=1) for m in (0.2, 0.35)], gold(0.2).structure)
    >>> [round(float(r.material.params.m[0]), 4) for r in results]
    [0.2, 0.35]
    """
    if values is not None:
        from .texels import fit_texels

        data = measurements if isinstance(measurements, Measurement) else _single(measurements)
        return fit_texels(data, values, structure, width=width, **options)
    start, solver, max_steps = options.pop("start"), options.pop("solver"), options.pop("max_steps")
    t0 = time.perf_counter()
    width = default_width() if width is None else width
    if width < 1:
        raise ValueError(f"width must be ≥ 1, got {width}")
    measurements = list(measurements)
    begins = list(start) if isinstance(start, (list, tuple)) else [start] * len(measurements)
    if len(begins) != len(measurements):
        raise ValueError(f"start: {len(begins)} starting values for {len(measurements)} measurements")
    results: list = [None] * len(measurements)
    preps: dict[int, PreparedFit] = {}
    chunked = solver == "lm" and width == 1  # one after the other: each on chunks, sharing their programs
    together = _fit_together(measurements, begins, results, structure, solver, max_steps, return_errors, options) if chunked else set()
    for i, (data, begin) in enumerate(zip(measurements, begins)):
        if i in together:
            continue
        got = _caught(lambda: prepare_fit(data, structure, start=begin, chunk=ROWS if chunked else None, **options), return_errors)
        if isinstance(got, Exception):
            results[i] = got
        elif chunked:
            results[i] = _caught(lambda: finish_fit(got, solve_prepared(got, solver, max_steps), solver, time.perf_counter(), max_steps=max_steps),
                                 return_errors)
        else:
            preps[i] = got
    for group in _groups(preps, solver, max_steps):
        for call in _calls(group, preps):
            outs: Any = _caught(lambda: _solve([preps[i] for i in call], solver, max_steps, width), return_errors)
            for i, out in zip(call, outs if isinstance(outs, list) else [outs] * len(call)):
                results[i] = out if isinstance(out, Exception) else _caught(
                    lambda: finish_fit(preps[i], out, solver, time.perf_counter(), max_steps=max_steps), return_errors)
    share = (time.perf_counter() - t0) / max(len(measurements), 1)
    for r in results:
        if isinstance(r, FitResult):
            r.stats["time_s"] = share
    return results


def _fit_together(measurements: list, begins: list, results: list, structure: Structure | None, solver: str, max_steps: int, return_errors: bool,
                  options: dict) -> set[int]:
    """Fit the groups of one geometry (:func:`~ctfit._fitting.shared_geometry.shared_groups`) a
    program call for many, their results into ``results``; the indices fitted."""
    from .shared_geometry import fit_shared, shared_groups

    together: set[int] = set()
    for group in shared_groups(measurements, begins):
        shared = fit_shared([measurements[i] for i in group], structure, start=begins[group[0]], solver=solver, max_steps=max_steps,
                            return_errors=return_errors, **options)
        if shared is None:  # too few to pay for compiling their layout's program: one by one, on chunks
            continue
        for i, res in zip(group, shared):
            results[i] = res
        together.update(group)
    return together


_T = TypeVar("_T")


def _caught(work: Callable[[], _T], return_errors: bool) -> _T | Exception:
    """``work()``, or with ``return_errors`` the ``ValueError`` it raised."""
    try:
        return work()
    except ValueError as e:
        if not return_errors:
            raise
        return e


def _single(measurements: Sequence[Measurement] | Measurement) -> Measurement:
    items = list(measurements)
    if len(items) != 1:
        raise ValueError(f"values (per-texel fitting) needs one measurement giving the geometry, got {len(items)}")
    return items[0]


def _sizes(prep: PreparedFit) -> tuple[int, int]:
    """(direction pairs, samples) of a prepared problem as padded; samples: the data's in the grid layout."""
    problem = prep.problem
    return problem.geom.cos_vh.shape[0], (len(prep.data) if problem.spec.grid else problem.y.shape[0])


def _layout(prep: PreparedFit, solver: str, max_steps: int) -> tuple:
    """What must be equal for two fits to share a program, up to the padded sizes."""
    shapes = lambda tree: tuple((a.shape, a.dtype.name) for a in jax.tree.leaves(tree))
    grid = None if prep.grid is None else prep.grid.shape
    return (jax.tree.structure(prep.problem), shapes(prep.problem.fixed), jax.tree.structure(prep.u0), shapes(prep.u0), grid,
            prep.options(solver, max_steps))


def _signature(prep: PreparedFit) -> tuple:
    """Every array's shape and dtype (and the tree): equal for members of one batched call."""
    return jax.tree.structure(prep.problem), tuple((a.shape, a.dtype.name) for a in jax.tree.leaves((prep.problem, prep.u0)))


def _groups(preps: dict[int, PreparedFit], solver: str, max_steps: int) -> list[list[int]]:
    """Indices of the fits that share a program; members are padded (in ``preps``) to the
    group's largest sizes."""
    by_layout: list[tuple[object, list[int]]] = []
    for i, prep in preps.items():
        key = _layout(prep, solver, max_steps)
        for k, members in by_layout:
            if k == key:
                members.append(i)
                break
        else:
            by_layout.append((key, [i]))
    groups = []
    for _, members in by_layout:
        if len(members) > 1:
            target = (max(_sizes(preps[i])[0] for i in members), max(_sizes(preps[i])[1] for i in members))
            for i in members:
                if _sizes(preps[i]) != target:
                    preps[i] = preps[i].padded(target)
        by_shape: dict = {}
        for i in members:  # the same layout pads to the same shapes; kept apart if not
            by_shape.setdefault(_signature(preps[i]), []).append(i)
        groups += list(by_shape.values())
    return groups


def batch_size(n: int) -> int:
    """The batch size that ``n`` fits are run at: the smallest ⌈2^(k/2)⌉ ≥ n (at most 41 % padding)."""
    k = 0
    while math.ceil(2 ** (k / 2)) < n:
        k += 1
    return math.ceil(2 ** (k / 2))


def _calls(group: list[int], preps: dict[int, PreparedFit]) -> list[list[int]]:
    """The group cut into calls of about equal size, each of at most :data:`SAMPLE_BUDGET` padded samples."""
    per_call = max(1, SAMPLE_BUDGET // max(preps[group[0]].problem.y.size, 1))
    n_calls = math.ceil(len(group) / per_call)
    size = math.ceil(len(group) / n_calls)
    return [group[a: a + size] for a in range(0, len(group), size)]


def default_width() -> int:
    """Fits solved side by side by default: 1 on a CPU (in sequence, inside the one program),
    all of a call (2³⁰) on an accelerator. On a CPU a vmapped solve costs more per fit than
    one after the other — every member computes both sides of the solver's branches (accepted
    and rejected steps) and runs until the slowest member is done — while a GPU runs the
    batch in the time of one fit."""
    return 1 if jax.default_backend() == "cpu" else 1 << 30


def mapped(fn: Callable[[Any], Any], xs: Any, active: Array, width: int) -> Any:
    """``fn`` over the leading axis of the pytree ``xs``, ``width`` members side by side
    (``jax.vmap``) and those groups in sequence (``jax.lax.map``). A member whose ``active`` is
    False (padding) is skipped where it runs alone; side by side it is computed and discarded."""
    n = active.shape[0]

    def one(args: Any) -> Any:
        x, on = args
        out = jax.eval_shape(fn, x)
        return jax.lax.cond(on, fn, lambda _: jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), out), x)

    if width >= n:
        return jax.vmap(fn)(xs)
    return jax.lax.map(one, (xs, active), batch_size=width if width > 1 else None)


def _solve(preps: list[PreparedFit], solver: str, max_steps: int, width: int) -> list[dict]:
    """``fit_core``'s output (host arrays) for each of ``preps`` (equal signatures): one call."""
    first = preps[0]
    options = first.options(solver, max_steps)
    if len(preps) == 1:
        return [jax.device_get(cached_call("fit", fit_core, first.problem, first.u0, first.grid, *options))]
    size = batch_size(len(preps))
    members = preps + [first] * (size - len(preps))
    stack = lambda *xs: np.stack(xs)  # on the host: no small programs to compile
    problems = jax.tree.map(stack, *(p.problem for p in members))
    u0s = jax.tree.map(stack, *(p.u0 for p in members))
    active = np.arange(size) < len(preps)
    width = min(width, size)
    out = jax.device_get(cached_call("fit_batch", _batched_core, problems, u0s, active, first.grid, width, *options))
    return [jax.tree.map(lambda a: a[i], out) for i in range(len(preps))]


def _batched_core(problems: Problem, u0s: dict, active: Array, grid: Any, width: int, *options: Any) -> Any:
    """``fit_core`` over stacked problems and starts (the m grid shared), :func:`mapped`."""
    return mapped(lambda pu: fit_core(pu[0], pu[1], grid, *options), (problems, u0s), active, width)
