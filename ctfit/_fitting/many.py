"""A database of measurements fitted across a Dask cluster: ``fit_many(items, structure, client=None)``.

Items are measurement files (read by the workers, so they must be reachable from every worker)
or :class:`~ctfit.Measurement` objects. A first round of tasks reads each file and returns its
geometry key (the directions, bands and which data columns exist, hashed): files with the same
key go to one task together — a group of files, not one file, so a task is coarse — and are
fitted there by :func:`~ctfit.fit_batch` in one compiled program. A worker process keeps its
programs in memory and in the on-disk store (:func:`~ctfit._runtime.cluster.prepare_worker`), so the
second group a worker gets does not compile again. Each file is read twice (key, then fit):
cheap next to its fit, and no measurement travels between processes.

Results come back as tasks complete; ``on_result(i, result)`` is called in the calling process
for each (the ``ctfit fit --workers`` command writes each file's JSON there, atomically, so a
run that is killed keeps every finished result). :func:`input_sha256` is the content hash that
the command stores in each result to know, on a re-run, which files are done: the worker that
fits a file hashes it before and after its read, so the hash is of the bytes fitted.
"""

from __future__ import annotations

import hashlib
import math
import os
import pickle
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from jax.typing import DTypeLike

from .._io import input_sha256
from .._model import Material, Measurement, Params, Structure

__all__ = ["fit_many", "input_sha256", "read_input", "geometry_key", "FILES_PER_TASK"]

FILES_PER_TASK = 64
"""Most files in one task (a group of the same geometry is cut into about two tasks per worker)."""


def fit_many(
    items: Sequence[Measurement | str | os.PathLike[str]],
    structure: Structure | None = None,
    client: Any = None,
    *,
    start: Params | Sequence[Params | None] | None = None,
    fixed: tuple[str, ...] = (),
    material: Material | None = None,
    loss: str = "auto",
    solver: str = "lm",
    dtype: DTypeLike | None = None,
    starts: int = 3,
    max_steps: int = 256,
    param_out: str | None = None,
    return_errors: bool = False,
    files_per_task: int | None = None,
    workers: int | None = None,
    on_result: Callable[[int, object], None] | None = None, progress: bool = False, choice: dict | None = None,
) -> list:
    """Fit ``structure`` to every item on a Dask cluster; one :class:`~ctfit.FitResult` per item, in input order.
    ``structure=None``: each item's structure is chosen by its data, as :func:`~ctfit.fit` chooses it (then ``start``
    and ``fixed`` do not apply; items are fitted one by one on their worker), among the candidates ``choice``
    names (:func:`~ctfit.choose_structure`'s ``families``, ``lobes``, ``diffuse``, ``geometry``, ``fresnel``).

    ``items``: paths of measurement files (CSV, ALTA, MERL .binary, RGL .bsdf; read on the workers, with
    ``param_out`` as for :func:`~ctfit.read_alta`) or :class:`~ctfit.Measurement` objects.
    ``client``: a :class:`distributed.Client`; None: a :class:`~distributed.LocalCluster` of
    ``workers`` processes (default one per core) made for this call and closed after it.
    Results equal :func:`~ctfit.fit_batch`'s (and :func:`~ctfit.fit`'s, to the solver's
    tolerance). ``return_errors``: an item that cannot be read or fitted is returned as its
    exception in its place (otherwise the first one is raised once all tasks are done).
    ``on_result(i, result)`` is called in this process as each item's task completes (a result
    or, with ``return_errors``, an exception); ``progress``: a bar over tasks on stderr.
    ``material``: a :class:`~ctfit.Material` whose values, on each item's bands, start its fit
    and whose ``meta["fixed"]`` names the fixed parameters (as ``ctfit fit --material``); the
    other fitting options are those of :func:`~ctfit.fit`. A file's result has in ``material.meta["input_sha256"]`` the SHA-256
    of the bytes its worker fitted (hashed before and after that read; a file changed meanwhile is read again, :data:`READ_TRIES` times).

    >>> import numpy as np, ctfit
    >>> def gold(m):
    ...     return ctfit.Material(ctfit.Structure(lobes=1, diffuse=None),
    ...                           ctfit.Params(m=np.array([m]), w=np.ones(1), f0=np.array([0.4, 0.9])),
    ...                           wavelength_nm=np.array([450.0, 650.0]))
    >>> items = [ctfit.simulate(gold(m), n_pairs=300, seed=1) for m in (0.2, 0.35)]  # or file paths
    >>> results = ctfit.fit_many(items, gold(0.2).structure, workers=1)  # a local cluster of one worker
    >>> [round(float(r.material.params.m[0]), 4) for r in results]
    [0.2, 0.35]
    """
    import jax.numpy as jnp

    from .._runtime import dask_client, worker_count

    items = list(items)
    dtype = jnp.float64 if dtype is None else dtype
    if isinstance(start, (list, tuple)):
        raise ValueError("start: fit_many takes one Params (or None) for every item")
    if files_per_task is not None and files_per_task < 1:
        raise ValueError(f"files_per_task must be ≥ 1, got {files_per_task}")
    options = dict(start=start, fixed=tuple(fixed), material=material, loss=loss, solver=solver, dtype=dtype, starts=starts, max_steps=max_steps)
    options["choice"] = choice or {}
    x64 = np.dtype(dtype).itemsize == 8
    results: list = [None] * len(items)
    if not items:
        return results

    def settle(i: int, got: Any) -> None:
        results[i] = got
        if on_result is not None:
            on_result(i, got)

    with dask_client(client, workers=workers) as cl:
        tasks = _tasks(_keys(cl, items, param_out, x64), files_per_task, worker_count(cl), settle)
        futures = {cl.submit(_fit_task, [_located(items[i]) for i in members], structure, options, param_out, x64, pure=False): members
                   for members in tasks}
        _settle_as_completed(futures, settle, progress)
    if not return_errors:
        for got in results:
            if isinstance(got, Exception):
                raise got
    return results


