"""Where distributed work runs: a Dask client for an existing cluster, or an embedded local one.

``ctfit`` does not schedule work itself: it hands coarse tasks (a group of files, a chunk of
texels) to `Dask distributed <https://distributed.dask.org>`_. :func:`dask_client` is the one
place that makes a client — connected to a running scheduler (``ctfit fit --scheduler ADDRESS``)
or to a :class:`distributed.LocalCluster` of worker processes (``--workers N``, one thread each:
JAX already uses the cores of a worker's machine inside one fit) — and closes what it made,
also when Ctrl-C ends the command (``ctfit._io.on_interrupt``).
The cluster's own log lines (ports, workers starting and stopping) are kept below ERROR.

Workers are separate processes: :func:`prepare_worker` runs at the start of every task and
switches float64 on where the task asks for it and the persistent compilation cache on
(``ctfit/_runtime/compile_cache.py``), once per process, so every worker keeps and reuses the compiled programs.
"""

from __future__ import annotations

import contextlib
import logging

__all__ = ["CONNECT_TIMEOUT", "LOCAL_WORKERS_PER_CORE", "check_local_workers", "dask_client", "prepare_worker", "scheduler_address", "worker_count"]

_LOGGERS = ("distributed", "tornado", "bokeh")
CONNECT_TIMEOUT = "30s"
"""How long ``dask_client`` tries to reach a scheduler before it gives up (an ``OSError``)."""
_prepared: set[bool] = set()

LOCAL_WORKERS_PER_CORE = 4
"""A local cluster has at most this many worker processes per core this process may use: each
imports JAX and holds its own compiled programs (some 0.3 GB), and the fits are CPU-bound.
(a request for 10**20 of them started processes until it was killed.)"""


def check_local_workers(workers: int | None) -> None:
    """``ValueError`` naming the limit where a local cluster of ``workers`` processes is not
    started (below 1, or above :data:`LOCAL_WORKERS_PER_CORE` per usable core); None: one per core.

    >>> check_local_workers(1)
    >>> check_local_workers(10**20)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ValueError: workers = 100000000000000000000: a local cluster has at most ... worker processes ...
    """
    from .._io import usable_cores

    if workers is None:
        return
    if workers < 1:
        raise ValueError(f"workers must be ≥ 1, got {workers}")
    cores = usable_cores()
    if workers > LOCAL_WORKERS_PER_CORE * cores:
        raise ValueError(f"workers = {workers}: a local cluster has at most {LOCAL_WORKERS_PER_CORE * cores} worker processes here "
                         f"({LOCAL_WORKERS_PER_CORE} per core, {cores} core{'s' if cores != 1 else ''}; each process imports JAX and "
                         "compiles its own programs); for more, start a cluster across machines and give its scheduler")


def _quiet_logs():
    """The cluster's log lines below ERROR (they are about ports and processes, not the fits)."""
    for name in _LOGGERS:
        logging.getLogger(name).setLevel(logging.ERROR)


@contextlib.contextmanager
def dask_client(client=None, *, workers: int | None = None, scheduler: str | None = None):
    """A :class:`distributed.Client`: ``client`` itself (left open), one connected to
    ``scheduler`` (an address such as ``tcp://host:8786``, or a scheduler file ending in
    ``.json``), or a new :class:`~distributed.LocalCluster` of ``workers`` processes (default:
    one per core) — those two are closed on exit."""
    if client is not None:
        yield client
        return
    _quiet_logs()
    from .extras import need

    need("cluster", "a Dask cluster")
    from distributed import Client, LocalCluster

    if scheduler is not None:
        with Client(address=scheduler_address(scheduler), timeout=CONNECT_TIMEOUT) as made:
            yield made
        return
    check_local_workers(workers)
    from .._io import on_interrupt

    with _sigint_ignored():  # the worker processes inherit it: Ctrl-C is the command's alone
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0", silence_logs=logging.ERROR)
    clients: list = []
    withdraw = on_interrupt(lambda: _shut_down(clients, cluster))  # Ctrl-C, also while the cluster closes: no process or semaphore left behind
    try:
        with cluster, Client(cluster) as client:
            clients.append(client)
            yield client
    finally:
        withdraw()


@contextlib.contextmanager
def _sigint_ignored():
    """SIGINT ignored while the block starts the local cluster's processes, which keep that (an
    ignored signal stays ignored across ``exec``): a Ctrl-C at the terminal reaches the whole
    process group, and each worker printed a traceback of its own (``KeyboardInterrupt`` inside
    Dask's nanny) before the command's one line. The command shuts them down
    (:func:`~ctfit._io.on_interrupt`). Only in the main thread (where a handler can be set)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _shut_down(clients: list, cluster) -> None:
    """Close the ``clients`` (none yet, or one) and their local ``cluster`` (an interrupted
    command, before it exits)."""
    for client in clients:
        client.close(timeout=10)
    cluster.close(timeout=10)


def scheduler_address(scheduler) -> str:
    """The address of ``scheduler``: itself, or read from a scheduler file (``.json``, the one
    a Dask scheduler writes when it is given a file) — read as any input (a regular file, not
    nested too deeply), so a missing file is an error at once (``distributed`` would wait for it
    to appear) and a file that is not one says so. A file that does not parse is read again for
    a second, as Dask does: the scheduler may be writing it.

    >>> scheduler_address("tcp://127.0.0.1:8786")
    'tcp://127.0.0.1:8786'
    >>> scheduler_address("no-such-scheduler.json")
    Traceback (most recent call last):
    ValueError: scheduler file no-such-scheduler.json: no such file (a Dask scheduler started with a scheduler file writes it)
    """
    import os
    import time

    from .._io import check_input_file, parse_json, quote

    if not str(scheduler).endswith(".json"):
        return str(scheduler)
    if not os.path.exists(scheduler):
        raise ValueError(f"scheduler file {scheduler}: no such file (a Dask scheduler started with a scheduler file writes it)")
    for attempt in range(20):
        check_input_file(scheduler, max_bytes=1 << 20)
        try:
            with open(scheduler, encoding="utf-8") as f:
                doc = parse_json(f.read(), scheduler)
            break
        except ValueError:
            if attempt == 19:
                raise
            time.sleep(0.05)
    address = doc.get("address") if isinstance(doc, dict) else None
    if not isinstance(address, str) or not address:
        raise ValueError(f"{scheduler}: not a Dask scheduler file (a JSON object with an \"address\"), got {quote(doc)}")
    return address


def worker_count(client) -> int:
    """Workers the scheduler knows now (at least 1, for sizing tasks before any has joined)."""
    return max(1, len(client.scheduler_info(n_workers=-1).get("workers", {})))


def prepare_worker(x64: bool) -> None:
    """Run in a task before JAX is used: float64 on (if asked) and the compilation cache on, once per process."""
    if x64 in _prepared:
        return
    import jax

    if x64:
        jax.config.update("jax_enable_x64", True)
    if not _prepared:
        import warnings

        from .compile_cache import CacheWarning, enable_compilation_cache

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", CacheWarning)  # a worker without a cache folder still fits
            enable_compilation_cache()
    _prepared.add(x64)
