"""Ctrl-C and the writes that must be whole: the hooks that the command's handler uses.

The ``ctfit`` command handles SIGINT itself (:mod:`ctfit._cli.interrupt`: status 130 and one
line, at once). What the rest of ctfit needs from it lives here, below the command:

- :func:`deferred`: a write that must be whole (an atomic write's final rename, the HDF5 chain's
  steps) holds a SIGINT back until it ends;
- :func:`on_interrupt`: a cleanup to run before an interrupted exit (a Dask cluster shut down);
- :func:`note_resumable`: a chain file is being written, so the line can say how to resume.

Without the command's handler (a library user) Ctrl-C behaves as usual: :func:`deferred` only
counts, and nothing here exits.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Callable
from typing import TypedDict

__all__ = ["deferred", "note_resumable", "on_interrupt", "resumable", "run_cleanups", "set_exit", "sigint", "wait_for_writes"]

_guard = threading.RLock()  # held by deferred writes; the command's watcher takes it before exiting
_cleanups: list[Callable[[], str | None]] = []  # run before an interrupted exit (on_interrupt)


def _interrupt(notes: list[str]) -> None:
    raise KeyboardInterrupt  # no command's exit set: what Ctrl-C does by default


class _State(TypedDict):
    """What :func:`deferred` and the command's handler share."""

    depth: int  # deferred blocks under way
    pending: bool  # a SIGINT held back until they end
    resumable: str | Callable[[], object] | None  # the chain file being written (note_resumable)
    exit: Callable[[list[str]], None]  # the command's exit (set_exit)


_state: _State = {"depth": 0, "pending": False, "resumable": None, "exit": _interrupt}


def note_resumable(path) -> None:
    """Record that a chain is being written to ``path``: an interruption can be resumed.
    ``path`` may be a function giving the path, or None while there is nothing to resume yet."""
    _state["resumable"] = path if callable(path) else os.fspath(path)


def resumable():
    """The chain file recorded by :func:`note_resumable`, or None."""
    got = _state["resumable"]
    if callable(got):
        path = got()
        return None if path is None else os.fspath(path)  # type: ignore[call-overload]  # a path, by note_resumable's contract
    return got


def set_exit(exit_now: Callable[[list[str]], None]) -> None:
    """The command's exit on SIGINT, ``exit_now(notes)``: called by :func:`sigint`, or when the
    :func:`deferred` block under way ends (with what it adds to the line)."""
    _state["exit"] = exit_now


def sigint() -> None:
    """A SIGINT arrived (the command's handler): exit now, or when the deferred write ends."""
    if _state["depth"]:
        _state["pending"] = True
        return
    _state["exit"]([])


def wait_for_writes(timeout: float) -> None:
    """Wait (at most ``timeout`` seconds) until no deferred write is under way; they stay held back after."""
    _guard.acquire(timeout=timeout)


@contextlib.contextmanager
def deferred(done: str | None = None):
    """Hold a SIGINT back until the block ends, for a write that must be whole; ``done``: what
    the interrupted line adds when the block ended normally (``"X was written in full"``).
    Without the command's handler (a library user), Ctrl-C behaves as usual."""
    with _guard:
        _state["depth"] += 1
        ended = False
        try:
            yield
            ended = True
        finally:
            _state["depth"] -= 1
            if not _state["depth"] and _state["pending"] and threading.current_thread() is threading.main_thread():
                _state["exit"]([done] if ended and done else [])


def on_interrupt(cleanup: Callable[[], str | None]) -> Callable[[], None]:
    """Run ``cleanup()`` before an interrupted exit (a Dask cluster shut down cleanly; what it
    returns, if a string, is added to the line); returns the function that withdraws it (call
    it once the resource is closed)."""
    _cleanups.append(cleanup)
    return lambda: _cleanups.remove(cleanup) if cleanup in _cleanups else None


def run_cleanups() -> list[str]:
    """Run the cleanups of :func:`on_interrupt`, the last registered first; one that fails is
    skipped. Returns what they said (their strings)."""
    said: list[str] = []
    for cleanup in reversed(list(_cleanups)):
        try:
            note = cleanup()
        except BaseException:  # leaving anyway: a cleanup that fails is skipped
            continue
        if isinstance(note, str):
            said.append(note)
    return said
