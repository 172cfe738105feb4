"""Ctrl-C in the ``ctfit`` command: exit status 130 and one line, at any moment, no file damaged.

:func:`install` (called by ``cli.main``) replaces Python's KeyboardInterrupt with an immediate
exit: the line is printed and the process leaves with ``os._exit(130)``. Nothing needs to
unwind: an atomic write under way is abandoned (its temporary file removed, the old file kept,
and the line says so), its final rename runs in :func:`deferred`, and so do the HDF5 chain's
writes, so a SIGINT during one takes effect when it ends. A Dask cluster made by the command is
shut down first (:func:`on_interrupt`), so that its processes leave nothing behind. An exception would
not do: one raised inside a callback (JAX's garbage-collection hook) or an import inside a C
extension is swallowed or printed as a traceback, and a normal interpreter exit while XLA's
threads still compile can crash (exit 139). Python runs signal handlers only between
bytecodes, so a SIGINT during a long call into XLA (a cold compile) would wait for it: the
signal also wakes a watcher thread (:func:`signal.set_wakeup_fd`), which exits the same way as
soon as no deferred write is under way.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from typing import Callable

__all__ = ["deferred", "exit_interrupted", "install", "note_resumable", "on_interrupt", "resumable"]

_WAIT_WRITES_S = 30.0  # the longest the watcher waits for a deferred write
_guard = threading.RLock()  # held by deferred writes; the watcher takes it before exiting
_exiting = threading.Lock()  # taken once, by whichever thread exits
_cleanups: list[Callable[[], None]] = []  # run before an interrupted exit (on_interrupt)
_state = {"depth": 0, "pending": False, "installed": False, "message": lambda: "interrupted", "resumable": None}


def note_resumable(path) -> None:
    """Record that a chain is being written to ``path``: an interruption can be resumed."""
    _state["resumable"] = os.fspath(path)


def resumable():
    """The chain file recorded by :func:`note_resumable`, or None."""
    return _state["resumable"]


def _handler(signum, frame):
    if _state["depth"]:
        _state["pending"] = True
        return
    exit_interrupted(_state["message"]())


@contextlib.contextmanager
def deferred(done: str | None = None):
    """Hold a SIGINT back until the block ends, for a write that must be whole; ``done``: what
    the interrupted line adds when the block ended normally (``"X was written in full"``).
    Without :func:`install` (a library user), Ctrl-C behaves as usual."""
    with _guard:
        _state["depth"] += 1
        ended = False
        try:
            yield
            ended = True
        finally:
            _state["depth"] -= 1
            if not _state["depth"] and _state["pending"] and threading.current_thread() is threading.main_thread():
                exit_interrupted(_state["message"](), [done] if ended and done else [])


def on_interrupt(cleanup: Callable[[], None]) -> Callable[[], None]:
    """Run ``cleanup()`` before an interrupted exit (a Dask cluster shut down cleanly); returns
    the function that withdraws it (call it once the resource is closed)."""
    _cleanups.append(cleanup)
    return lambda: _cleanups.remove(cleanup) if cleanup in _cleanups else None


def _run_cleanups() -> None:
    for cleanup in reversed(list(_cleanups)):
        try:
            cleanup()
        except BaseException:  # noqa: BLE001 — leaving anyway: a cleanup that fails is skipped
            pass


def exit_interrupted(message: str, notes=()) -> None:
    """Print ``message`` on stderr as one line and end the process with status 130, at once.

    Writes under way are abandoned (their temporary files removed): the line says which files
    were not written and kept their old content; ``notes`` adds what else to say. Cleanups
    (:func:`on_interrupt`) run first."""
    _exiting.acquire()  # a second caller waits here until the first has ended the process
    from .files import remove_temporaries

    notes = [*notes, *remove_temporaries()]
    _run_cleanups()
    message = "; ".join([message, *notes])
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # noqa: BLE001 — a closed or broken stream: nothing more to say there
            pass
    try:
        os.write(2, (message + "\n").encode())
    except OSError:
        pass
    os._exit(130)


def _watch(fd: int, message: Callable[[], str]) -> None:
    while True:
        try:
            got = os.read(fd, 64)
        except OSError:
            return
        if signal.SIGINT in got:
            _guard.acquire(timeout=_WAIT_WRITES_S)  # let a deferred write finish
            exit_interrupted(message())


def install(message: Callable[[], str]) -> bool:
    """Handle SIGINT as described in the module docstring; ``message()`` gives the line to print.

    Does nothing (returns False) outside the main thread, or when SIGINT is ignored (a job
    started in the background by a shell): an ignored signal stays ignored.
    """
    if _state["installed"]:
        return True
    if threading.current_thread() is not threading.main_thread() or signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        return False
    r, w = os.pipe()
    os.set_blocking(w, False)
    _state["message"] = message
    signal.signal(signal.SIGINT, _handler)
    signal.set_wakeup_fd(w, warn_on_full_buffer=False)
    threading.Thread(target=_watch, args=(r, message), name="ctfit-interrupt", daemon=True).start()
    _state["installed"] = True
    return True
