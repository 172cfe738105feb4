"""Measurements of one geometry fitted together: many files' values, one program call.

A folder of a database often holds files measured at the same directions and bands (one
goniometer, one sampling plan): only their values differ. :func:`fit_shared` fits such a group
as the texel engine fits texels (:mod:`~ctfit._fitting.texels`): the first member is prepared
as :func:`~ctfit.fit` prepares it (checks, start, problem padded to its size bucket, m grid), the
others only checked, their values laid out as the first one's (:class:`~ctfit._fitting.texels.ValueLayout`)
with their own loss floor; one compiled program maps the single fit's program (``fit_core``)
over :data:`SHARED_CALL` members at a time with the geometry shared (one after the other on a
CPU, :func:`~ctfit._fitting.batch.mapped`), and keeps everything each member's report needs.
Up to :data:`SOLVE_THREADS` calls are solved at once, each in a thread, and while the members
of one call are reported (Python) the next ones solve (XLA, without the GIL). A group of several
calls makes its program first, on members all inactive (milliseconds): the store checks a
program it loads by running it, under a lock, so a call that made it would hold the others for
its whole solve (the first 64 files of a folder took 4.1 s, against 2.0 s). Each member's report is made by
:func:`~ctfit._fitting.least_squares.finish_fit`, as for a fit alone.

:func:`shared_groups` finds the groups: measurements with the same geometry key
(:func:`~ctfit._fitting.many.geometry_key`: directions, bands, which columns exist), no sigma
column, the same start, at most :data:`SHARED_SAMPLES` samples each, at least :data:`SHARED_MIN` of them.
"""

from __future__ import annotations

import collections
import concurrent.futures
import dataclasses
import os
import time

import jax
import numpy as np

from .._model import Measurement
from .._runtime import cached_call, program_made, stored_program
from .batch import SAMPLE_BUDGET, mapped
from .fit_report import PARAM_FIELDS
from .least_squares import PreparedFit, check_fit_arguments, finish_fit, fit_core, prepare_fit
from .many import geometry_key
from .texels import ValueLayout, with_values
from .validate import check_fittable

__all__ = ["fit_shared", "shared_groups", "SHARED_CALL", "SHARED_COMPILE_FILES", "SHARED_MIN", "SHARED_SAMPLES"]

SHARED_CALL = 32
"""Members per program call (fewer when their samples exceed :data:`~ctfit._fitting.batch.SAMPLE_BUDGET`);
the last call of a group is filled up with inactive copies (skipped), so one compiled program
serves every group of a structure and size bucket."""

SOLVE_THREADS = min(4, os.cpu_count() or 1)
"""Program calls solved at once, each in its own thread (a program runs without the GIL, on one
core): while one call's members are reported, the others' solve."""

SHARED_MIN = 4
"""The fewest measurements of one geometry fitted together; fewer are fitted one after the
other on chunks (:mod:`~ctfit._fitting.chunked_fit`), whose programs every size shares."""

SHARED_COMPILE_FILES = 64
"""The fewest measurements of one geometry for which :func:`fit_shared` makes (compiles) its program
when it is not made yet: about 8 s of compiling on two cores here, against some 60 ms a file saved
(a file of 2,000 samples: 23 ms in a shared call against 85 ms on chunks, warm). A smaller group of
a layout whose program is not made is fitted on chunks, whose programs every size shares: a new
size of file compiles nothing. (A folder is read ``ctfit fit``'s window at a time, 64 files.)"""

SHARED_SAMPLES = 1 << 16
"""The most samples of a measurement fitted together with others: where the per-file costs
around the solve matter. Larger ones are fitted on chunks, one after the other, whose memory
stays bounded whatever their size (a member of a call is laid out whole)."""


def shared_groups(measurements: list, begins: list) -> list[list[int]]:
    """Indices of the measurements that :func:`fit_shared` fits together, each group in input
    order: one geometry key, no sigma column, the same start (``begins[i]``: Params or None),
    at most :data:`SHARED_SAMPLES` samples.

    >>> import numpy as np, ctfit
    >>> base = ctfit.simulate(ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([0.2]), w=np.ones(1),
    ...                       f0=np.array([0.9])), wavelength_nm=np.array([550.0])), n_pairs=50, seed=0)
    >>> other = ctfit.simulate(ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([0.2]), w=np.ones(1),
    ...                        f0=np.array([0.9])), wavelength_nm=np.array([550.0])), n_pairs=60, seed=1)
    >>> shared_groups([base, other, base, base, base], [None] * 5)
    [[0, 2, 3, 4]]
    """
    by_key: dict = {}
    for i, (data, begin) in enumerate(zip(measurements, begins)):
        if isinstance(data, Measurement) and data.sigma is None and data.brdf is not None and len(data) <= SHARED_SAMPLES:
            by_key.setdefault((geometry_key(data), _start_key(begin)), []).append(i)
    return [members for members in by_key.values() if len(members) >= SHARED_MIN]


def _start_key(start) -> object:
    if start is None:
        return None
    return tuple(None if getattr(start, k) is None else np.asarray(getattr(start, k), float).tobytes() for k in PARAM_FIELDS)