def _settle_as_completed(futures: dict, settle: Callable, progress: bool) -> None:
    """``settle(i, result)`` for every member ``i`` of each task (future → members) as it completes."""
    from .._runtime import need

    need("cluster", "fitting on a Dask cluster")
    from distributed import as_completed

    from .._runtime import bar

    for future in bar(as_completed(futures), desc="tasks", enabled=progress, total=len(futures)):
        members = futures.pop(future)
        try:
            outs = future.result()
        except Exception as e:  # the task itself was lost (its workers died): every member fails
            outs = [RuntimeError(f"the task fitting it failed: {type(e).__name__}: {e}")] * len(members)
        for i, got in zip(members, outs):
            settle(i, got)


def _keys(client: Any, items: list, param_out: str | None, x64: bool) -> list:
    """Each item's geometry key, or the exception that reading it raised (files are read on the workers)."""
    keys: list = [None] * len(items)
    paths = [i for i, item in enumerate(items) if not isinstance(item, Measurement)]
    for i, item in enumerate(items):
        if isinstance(item, Measurement):
            keys[i] = geometry_key(item)
    if paths:
        got = client.gather(client.map(_key_task, [_located(items[i]) for i in paths], param_out=param_out, x64=x64, pure=False))
        for i, key in zip(paths, got):
            keys[i] = key
    return keys


def _tasks(keys: list, files_per_task: int | None, n_workers: int, settle: Callable[[int, Any], None]) -> list[list[int]]:
    """Item indices per task: the same geometry together, about two tasks per worker, at most
    ``files_per_task`` (:data:`FILES_PER_TASK`) each; items whose key is an exception are settled now."""
    groups: dict = {}
    for i, key in enumerate(keys):
        if isinstance(key, Exception):
            settle(i, key)
        else:
            groups.setdefault(key, []).append(i)
    total = sum(len(g) for g in groups.values())
    size = files_per_task or max(1, min(FILES_PER_TASK, math.ceil(total / (2 * n_workers))))
    return [g[a: a + size] for g in groups.values() for a in range(0, len(g), size)]


def read_input(path: str | os.PathLike[str], param_out: str | None = None) -> Measurement:
    """A measurement file read by its format's reader; ``param_out`` serves only an ALTA file
    without its own #PARAM_OUT line."""
    from .._io import read_alta, reader_for

    reader = reader_for(path)
    return reader(path, param_out_default=param_out) if param_out is not None and reader is read_alta else reader(path)


def geometry_key(data: Measurement) -> str:
    """A hash of what files must share to be fitted in one program: directions, bands, data columns."""
    h = hashlib.sha256()
    for a in (data.theta_i, data.phi_i, data.theta_o, data.phi_o, data.band):
        h.update(np.ascontiguousarray(a, dtype=float).tobytes())
    h.update(repr((None if data.wavelength_nm is None else np.asarray(data.wavelength_nm).tolist(), data.channels,
                   data.sigma is None, data.band_unknown)).encode())
    return h.hexdigest()


