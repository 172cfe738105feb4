"""The programs a command used last time, loaded from the store while it reads its files.

A warm fit still loads its compiled programs from the store (:mod:`~ctfit._runtime.stored_programs`:
about 0.1–0.2 s for one structure), and it can ask for them only once its data is read: their
keys hold the data's bands and layout. The same command with the same options (a user fitting
one file of an instrument after another) asks for the same programs; so the ``ctfit fit`` command
records, at its end, the programs it asked for (:func:`record_programs`: their names and keys, in a
small file of the store named by a digest of the options that shape them), and the next run with
those options loads them in a thread of its own while it reads its files (:func:`start_preload`).

A program loaded ahead is kept aside, not used as it is: when the fit asks for it, it is tried on
the fit's arguments as any program loaded from the store (a damaged one is dropped there, and
compiled again). One the fit does not ask for is only dropped. The first program the fit asks for
that the record does not name (data of other bands, say) stops the loading: the rest would be
loaded for nothing. The thread and what it loaded end with the command (:meth:`Preload.finish`).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import re
import threading
import time

from .._io import atomic_write
from . import stored_programs as sp

__all__ = ["Preload", "programs_asked", "record_programs", "start_preload", "RECORDS_KEPT", "RECORD_PROGRAMS"]

RECORDS_KEPT = 32
"""Records kept in the store (one per set of options); beyond, the oldest are deleted."""

RECORD_PROGRAMS = 96
"""The most programs a record names (a default fit, its structure chosen among several, asks for
about 56)."""

_PREFIX = "recent-"
_NAME = re.compile(r"[A-Za-z0-9_]+")
_DIGEST = re.compile(r"[0-9a-f]{64}")


def _record_path(signature: str):
    store = sp._store()
    if store is None:
        return None
    return store / f"{_PREFIX}{hashlib.sha256(signature.encode()).hexdigest()[:32]}.json"


class Preload:
    """A background load of the programs the record of ``signature`` names (:func:`start_preload`):
    the thread finds the store (registering JAX's LAPACK kernels, 0.1 s), reads the record and loads
    them, so the command goes on reading its files at once."""

    def __init__(self, signature: str):
        self._stop = threading.Event()
        self.loaded: list[str] = []
        self._keys: set[str] | None = None  # the record's, once read
        self._early: list[str] = []  # programs asked for that were not loaded ahead, before the record was read
        self._guard = threading.Lock()  # the record's keys set, and _early read, against _missed
        sp._missed.append(self._missed)
        self._thread = threading.Thread(target=self._run, args=(signature,), name="ctfit-preload", daemon=True)
        self._thread.start()

    def _missed(self, key: str) -> None:
        """A program the record does not name was asked for: this run's data is not like the last
        run's (other bands, say), so the rest would be loaded for nothing. One asked for before
        the record is read is judged once it is (:meth:`_run`)."""
        with self._guard:
            if self._keys is None:
                self._early.append(key)
            elif key not in self._keys:
                self._stop.set()

    def _run(self, signature: str) -> None:
        path = _record_path(signature)
        try:
            entries = _entries(path) if path is not None else []
        except (OSError, ValueError, KeyError, TypeError):  # no record, or not one of ours: nothing ahead
            entries = []
        with self._guard:
            self._keys = {f"{name}-{digest}" for name, digest in entries}
            if any(key not in self._keys for key in self._early):
                self._stop.set()
        for name, digest in entries:
            if self._stop.is_set():
                return
            if sp.load_ahead(name, digest):
                self.loaded.append(f"{name}-{digest}")

    def finish(self) -> None:
        """Stop after the program being loaded, wait for it, and drop what no fit asked for."""
        self._stop.set()
        self._thread.join()
        with contextlib.suppress(ValueError):
            sp._missed.remove(self._missed)
        for key in self.loaded:
            sp._preloaded.pop(key, None)


def start_preload(signature: str) -> Preload:
    """Start loading, in a thread, the programs the last commands of ``signature`` (a text naming
    the options that shape its programs) recorded, if any (none without a store or a record)."""
    return Preload(signature)


def _entries(path) -> list[tuple[str, str]]:
    """The (name, digest) pairs a record holds; none where it was written by another ctfit (its
    source, or the versions of JAX and its libraries: :func:`~ctfit._runtime.stored_programs._environment_digest`),
    whose programs no run of this one asks for; OSError, ValueError, KeyError or TypeError where it
    is missing or malformed."""
    doc = json.loads(path.read_text())
    if doc["environment"] != sp._environment_digest():
        return []
    entries = [(n, d) for n, d in doc["programs"]]
    if not all(isinstance(n, str) and isinstance(d, str) and _NAME.fullmatch(n) and _DIGEST.fullmatch(d) for n, d in entries):
        raise ValueError("a record's programs are pairs of a name and a hexadecimal digest")  # (nothing outside the store is read)
    return entries


def programs_asked() -> dict[str, tuple[str, str]]:
    """From now on, every program asked for (in this process, any thread), in the order first
    asked: key → (name, digest); for :func:`record_programs`, which ends it."""
    asked: dict[str, tuple[str, str]] = {}
    sp._askers.append(asked)
    return asked


def record_programs(signature: str, asked: dict[str, tuple[str, str]], write: bool = True) -> None:
    """End the recording ``asked`` (:func:`programs_asked`) and, with ``write``, record its programs,
    in order, for the next command of ``signature`` to load ahead, then those of the record before
    not among them (one folder of small files and one large file, fitted in turn, each find theirs),
    :data:`RECORD_PROGRAMS` at most; keep :data:`RECORDS_KEPT` records."""
    sp._askers[:] = [a for a in sp._askers if a is not asked]  # (by identity: two recorders may hold equal contents)
    path = _record_path(signature) if write else None
    programs = [list(e) for e in asked.values()]
    if path is None or not programs:
        return
    with contextlib.suppress(OSError, ValueError, KeyError, TypeError):
        programs += [list(e) for e in _entries(path) if list(e) not in programs]
    with contextlib.suppress(OSError):
        doc = {"environment": sp._environment_digest(), "programs": programs[:RECORD_PROGRAMS]}
        atomic_write(path, [json.dumps(doc).encode()], quiet=True)
        records = sorted(path.parent.glob(f"{_PREFIX}*.json"), key=_mtime)
        for old in records[: max(len(records) - RECORDS_KEPT, 0)]:
            old.unlink(missing_ok=True)


def _mtime(path) -> float:
    try:
        return path.stat().st_mtime
    except OSError:  # deleted meanwhile (another process keeping its records)
        return time.time()