def fit_shared(measurements: list, structure, *, start, fixed, loss, dtype, starts, solver: str, max_steps: int,
               return_errors: bool, compile_from: int | None = None) -> list | None:
    """One :class:`~ctfit.FitResult` (or, with ``return_errors``, the ``ValueError`` that stopped
    it) per measurement of one geometry (:func:`shared_groups`), each what :func:`~ctfit.fit`
    gives for it alone (to the solver's tolerance); arguments as for :func:`~ctfit.fit_batch`.
    None, having fitted nothing, where the group's program is not made and the group has fewer
    than ``compile_from`` measurements (None: :data:`SHARED_COMPILE_FILES`): the caller fits them
    one by one, on chunks.

    >>> import numpy as np, ctfit
    >>> def gold(m):
    ...     return ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([m]), w=np.ones(1),
    ...                           f0=np.array([0.4, 0.9])), wavelength_nm=np.array([450.0, 650.0]))
    >>> base = ctfit.simulate(gold(0.2), n_pairs=60, seed=1)
    >>> data = [base.replace(brdf=np.asarray(ctfit.evaluate(gold(m), base))) for m in (0.1, 0.2, 0.3, 0.4)]
    >>> fits = fit_shared(data, gold(0.2).structure, start=None, fixed=(), loss="auto", dtype=np.float64, starts=3, solver="lm",
    ...                   max_steps=256, return_errors=False, compile_from=0)  # made for 4 files, if need be
    >>> [round(float(r.material.params.m[0]), 4) for r in fits]
    [0.1, 0.2, 0.3, 0.4]
    """
    t0 = time.perf_counter()
    results: list = [None] * len(measurements)
    template, members = None, []
    for i, data in enumerate(measurements):
        try:
            if template is None:
                template = prepare_fit(data, structure, start=start, fixed=fixed, loss=loss, dtype=dtype, starts=starts)
            else:
                check_fit_arguments(data, structure)
                check_fittable(data, template.structure, fixed=template.fixed, loss=template.loss, dtype=dtype)
            members.append(i)
        except ValueError as e:
            if not return_errors:
                raise
            results[i] = e
    if template is None:
        return results
    layout = ValueLayout(template.problem, template.data)
    size = max(1, min(SHARED_CALL, SAMPLE_BUDGET // max(template.problem.y.size, 1)))
    options = template.options(solver, max_steps)

    def values(chunk: list[int]):
        block = np.stack([np.asarray(measurements[i].brdf, float) for i in chunk])
        return layout(np.concatenate([block, np.broadcast_to(block[-1:], (size - len(chunk), block.shape[1]))]), dtype)

    def solve(chunk: list[int]):
        ys, floors = values(chunk)
        active = np.arange(size) < len(chunk)
        out = cached_call("fit_shared", _shared_core, template.problem, ys, floors, active, template.u0, template.grid, *options)
        return chunk, ys, floors, jax.device_get(out)

    calls = [members[a: a + size] for a in range(0, len(members), size)]
    idle = (template.problem, *values(calls[0]), np.zeros(size, bool), template.u0, template.grid, *options)  # every member inactive
    if len(measurements) < (SHARED_COMPILE_FILES if compile_from is None else compile_from) and not program_made("fit_shared", *idle):
        return None
    if len(calls) > 1:  # made here, on members all inactive (skipped: milliseconds), so the calls run side by side at once
        stored_program("fit_shared", _shared_core, *idle)
    with concurrent.futures.ThreadPoolExecutor(min(SOLVE_THREADS, len(calls))) as pool:
        running = collections.deque(pool.submit(solve, c) for c in calls[:SOLVE_THREADS])
        for c in calls[SOLVE_THREADS:] + [None] * len(running):
            done = running.popleft().result()
            if c is not None:
                running.append(pool.submit(solve, c))
            _report(done, template, measurements, results, solver, max_steps, t0, return_errors)
    return results


def _report(call, template: PreparedFit, measurements: list, results: list, solver: str, max_steps: int, t0: float, return_errors: bool) -> None:
    """Each member's :class:`~ctfit.FitResult` of a solved call, into ``results``."""
    chunk, ys, floors, out = call
    pairs, index = template.data.directions()
    for j, i in enumerate(chunk):
        problem = with_values(template.problem, ys[j], floors[j])
        data = measurements[i].with_directions(pairs, index)  # the same arrays: what is computed from them is kept for the next member
        prep = dataclasses.replace(template, data=data, problem=problem)
        try:
            results[i] = finish_fit(prep, jax.tree.map(lambda x: x[j], out), solver, t0, max_steps=max_steps)
        except ValueError as e:
            if not return_errors:
                raise
            results[i] = e


def _shared_core(problem, ys, floors, active, u0, grid, *options):
    """``fit_core`` over the members' values and floors (geometry, start and m grid shared), one
    after the other; inactive members skipped."""

    def one(member):
        y, floor = member
        return fit_core(with_values(problem, y, floor), u0, grid, *options)

    return mapped(one, (ys, floors), active, 1)

