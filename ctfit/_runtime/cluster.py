"""Where distributed work runs: a Dask client for an existing cluster, or an embedded local one.

``ctfit`` does not schedule work itself: it hands coarse tasks (a group of files, a chunk of
texels) to `Dask distributed <https://distributed.dask.org>`_. :func:`dask_client` is the one
place that makes a client — connected to a running scheduler (``ctfit fit --scheduler ADDRESS``)
or to a :class:`distributed.LocalCluster` of worker processes (``--workers N``, one thread each:
JAX already uses the cores of a worker's machine inside one fit) — and closes what it made.
The cluster's own log lines (ports, workers starting and stopping) are kept below ERROR.

Workers are separate processes: :func:`prepare_worker` runs at the start of every task and
switches float64 on where the task asks for it and the persistent compilation cache on
(``ctfit/_runtime/compile_cache.py``), once per process, so every worker keeps and reuses the compiled programs.
"""

from __future__ import annotations

import contextlib
import logging

__all__ = ["CONNECT_TIMEOUT", "dask_client", "prepare_worker", "scheduler_address", "worker_count"]

_LOGGERS = ("distributed", "tornado", "bokeh")
CONNECT_TIMEOUT = "30s"
"""How long ``dask_client`` tries to reach a scheduler before it gives up (an ``OSError``)."""
_prepared: set[bool] = set()


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
    from distributed import Client, LocalCluster

    if scheduler is not None:
        with Client(address=scheduler_address(scheduler), timeout=CONNECT_TIMEOUT) as made:
            yield made
        return
    if workers is not None and workers < 1:
        raise ValueError(f"workers must be ≥ 1, got {workers}")
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=logging.ERROR) as cluster, Client(cluster) as made:
        yield made


def scheduler_address(scheduler) -> str:
    """The address of ``scheduler``: itself, or read from a scheduler file (``.json``, the one
    a Dask scheduler writes when it is given a file) — read once, so a missing file is an error at
    once (``distributed`` would wait for it to appear) and a file that is not one says so.

    >>> scheduler_address("tcp://127.0.0.1:8786")
    'tcp://127.0.0.1:8786'
    >>> scheduler_address("no-such-scheduler.json")
    Traceback (most recent call last):
    ValueError: scheduler file no-such-scheduler.json: no such file (a Dask scheduler started with a scheduler file writes it)
    """
    import json
    from pathlib import Path

    if not str(scheduler).endswith(".json"):
        return str(scheduler)
    what = f"scheduler file {scheduler}"
    try:
        doc = json.loads(Path(scheduler).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ValueError(f"{what}: no such file (a Dask scheduler started with a scheduler file writes it)") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ValueError(f"{what}: cannot be read ({getattr(e, 'strerror', None) or e})") from None
    except ValueError as e:
        raise ValueError(f"{what}: is not JSON ({e}); a Dask scheduler file is a JSON object with the scheduler's 'address'") from None
    address = doc.get("address") if isinstance(doc, dict) else None
    if not isinstance(address, str) or not address:
        raise ValueError(f"{what}: has no 'address': a Dask scheduler file is a JSON object such as " + '{"address": "tcp://HOST:8786", ...}')
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
