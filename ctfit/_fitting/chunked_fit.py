"""The Levenberg–Marquardt fit on chunks of one fixed shape: one set of compiled programs per
structure, whatever the number of samples.

A measurement is laid out (``make_problem(chunk=ROWS)``) with its rows padded to a multiple of
the chunk's (samples in the pairs layout, each with its own geometry; direction pairs × bands in
the grid layout) and cut into chunks of that one shape. Everything that reads the data is a
*chunk kernel*, compiled once per structure (spec, bands, dtype) and called over the chunks of
any file, each adding its share to a running sum on the device (calls are queued, not awaited):

- ``fit_ne``: ½‖r‖², Jᵀr and JᵀJ at a flat parameter vector, and the chunk's model values there
  (:func:`~ctfit._fitting.jacobian.normal_equations_and_values`): the residual summary of the
  report is made from those at the solution, on the host (:func:`_summary`);
- ``fit_grid_sums``: the sums the seeds' scores are made of (:func:`~ctfit._fitting.starts.grid_sums`;
  the scores from them, :func:`~ctfit._fitting.starts.grid_costs`, and the seeds are chosen on the
  host, in NumPy: :func:`_seed_choice`);
- ``fit_zero``: the cost of a zero model, with no structure in it (one program per loss, layout
  and bands, shared by every structure).

The report is made on the host from the sums at the solution (:func:`~ctfit._fitting.fit_report.report_core`
with ``xp=numpy``; :func:`~ctfit._fitting.fit_report.light_report_core` without the standard
errors): no program per structure (as one, ``fit_report``, it took about 1.2 s of a first fit's
CPU: 0.4 s tracing, 0.3 s lowering, 0.6 s compiling). Programs whose shapes depend only on the
number of parameters: optimistix's solver itself (:func:`~ctfit._fitting.seeded_solve.lm_solver`), ``lm_init`` and
``lm_step``, one step of ``StructuredLevenbergMarquardt`` given the cost, Jᵀr and JᵀJ at the
point it evaluates, compiled per number of parameters and shared by every structure. The host
runs optimistix's iteration (init, step until it terminates) and the race of the seeds as the
compiled ``_structured_lm`` does (the seeds of each phase side by side, in threads), so results
agree with it to rounding.

All programs go through the program store (:func:`~ctfit._runtime.stored_program`), so a new
process loads them; a file of a new size compiles nothing.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import math
import weakref
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from .._model import Params, Structure, array_leaves, is_array, split_arrays
from .._runtime import shipped, stored_program
from .coordinates import bounds, flat_host, fraction_weights
from .fit_report import combined_rms, light_report_core, report_core, summary_of_values
from .jacobian import normal_equations_and_values
from .losses import zero_model_cost
from .problem import Problem, Spec
from .seeded_solve import RACE_MARGIN, RACE_STEPS, lm_solver, stop_tolerances
from .starts import best_splits, grid_sums, grid_sums_shape, seeds_from_scores

__all__ = ["ROWS", "RACE_CHUNKS", "PARAMETER_STEP", "chunk_problems", "chunked_core", "prefetch", "race_rows", "shipped_solver_arguments"]

ROWS = 2048
"""Cells per chunk: samples of the pairs layout; the grid layout takes a power of two of
direction pairs with about this many cells (:func:`~ctfit._fitting.chunks.chunk_rows`)."""


def chunk_problems(problem: Problem, limit: int | None = None, rows_of: np.ndarray | None = None) -> list[Problem]:
    """``problem`` (rows a multiple of the chunk's: ``make_problem(chunk=ROWS)``) cut into
    problems of one shape, on the host (the first ``limit`` of them); ``rows_of``: only these
    rows (a multiple of the chunk's, e.g. :func:`race_rows`). Pairs layout: each chunk's
    samples carry their own direction pair's geometry (``pair`` None)."""
    rows = _rows(problem)
    if rows_of is not None:  # the rows' cells; a grid's rows are direction pairs, so their geometry too
        take = lambda a: None if a is None else np.asarray(a)[rows_of]
        cells: dict[str, Any] = {k: take(getattr(problem, k)) for k in ("y", "sigma", "cos_i", "mask", "band", "pair")}
        per_row = problem.spec.grid or problem.pair is None  # the geometry is the rows' own
        problem = dataclasses.replace(problem, **cells, **({"geom": jax.tree.map(take, problem.geom)} if per_row else {}))
    host = lambda a: None if a is None else np.asarray(a)
    y = np.asarray(problem.y)
    sigma, cos_i, mask = (host(a) for a in (problem.sigma, problem.cos_i, problem.mask))
    geom = jax.tree.map(np.asarray, problem.geom)
    count = y.shape[0] // rows if limit is None else min(limit, y.shape[0] // rows)
    pair, band = host(problem.pair), host(problem.band)
    grid = problem.spec.grid

    def host_chunk(c: int) -> tuple:
        cut = slice(c * rows, (c + 1) * rows)
        at = (lambda a: a[cut]) if grid or pair is None else (lambda a: a[pair[cut]])
        return _chunk_arrays(jax.tree.map(at, geom), *(None if a is None else a[cut] for a in (y, sigma, cos_i, mask, None if grid else band)))

    def problem_of(g, cells: dict) -> Problem:
        if grid:
            del cells["band"]
            return dataclasses.replace(problem, geom=g, **cells)
        return dataclasses.replace(problem, geom=g, pair=None, **cells)  # each sample its own pair's geometry

    if count == 0:
        return []
    first = host_chunk(0)
    first_dev = jax.device_put(first)
    template = problem_of(*first_dev)
    if count == 1:
        return [template]
    return [template, *_more_chunks(template, jax.tree.leaves(first_dev), map(host_chunk, range(1, count)))]


def _chunk_arrays(geom, y, sigma, cos_i, mask, band) -> tuple:
    """A chunk's own arrays (``band`` None in the grid layout), as one tree."""
    return geom, dict(y=y, sigma=sigma, cos_i=cos_i, mask=mask, band=band)


def _copies(*leaves):
    return list(leaves)


def transfer_program(template: Problem) -> Callable:
    """``chunk_put``: a program that returns its arguments, the arrays of one chunk like
    ``template``'s (:func:`_chunk_arrays`' leaves). The chunks after a fit's first go to the
    device through it: a compiled call takes host arrays at a few microseconds each, where
    ``jax.device_put`` costs about 55 µs an array here, and a chunk has about ten (a MERL
    table's 2,304 chunks: 1.3–1.5 s one array at a time, 0.7–1.0 s so). It depends on the
    layout alone; a structure's first fit makes it with its other programs, so a file of another
    size compiles nothing."""
    t = template
    leaves = jax.tree.leaves(_chunk_arrays(t.geom, t.y, t.sigma, t.cos_i, t.mask, None if t.spec.grid else t.band))
    return _program("chunk_put", _copies, *leaves)


def _more_chunks(template: Problem, first: list, chunks) -> list[Problem]:
    """The problems of ``chunks`` (host trees like the first chunk's, whose device arrays are
    ``first``), made from ``template`` (the first chunk's problem) by putting each chunk's
    arrays where the first's are in its leaves: no Equinox ``__init__`` per chunk (a quarter of a
    millisecond each)."""
    leaves, treedef = jax.tree.flatten(template)
    where = {id(a): i for i, a in enumerate(leaves)}
    slots = [where[id(a)] for a in first]  # a Problem holds the arrays it is given (tests/test_fit_chunks.py)
    put = transfer_program(template)
    out = []
    for tree in chunks:
        new = list(leaves)
        for i, a in zip(slots, put(*jax.tree.leaves(tree))):
            new[i] = a
        out.append(jax.tree.unflatten(treedef, new))
    return out


def _rows(problem: Problem) -> int:
    from .chunks import chunk_rows

    return chunk_rows(problem.spec.grid, problem.fixed_bands, ROWS)


RACE_CHUNKS = 8
"""The most chunks' rows a race on a sample runs on (16,384 samples of the pairs layout: data of
131,072 samples or more), :func:`race_rows`: the race's steps then cost what they cost on a file
of 16,384 samples, and only the winners go on over all the data."""

FEWEST_RACE_CHUNKS = 2
"""The fewest chunks' rows a race on a sample runs on (4,096 samples of the pairs layout). Data of
at least twice this many chunks (8,192 samples) races on a sample of about an eighth of its rows
(:data:`RACE_SHARE`), in whole chunks, from this many to :data:`RACE_CHUNKS`."""

RACE_SHARE = 8
"""Data of ``n`` chunks races on ``n // RACE_SHARE`` chunks' rows (within :data:`FEWEST_RACE_CHUNKS`
and :data:`RACE_CHUNKS`). A smaller sample makes each of the race's steps cheaper, but its
optimum lies farther from that of all the data, which the winners then reach in more steps over
all of it. On Mitsuba-rendered data the model cannot represent (four BSDFs, four structures
each), 180,000 samples raced on 4,096 took up to 3× the steps over all the data that they take
raced on 16,384. Against the sizes before (all of the data below 16,384 samples, half of it
below 32,768, then 16,384), 56 fits of 12,000 to 60,000 samples (those files, and scattered
samples) took 0.80× the time in one process, at the same cost within 2·10⁻⁹ in 52 of them; three
ended lower (0.27–2.4 %: another seed won) and one 0.018 % higher. 20,000 scattered samples race
on 4,096 (2 of their 10 chunks) and end where a race on all of them does."""

RACE_CLOSE = 0.01
"""Raced on a sample, every seed whose cost there is within this fraction of the lowest goes on
to convergence on all the data (a near tie on the sample may be decided otherwise on all of it);
the lowest cost on all the data wins."""


def race_rows(problem: Problem) -> np.ndarray | None:
    """The rows (sorted; random, seed 0) of ``problem`` where its seeds are chosen (the m grid's
    scores, also for one start) and several seeds raced: an eighth of its
    chunks' worth of rows holding data (:data:`RACE_SHARE`), from :data:`FEWEST_RACE_CHUNKS` to
    :data:`RACE_CHUNKS` chunks' worth, or None where the data is less than twice the fewest (then
    the seeds are raced on all of it). Rows are samples (pairs layout) or direction pairs with
    every band (grid layout)."""
    rows, mask = _rows(problem), np.asarray(problem.mask)
    real = np.flatnonzero(mask if mask.ndim == 1 else mask.any(axis=1))
    whole = real.size // rows
    if whole < 2 * FEWEST_RACE_CHUNKS:
        return None
    chunks = min(max(whole // RACE_SHARE, FEWEST_RACE_CHUNKS), RACE_CHUNKS)
    return np.sort(np.random.default_rng(0).choice(real, chunks * rows, replace=False))


_programs: dict = {}  # (name, shapes) → a weak reference to the program (the store's memory owns it)
_made: set = set()  # the signatures of fits whose programs were all made once in this process

SUM_PARTS = 2
"""A pass that sums over :data:`SPLIT_CHUNKS` chunks or more (the normal equations, the seeds'
scores) is made as this many chains of calls, the first half of the chunks and the second,
added at the end on the host: on a machine of two cores or more the chains run side by side (a
program runs on one core; measured here, 200,000 samples in 128 chunks: 48 ms a pass as one
chain, 38 ms as two). The additions are in the same order on every machine, so a fit does not
depend on its cores."""

SPLIT_CHUNKS = 16
"""Fewer chunks are summed in one chain on the device: there a pass costs a few milliseconds,
and the host's additions would cost more than a second core gains (a 20,000-sample race, 10
chunks: 0.22–0.25 s split against 0.17–0.22 s in one chain; the race's sample has 8)."""

_sum_pool: list = []  # the threads of the chains (made on first use where there are cores for them)


def _pool() -> concurrent.futures.ThreadPoolExecutor | None:
    if not _sum_pool:
        from .._io import usable_cores

        _sum_pool.append(concurrent.futures.ThreadPoolExecutor(SUM_PARTS, thread_name_prefix="ctfit-sums") if usable_cores() > 1 else None)
    return _sum_pool[0]


def chunk_sums(program: Callable, zeros: list, parts: list[list], rest: list, side_by_side: bool = True) -> tuple[list, list]:
    """``zeros`` + the sums ``program(*acc, *chunk, *rest)`` adds up over the chunks ``parts``
    (each its array leaves): as :data:`SUM_PARTS` chains from :data:`SPLIT_CHUNKS` chunks on
    (host arrays), as one below (device arrays). ``side_by_side`` False: the chains one after
    the other in this thread (seeds raced side by side keep the cores busy already), added in
    the same order. Returns (the sums, each chunk's outputs after its sums, in the chunks'
    order: a program may return more than the running sums)."""

    def chain(group: list[list]) -> tuple[list, list]:
        acc, kept = zeros, []
        for leaves in group:
            out = program(*acc, *leaves, *rest)
            acc = out[: len(zeros)]
            kept.append(out[len(zeros):])
        return acc, kept

    if len(parts) < SPLIT_CHUNKS:
        return chain(parts)
    half = -(-len(parts) // SUM_PARTS)
    groups = [parts[i: i + half] for i in range(0, len(parts), half)]
    pool = _pool() if side_by_side else None
    outs = [chain(g) for g in groups] if pool is None else list(pool.map(chain, groups))
    got = jax.device_get([acc for acc, _ in outs])
    total = list(got[0])
    for g in got[1:]:
        total = [a + b for a, b in zip(total, g)]
    return total, [k for _, kept in outs for k in kept]


def _signature(args) -> tuple:
    return jax.tree.structure(args), tuple((a.shape, a.dtype.name) if is_array(a) else a for a in jax.tree.leaves(args))


_EFFORT = {"fit_ne": "step", "fit_grid_sums": "step"}
"""The compile effort of each program (:data:`~ctfit._runtime.COMPILE_EFFORT`): "step" for the
kernels over a chunk (the normal equations at every Levenberg–Marquardt step, the seeds' sums),
"once" for the others (``lm_init``, the cost of a zero model: once per fit) and the
solver's step. A first fit's compiling is mostly these kernels' (a data-chosen
default makes them for each of its nine structures): at "step" ``fit_ne`` and ``fit_grid_sums``
compile in about half the CPU time of "run" (XLA's fusion emitters) and run a chunk as fast
where the fit calls them (whole processes: a MERL table 0.94×, 200,000 samples 0.99×; a first
fit of 20,000 samples 0.89×, a first data-chosen default 0.81×; docs/benchmarks.md). The seeds'
sums run on at most :data:`RACE_CHUNKS` chunks (the race's sample, :func:`race_rows`), where their
slower chunk (about 3 ms against 1 ms on 31 bands) costs less than the compile saves. ``lm_step``
at "step" took 0.87 s of compiling (40 parameters) and 0.33 ms a step, at "once" 0.25 s and
0.39 ms; a fit takes 20–45 steps. One effort per program whatever the data's size: a file of
another size compiles nothing. Since the Jacobian's columns are made once before the products
read them (:func:`~ctfit._fitting.jacobian._fenced`), ``fit_ne`` runs a chunk of 2,048 samples of
31 bands in 0.33 ms at "step" and 0.16 ms at "run", which compiles 0.35 s of CPU longer: a warm
fit of 200,000 samples took 0.88× the time at "run", one of 20,000 1.08× (6 and 8 pairs, whole
processes, 2026-12-06), where the larger program's load outweighs its steps; it stays at "step"."""


def _program(name: str, fn, *args):
    """:func:`~ctfit._runtime.stored_program`, looked up first under a key that is cheap to
    compute (the arguments' tree, shapes and dtypes): a database calls this a few times a file.
    Threads asking for one program at once (:func:`prefetch`) make it once (the store's lock)."""
    sig = (name, *_signature(args))
    ref = _programs.get(sig)
    run = ref() if ref is not None else None
    if run is None:  # not made yet, or dropped from the store's memory (MEMORY_PROGRAMS): held weakly here
        run = stored_program(name, fn, *args, effort=_EFFORT.get(name, "once"))
        # A program the store keeps in memory is held weakly (it owns it); one it cannot key (a
        # closure in the static part), held here as before, as nothing else keeps it.
        _programs[sig] = weakref.ref(run) if isinstance(run, jax.stages.Compiled) else (lambda run=run: run)
    return run


def _flat_shape(u0: dict) -> tuple[int, np.dtype]:
    """The size and dtype of ``ravel_pytree(u0)[0]``, on the host (an eager ``ravel_pytree``
    compiles a concatenation per shape, in every process)."""
    return int(sum(np.size(v) for v in u0.values())), np.result_type(*[np.asarray(v).dtype for v in u0.values()])


def _unflat(u0: dict, flat) -> dict:
    """``ravel_pytree``'s inverse on the host: the dict of ``u0``'s shapes from a flat vector."""
    out, at = {}, 0
    for k in sorted(u0):
        size = int(np.size(u0[k]))
        out[k] = np.reshape(flat[at: at + size], np.shape(u0[k]))
        at += size
    return out


PARAMETER_STEP = 8
"""The solver's programs (``lm_init``, ``lm_step``) take the flat parameter vector padded with
zeros to a multiple of this (padded coordinates have zero gradient and JᵀJ and the bounds
[0, 0], so every step leaves them at 0): structures with about as many parameters share them."""


def _padded_size(p: int) -> int:
    return -(-p // PARAMETER_STEP) * PARAMETER_STEP


def _ne_kernel(acc, part: Problem, flat, u0: dict):
    """``acc`` + (½‖r‖², Jᵀr, JᵀJ) of ``part`` at ``flat`` (padded: :data:`PARAMETER_STEP`), and
    the model's values on ``part`` there."""
    unflat = ravel_pytree(u0)[1]
    p, extra = ravel_pytree(u0)[0].shape[0], flat.shape[0] - ravel_pytree(u0)[0].shape[0]
    cost, grad, hess, values = normal_equations_and_values(part, unflat(flat[:p]), dense=True)
    return [acc[0] + cost, acc[1] + jnp.pad(grad, (0, extra)), acc[2] + jnp.pad(hess, ((0, extra), (0, extra))), values]


def _sums_kernel(acc, part: Problem, u0: dict, grid):
    return [a + b for a, b in zip(acc, grid_sums(part, u0, grid))]


def _zero_kernel(acc, part: Problem):
    return acc + zero_model_cost(part)


def _data_only(part: Problem) -> Problem:
    """``part`` with no structure in it (a metal of one lobe, nothing fixed, no geometry): what
    the cost of a zero model reads, so that one ``fit_zero`` serves every structure."""
    spec = Spec(structure=Structure(), free=(), loss=part.spec.loss, grid=part.spec.grid)
    return dataclasses.replace(part, spec=spec, geom=None, fixed=Params())


def _seed_choice(part: Problem, u0: dict, k: int, grid, num, den, keep_start: bool) -> dict:
    """The seeds, flat, and the bounds, from the seeds' sums ``num`` and ``den`` over all chunks
    (:func:`~ctfit._fitting.starts.grid_sums`; ``grid`` None: ``u0`` alone), all host arrays: a
    few hundred numbers (:func:`~ctfit._fitting.starts.best_splits`,
    :func:`~ctfit._fitting.starts.seeds_from_scores` in NumPy), no program to make. As a program
    (``fit_seeds``, per structure), its tracing and compiling took 0.35 s of a first fit's CPU."""
    if grid is None:
        seeds = {name: np.asarray(v)[None] for name, v in u0.items()}
    else:
        costs, scales, amplitudes, split = best_splits(num, den)
        seeds = seeds_from_scores(part, u0, k, grid, costs, scales, keep_start, amplitudes, split)
    lower, upper = bounds(part.spec, u0)
    return dict(flat=flat_host(seeds, batch=True), lower=flat_host(lower), upper=flat_host(upper))


def _given(flat, data):
    return data


def _cost_given(flat, f):
    return f, None


def _lm(y, lower, upper, grad, hess, tol):
    solver = lm_solver(y.dtype, lower, upper, (grad, hess), _given, stol=tol[0], gtol=tol[1], zero_cost=tol[2])
    template = solver.init(_cost_given, y, jnp.zeros((), y.dtype), {}, jax.ShapeDtypeStruct((), y.dtype), None, frozenset())
    return solver, template


def _lm_init(y, lower, upper, tol):
    """optimistix's ``init`` and first ``terminate`` (``_run_solver``'s); ``tol``: (stol, gtol, the
    cost of a zero model)."""
    import optimistix as optx

    p = y.shape[0]
    solver, state = _lm(y, lower, upper, jnp.zeros((p,), y.dtype), jnp.zeros((p, p), y.dtype), tol)
    done, result = solver.terminate(_cost_given, y, jnp.zeros((), y.dtype), {}, state, frozenset())
    sound = (result == optx.RESULTS.successful) & jnp.all(jnp.isfinite(y))
    return dict(state=array_leaves(state), y_eval=state.y_eval, done=done, sound=sound)


def _lm_step(y, leaves: list, f, grad, hess, lower, upper, tol):
    """One optimistix step given the cost, Jᵀr and JᵀJ at the point the state evaluates."""
    import optimistix as optx

    solver, template = _lm(y, lower, upper, grad, hess, tol)
    state = split_arrays(template)[1](leaves)
    y, state, _ = solver.step(_cost_given, y, f, {}, state, frozenset())
    done, result = solver.terminate(_cost_given, y, f, {}, state, frozenset())
    sound = (result == optx.RESULTS.successful) & jnp.all(jnp.isfinite(y))
    return dict(y=y, state=array_leaves(state), y_eval=state.y_eval, done=done, sound=sound, cost=state.f_info.f)


@dataclasses.dataclass
class _Kernels:
    """The compiled programs of one fit, and the chunks' array leaves they run over."""

    parts: list[list]
    template: Problem
    u0: dict
    ne: Callable[..., Any]
    init: Callable[..., Any]
    step: Callable[..., Any]
    zeros: list  # the sums' starting values, on the device once (programs do not donate their inputs)

    def normal_equations(self, flat, side_by_side: bool = True) -> tuple[list, list]:
        """((½‖r‖², Jᵀr, JᵀJ) at ``flat``, summed over the chunks (:func:`chunk_sums`); each
        chunk's model values there)."""
        sums, kept = chunk_sums(self.ne, self.zeros, self.parts, [flat, *array_leaves(self.u0)], side_by_side)
        return sums, [values for (values,) in kept]

    def run(self, y0, lower, upper, budget: int, tol, alone: bool = True, resume: tuple | None = None):
        """``_run_solver`` on the host: (value, converged, steps, sound, cost, last, paused),
        ``last`` the point the solver last evaluated, (½‖r‖², Jᵀr, JᵀJ) and the chunks' model
        values there (:meth:`normal_equations`), or None;
        ``paused`` what ``resume`` takes to go on with this solve (its state), or None where it
        took no step. ``tol``: the solver's (stol, gtol, zero_cost) (:func:`~ctfit._fitting.seeded_solve.lm_solver`),
        a device array. ``alone``: no other seed runs meanwhile (the sums' chains then run side
        by side). ``resume``: a ``paused`` of a solve on the same data, going on from ``y0``."""
        if resume is None:
            out = self.init(y0, lower, upper, tol)
            leaves, y_eval = out["state"], out["y_eval"]
            done, sound = (bool(v) for v in jax.device_get((out["done"], out["sound"])))
        else:
            (leaves, y_eval), done, sound = resume, False, True
        y, k, cost, last = y0, 0, np.inf, None
        while not done and sound and k < budget:
            last = None  # (its values are not held beside the next ones)
            (f, grad, hess), values = self.normal_equations(y_eval, alone)
            last = (y_eval, [f, grad, hess], values)
            out = self.step(y, *leaves, f, grad, hess, lower, upper, tol)
            y, leaves, y_eval, cost = out["y"], out["state"], out["y_eval"], out["cost"]
            done, sound = (bool(v) for v in jax.device_get((out["done"], out["sound"])))
            k += 1
        return y, done and sound, k, sound, float(cost), last, ((leaves, y_eval) if k > 0 else None)

    def normal_equations_at(self, flat, last):
        """:meth:`normal_equations` at ``flat``, or those of ``last`` (:meth:`run`'s) where they
        were evaluated at ``flat`` itself (the solver's last step was accepted): a pass over the
        data fewer."""
        if last is not None and np.array_equal(*jax.device_get((last[0], flat))):
            return last[1], last[2]
        return self.normal_equations(flat)


def _kernels(parts: list[Problem], u0: dict, solver: tuple | None = None, ne: Callable[..., Any] | None = None) -> _Kernels:
    """The fit's kernels over ``parts``; ``solver`` (:func:`_solver_programs`) and ``ne``
    (:func:`_ne_program`) where made already (in other threads)."""
    init, step, zeros = _solver_programs(u0) if solver is None else solver
    ne = _ne_program(parts[0], u0) if ne is None else ne
    return _Kernels([array_leaves(pt) for pt in parts], parts[0], u0, ne, init, step, zeros)


def _ne_program(template: Problem, u0: dict):
    """``fit_ne`` for chunks like ``template``: the largest of a fit's programs (its load is
    most of a warm fit's loading)."""
    size, dtype = _flat_shape(u0)
    p = _padded_size(size)
    zeros = [np.zeros(s, dtype) for s in ((), (p,), (p, p))]
    return _program("fit_ne", _ne_kernel, zeros, template, zeros[1], u0)


def shipped_solver_arguments(p: int, dtype) -> list[tuple[str, Callable, tuple]]:
    """(name, function, arguments like its own) of ``lm_init`` and ``lm_step`` for ``p`` padded
    parameters of ``dtype``: what ``scripts/ship_programs.py`` exports (:func:`_solver_programs`
    asks for them with arguments of these shapes). ``lm_step``'s state is the shape of ``lm_init``'s."""
    flat, tol, zeros = np.zeros(p, dtype), np.zeros(3, dtype), [np.zeros(s, dtype) for s in ((), (p,), (p, p))]
    init_args = (flat, flat, flat, tol)
    state = [np.zeros(x.shape, x.dtype) for x in jax.eval_shape(_lm_init, *init_args)["state"]]
    return [("lm_init", _lm_init, init_args), ("lm_step", _lm_step, _step_arguments(flat, state, zeros, tol))]


def _step_arguments(flat, state: list, zeros: list, tol) -> tuple:
    """``lm_step``'s arguments (:func:`_lm_step`): the point, the solver's state, the cost, Jᵀr and
    JᵀJ (``zeros``' shapes), the bounds, the tolerances; the one layout of :func:`_solver_programs`
    and of the programs shipped (:func:`shipped_solver_arguments`)."""
    return (flat, state, zeros[0], flat, zeros[2], flat, flat, tol)


def _solver_programs(u0: dict) -> tuple:
    """(``lm_init``, ``lm_step``, the sums' zeros on the device): they depend on the number of
    parameters alone. Where ctfit ships them for these shapes (:func:`~ctfit._runtime.shipped`),
    the shipped module is compiled instead of tracing optimistix (a first fit's CPU: about a
    second less, holding the GIL the other programs' tracing needs)."""
    size, dtype = _flat_shape(u0)
    p = _padded_size(size)
    flat = jax.device_put(np.zeros(p, dtype))
    zeros = [jax.device_put(np.zeros(s, dtype)) for s in ((), (p,), (p, p))]
    tol = jax.device_put(np.zeros(3, dtype))
    init_args = (flat, flat, flat, tol)
    init = _program("lm_init", _solver_function("lm_init", _lm_init, init_args), *init_args)
    step_args = _step_arguments(flat, init(*init_args)["state"], zeros, tol)
    step = _program("lm_step", _solver_function("lm_step", _lm_step, step_args), *step_args)
    return init, step, zeros


def _solver_function(name: str, fn: Callable, args: tuple) -> Callable:
    """``fn``, or the module ctfit ships for program ``name`` with ``args``' shapes
    (:func:`~ctfit._runtime.shipped`), chosen when the program is traced: a program loaded from
    the store reads neither (40 ms of a warm fit, ``jax.export`` imported and two modules read)."""

    def traced(*a):
        return (shipped(name, args) or fn)(*a)

    return traced


def _zero_program(template: Problem):
    """Make (compile or load) ``fit_zero``, the cost of a zero model over a chunk like ``template``
    (no structure in it: one program per loss, layout and bands)."""
    return _program("fit_zero", _zero_kernel, np.zeros((), template.y.dtype), _data_only(template))


def _sums_program(template: Problem, u0: dict, k: int, grid):
    """``fit_grid_sums`` (the seeds' sums over a chunk), or None where the fit has no grid."""
    if "m" not in u0 or k < 1 or grid is None:
        return None
    acc = [np.zeros(grid_sums_shape(u0, grid, template.fixed_bands), grid.dtype) for _ in range(2)]
    return _program("fit_grid_sums", _sums_kernel, acc, template, u0, grid)


def _seeds(parts: list[Problem], u0: dict, k: int, grid, keep_start: bool) -> dict:
    """The flat seeds and the bounds (host arrays): the scores' sums over the chunks (one pass),
    then the choice on the host (:func:`_seed_choice`)."""
    template = parts[0]
    host_u0 = jax.device_get(u0)
    sums = _sums_program(template, u0, k, grid)
    if sums is None:
        return _seed_choice(template, host_u0, k, None, None, None, keep_start)
    acc = [jax.device_put(np.zeros(grid_sums_shape(u0, grid, template.fixed_bands), grid.dtype)) for _ in range(2)]
    num, den = jax.device_get(chunk_sums(sums, acc, [array_leaves(pt) for pt in parts], [*array_leaves(u0), grid])[0])
    return _seed_choice(template, host_u0, k, np.asarray(jax.device_get(grid)), np.asarray(num), np.asarray(den), keep_start)


def prefetch(problem: Problem, u0: dict, grid, starts: int, keep_start: bool = False) -> list[Callable]:
    """Make (load from the store, or compile) every program :func:`chunked_core` calls for a fit
    of ``problem``'s layout from ``u0``'s shapes (with the report or without: the same), without fitting;
    returns them. Run in a background thread while another fit runs, it takes the loading or
    compiling off that fit's path."""
    (template,) = chunk_problems(problem, limit=1)
    u0 = {k: jnp.asarray(v) for k, v in u0.items()}
    kern = _kernels([template], u0)
    made = [kern.ne, kern.init, kern.step, _zero_program(template), transfer_program(template),
            _sums_program(template, u0, starts, grid)]
    _made.add(_signature((template, u0, grid, starts, keep_start)))
    return [run for run in made if run is not None]


def _race(kern: _Kernels, seeds: dict, max_steps: int, tolerance: float | None = None, sample: _Kernels | None = None, zero_cost: float = 0.0):
    """``_structured_lm``'s race on the host: every seed ``RACE_STEPS`` steps, then those within
    ``RACE_MARGIN`` of the lowest cost go on with their solves (the solver's state, its damping
    included, carried over). Returns flat values, sound, steps, costs.
    ``tolerance``: stop where one more Gauss–Newton step promises less than this relative
    decrease of the cost (None: ``lm_solver``'s tests); ``zero_cost``: the cost of a zero model over
    all the data, the scale below which the solver's stopping tests take a cost as rounding
    (``lm_solver``'s; that of the race's sample is the same fraction of it). The seeds of a phase run side by side,
    one thread each, beyond the machine's cores too (the programs run without the GIL: three
    seeds on two cores end in 1.5 rounds, not two; every seed's steps are those it would take
    alone). Also returns each seed's :meth:`_Kernels.run` ``last`` (over all the data).

    ``sample``: the kernels of a sample of the rows (:func:`race_rows`; given for more than one
    seed). The race runs there, to convergence; then the seeds within ``RACE_CLOSE`` of its
    lowest cost go on over all the data (``kern``), each with ``max_steps`` steps. The steps returned are those on all the data; a
    seed that did not go on keeps cost ∞."""
    n, p = seeds["flat"].shape
    dtype = seeds["flat"].dtype
    tolerances = lambda zero: jax.device_put(np.array([*stop_tolerances(dtype, tolerance), zero], dtype))
    tol = tolerances(zero_cost)
    tol_first = tol if sample is None else tolerances(zero_cost * len(sample.parts) / len(kern.parts))  # about the sample's share of the zero cost
    extra = _padded_size(p) - p
    flat = np.pad(seeds["flat"], ((0, 0), (0, extra)))
    lower, upper = (jax.device_put(np.pad(seeds[k], (0, extra))) for k in ("lower", "upper"))
    values = [jax.device_put(v) for v in flat]
    ok, steps, costs, sound = [False] * n, [0] * n, [math.inf] * n, [True] * n
    last: list = [None] * n
    paused: list = [None] * n  # each seed's solver state after its last step (:meth:`_Kernels.run`'s)
    race = n > 1 and max_steps > RACE_STEPS

    def phase(budgets: list[int], on: _Kernels) -> None:
        go = [j for j in range(n) if budgets[j] > 0]
        tol_on = tol if on is kern else tol_first
        run = lambda j: on.run(values[j], lower, upper, budgets[j], tol_on, len(go) <= 1, paused[j] if sound[j] else None)
        if len(go) <= 1:  # one seed (a fit from its start alone): no thread
            runs = [run(j) for j in go]
        else:
            with concurrent.futures.ThreadPoolExecutor(len(go)) as pool:
                runs = list(pool.map(run, go))
        for j, (v, o, k, fine, c, at, state) in zip(go, runs):
            if k > 0:  # a seed that did not go on keeps what it had
                values[j], ok[j], sound[j], costs[j], last[j], paused[j] = v, o, fine, (c if math.isfinite(c) else math.inf), at, state
            steps[j] += k

    first = sample or kern
    if not race:
        phase([max_steps] * n, first)
    else:
        phase([RACE_STEPS] * n, first)
        lowest = min(costs)
        phase([max_steps - RACE_STEPS if (not ok[j] and costs[j] <= RACE_MARGIN * lowest) else 0 for j in range(n)], first)
    if sample is not None:  # the sample's winners, over all the data: a new solve each (other data)
        go = _distinct_winners(jax.device_get(values), costs, kern.u0)
        ok, steps, costs, last, paused = [False] * n, [0] * n, [math.inf] * n, [None] * n, [None] * n
        phase([max_steps if j in go else 0 for j in range(n)], kern)
    return values, np.array(sound), np.array(steps, np.int32), np.array(costs, flat.dtype), last


SAME_POINT = 1e-3
"""Seeds whose coordinates (F0, s, log m, the lobes' weights, …; the lobes in order of m) all agree
within this (absolute and relative) after the race on a sample converged to one point: only the
lowest of them goes on."""


def _lobes_in_order(flat: np.ndarray, u0: dict | None) -> np.ndarray:
    """``flat`` (a seed's coordinates, as ``ravel_pytree(u0)`` orders them, padded or not) with its
    lobes in order of m, each lobe's weight in place of the stick fractions
    (:func:`~ctfit._fitting.coordinates.lobe_weights`): two seeds whose lobes are the same but
    listed in another order — one model, one cost — compare equal. Without free m and w, ``flat``."""
    flat = np.asarray(flat)
    if u0 is None or "m" not in u0 or "w" not in u0:
        return flat
    u = _unflat(u0, flat)
    order = np.argsort(u["m"], kind="stable")
    rest = [np.ravel(u[k]) for k in sorted(u) if k not in ("m", "w")]
    return np.concatenate([*rest, u["m"][order], fraction_weights(u["w"])[order]])


def _distinct_winners(values: list, costs: list[float], u0: dict | None = None) -> list[int]:
    """The seeds that go on over all the data after a race on a sample: those within
    ``RACE_CLOSE`` of the lowest cost, lowest first, leaving out any at the point of one before
    (its lobes in any order, given ``u0``: :func:`_lobes_in_order`)."""
    finite = [c for c in costs if math.isfinite(c)]
    if not finite:
        return []
    lowest = min(finite)
    points = [_lobes_in_order(v, u0) for v in values]
    out: list[int] = []
    for j in sorted(range(len(costs)), key=lambda j: costs[j]):
        if costs[j] <= (1 + RACE_CLOSE) * lowest and not any(np.allclose(points[j], points[i], rtol=SAME_POINT, atol=SAME_POINT) for i in out):
            out.append(j)
    return out


def _made_in_threads(parts: list[Problem], u0: dict, seeds: Callable[[], dict]):
    """(seeds, kernels, rest), the fit's programs made (compiled, or loaded from the store) in
    four threads at once, as XLA compiles and loads without the GIL: ``fit_ne`` (the largest),
    the solver's, ``fit_zero`` (and ``chunk_put``), and the seeds' (``seeds()``) in this one.
    ``fit_zero`` is needed once the seeds are chosen (its cost is the solver's scale): it may
    still be being made while they are (a failure there is met again, and raised, where the race
    takes it). ``rest``: the future of ``fit_zero``'s; the fit waits for it before it returns, so
    that nothing it started outlives it."""
    template = parts[0]
    pool = concurrent.futures.ThreadPoolExecutor(3, thread_name_prefix="ctfit-programs")
    try:
        ne = pool.submit(_ne_program, template, u0)
        solver = pool.submit(_solver_programs, u0)
        rest = pool.submit(lambda: (_zero_program(template), transfer_program(template)))
        made = seeds()
        return made, _kernels(parts, u0, solver.result(), ne.result()), rest
    finally:
        pool.shutdown(wait=False)


def chunked_core(problem: Problem, u0: dict, grid, starts: int, max_steps: int, keep_start: bool = False, parts: list[Problem] | None = None,
                 tolerance: float | None = None, report: bool = True, race_parts: list[Problem] | None = None) -> dict:
    """``fit_core``'s output (host arrays) for the solver "lm", on chunks: ``problem`` laid out
    by ``make_problem(chunk=ROWS)``, ``parts`` its :func:`chunk_problems` (made here if None);
    ``tolerance``: :func:`_race`'s. ``report=False``: only what comparing fits needs (the
    parameters, the cost of a zero model, the Gauss–Newton decrease; no residual summary or
    standard errors); both are made on the host, with the same programs.
    ``race_parts``: the chunks of a sample of the rows (:func:`race_rows`), where the seeds are
    chosen and raced (:func:`_race`'s ``sample``; the same programs: chunks of one shape)."""
    parts = chunk_problems(problem) if parts is None else parts
    seeding = parts if race_parts is None else race_parts
    u0 = {k: jnp.asarray(v) for k, v in u0.items()}
    shapes = _signature((parts[0], u0, grid, starts, keep_start))
    if shapes in _made:
        seeds, kern = _seeds(seeding, u0, starts, grid, keep_start), _kernels(parts, u0)
        return _race_and_report(problem, u0, seeds, kern, race_parts, max_steps, tolerance, report)
    seeds, kern, rest = _made_in_threads(parts, u0, lambda: _seeds(seeding, u0, starts, grid, keep_start))
    _made.add(shapes)
    try:
        return _race_and_report(problem, u0, seeds, kern, race_parts, max_steps, tolerance, report)
    finally:
        concurrent.futures.wait([rest])  # nothing the fit started outlives it


def _race_and_report(problem: Problem, u0: dict, seeds: dict, kern: _Kernels, race_parts, max_steps: int, tolerance, report: bool) -> dict:
    """:func:`chunked_core` once its programs are made: the race, the sums at the winner, the report."""
    sample, race_samples = None, 0
    if race_parts is not None and seeds["flat"].shape[0] > 1:  # one seed alone is not raced: it is solved on all the data
        sample = dataclasses.replace(kern, parts=[array_leaves(pt) for pt in race_parts])
        race_samples = int(sum(np.sum(np.asarray(pt.mask)) for pt in race_parts))
    zero = _zero_cost(kern, seeds["flat"].dtype)
    values, sound, steps, costs, last = _race(kern, seeds, max_steps, tolerance, sample, float(zero))
    best = int(np.argmin(costs))
    p = _flat_shape(u0)[0]
    (cost, jtr, jtj), at_best = kern.normal_equations_at(values[best], last[best])
    cost, jtr, jtj = (np.asarray(a) for a in jax.device_get((cost, jtr, jtj)))
    jtr, jtj = jtr[:p], jtj[:p, :p]
    solved = dict(u=_unflat(u0, np.asarray(values[best])), ok=sound, steps=steps, costs=costs, best=best)
    if sample is not None:
        solved["race_samples"] = race_samples
    del last  # the other seeds' values
    host = dataclasses.replace(kern.template, fixed=jax.device_get(kern.template.fixed))  # on the host: no program per structure
    if not report:
        return dict(light_report_core(host, solved["u"], cost, jtr, jtj, zero, np), **solved, zero_cost=zero)
    return dict(report_core(host, solved["u"], cost, jtr, jtj, zero, np), **_summary(problem, at_best), **solved)


def _zero_cost(kern: _Kernels, dtype) -> np.ndarray:
    """The cost of a zero model over ``kern``'s chunks (``fit_zero``, shared by every structure:
    each chunk with no structure in it), on the host: the report's scale, and the solver's
    (a cost below ε times it is rounding, :func:`~ctfit._fitting.seeded_solve.lm_solver`)."""
    zero_program = _zero_program(kern.template)
    zero = jax.device_put(np.zeros((), dtype))
    rebuild = split_arrays(kern.template)[1]
    for leaves in kern.parts:
        zero = zero_program(zero, *array_leaves(_data_only(rebuild(leaves))))
    return np.asarray(jax.device_get(zero))


SUMMARY_CELLS = 1 << 17
"""Cells of the layout the host summarises at once (:func:`_summary`; 64 chunks of 2,048): a few
MB of temporaries, a few NumPy calls per 64 chunks."""


def _summary(problem: Problem, values: list) -> dict:
    """The residual summary of the report (relative residuals, rms errors, cells whose model
    value is not finite) from the chunks' model ``values`` at the solution, on the host: the
    values come with the normal equations there (``fit_ne``), so the summary needs no program
    (as one, ``fit_summary``, it took 0.4–0.7 s of compiling per structure). The chunks are the
    layout's rows in order (:func:`chunk_problems`), summarised about :data:`SUMMARY_CELLS` cells at a time."""
    values = jax.device_get(values)
    rows = values[0].shape[0]
    y, mask, floor = np.asarray(problem.y), np.asarray(problem.mask), np.asarray(problem.floor)
    step = max(1, SUMMARY_CELLS // values[0].size)
    rel = np.empty((len(values) * rows, *values[0].shape[1:]), np.float32)  # filled in place: no second copy to join at the end
    stats, bad = [], 0
    for c in range(0, len(values), step):
        cut = slice(c * rows, (c + step) * rows)
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):  # a value that is not finite gives NaN, as in a program
            rel[cut], st, b = summary_of_values(np.concatenate(values[c: c + step]), y[cut], mask[cut], floor)
        stats.append(st)
        bad += int(b)
    n = max(int(np.sum(mask)), 1)
    with np.errstate(invalid="ignore", over="ignore"):
        rmse, rel_rmse = (combined_rms(np.array([s[i][0] for s in stats]), np.array([s[i][1] for s in stats]), n, xp=np) for i in (0, 1))
    return dict(rel=rel, rmse=rmse, rel_rmse=rel_rmse, bad=bad)