_CAUGHT = (ValueError, OSError, KeyError)


def _located(item: Any) -> Any:
    """A measurement as it is; a path as (the path given, its absolute path): a worker may run in
    another folder, and messages and results name the file as the user gave it."""
    if isinstance(item, Measurement):
        return item
    return os.fspath(item), os.path.abspath(item)


def _read_item(item: Any, param_out: str | None) -> Measurement:
    """The measurement of a :func:`_located` item, read on a worker."""
    if isinstance(item, Measurement):
        return item
    shown, where = item
    return _as_shown(lambda: read_input(where, param_out).replace(source=shown), where, shown)


READ_TRIES = 3
"""How often a worker reads a file that changes while it reads it before that file fails (:func:`_read_hashed`)."""


def _read_hashed(item: Any, param_out: str | None) -> tuple[Measurement, str | None]:
    """The measurement of a :func:`_located` item and the SHA-256 of the bytes it was parsed from
    (None: a Measurement): the file is hashed before and after it is read, and read again if the
    two differ (it changed meanwhile); one still changing after :data:`READ_TRIES` reads fails."""
    if isinstance(item, Measurement):
        return item, None
    shown, where = item
    for _ in range(READ_TRIES):
        before = _as_shown(lambda: input_sha256(where), where, shown)
        meas = _read_item(item, param_out)
        if _as_shown(lambda: input_sha256(where), where, shown) == before:
            return meas, before
    raise ValueError(f"{shown}: changed while it was read ({READ_TRIES} tries); fit it again once it is written")


def _as_shown(call: Callable[[], Any], where: str, shown: str) -> Any:
    """``call()``; an error it raises names the file as the user gave it (``shown``), not by its absolute path."""
    try:
        return call()
    except _CAUGHT as e:
        text = str(e).replace(where, shown)
        if text == str(e):
            raise
        try:
            renamed = type(e)(text)
        except Exception:
            renamed = ValueError(text)
        raise renamed from None


def _portable(e: Exception) -> Exception:
    """``e`` if it survives pickling (the trip back from a worker), else a ValueError with its message."""
    try:
        pickle.loads(pickle.dumps(e))
        return e
    except Exception:
        return ValueError(str(e))


def _key_task(item: Any, param_out: str | None, x64: bool) -> Any:
    from .._runtime import prepare_worker

    prepare_worker(x64)
    try:
        return geometry_key(_read_item(item, param_out))
    except _CAUGHT as e:
        return _portable(e)


def _fit_task(items: list, structure: Structure | None, options: dict, param_out: str | None, x64: bool) -> list:
    """One task: read the files (or take the measurements) and fit them with ``fit_batch``;
    per item a FitResult or the exception that stopped it."""
    from .._runtime import prepare_worker
    from .batch import fit_batch

    prepare_worker(x64)
    outs: list = [None] * len(items)
    ready = []
    hashes: dict[int, str | None] = {}
    for j, item in enumerate(items):
        try:
            meas, hashes[j] = _read_hashed(item, param_out)
            ready.append((j, meas))
        except _CAUGHT as e:
            outs[j] = _portable(e)
    options = dict(options)
    base, choice = options.pop("material"), options.pop("choice", {})
    if base is not None:  # each item's start on its own bands, as `ctfit fit --material` makes it
        from .starts import start_from_material

        starts, kept = [], []
        for j, meas in ready:
            try:
                start, options["fixed"] = start_from_material(base, structure, meas)
                starts.append(start)
                kept.append((j, meas))
            except _CAUGHT as e:
                outs[j] = _portable(e)
        ready, options["start"] = kept, starts
    if ready and structure is None:  # the data chooses each item's structure among the candidates of ``choice`` (ctfit.fit's default: all)
        from .structure_selection import choose_structure

        for j, meas in ready:
            try:
                outs[j] = choose_structure(meas, **choice, **{k: v for k, v in options.items() if k not in ("start", "fixed")})[0]
            except _CAUGHT as e:
                outs[j] = _portable(e)
    elif ready:
        fits = fit_batch([m for _, m in ready], structure, return_errors=True, **options)
        for (j, _), got in zip(ready, fits):
            outs[j] = _portable(got) if isinstance(got, Exception) else got
    for j, sha in hashes.items():  # the hash of the bytes fitted, taken by the read that parsed them
        if sha is not None and not isinstance(outs[j], Exception):
            outs[j].material.meta["input_sha256"] = sha
    return outs
