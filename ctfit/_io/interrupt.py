"""Ctrl-C in the ``ctfit`` command: exit status 130 and one line, at any moment, no file damaged.

:func:`install` (called by ``cli.main``) replaces Python's KeyboardInterrupt with an immediate
exit: the line is printed and the process leaves with ``os._exit(130)``. Nothing needs to
unwind: atomic writes run in :func:`deferred` (their temporary file is also removed), and so do
the HDF5 chain's writes, so a SIGINT during one takes effect when it ends. An exception would
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

__all__ = ["deferred", "exit_interrupted", "install", "note_resumable", "resumable"]

_WAIT_WRITES_S = 30.0  # the longest the watcher waits for a deferred write
_guard = threading.RLock()  # held by deferred writes; the watcher takes it before exiting
_exiting = threading.Lock()  # taken once, by whichever thread exits
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
def deferred():
    """Hold a SIGINT back until the block ends, for a write that must be whole. Without
    :func:`install` (a library user), Ctrl-C behaves as usual."""
    with _guard:
        _state["depth"] += 1
        try:
            yield
        finally:
            _state["depth"] -= 1
            if not _state["depth"] and _state["pending"] and threading.current_thread() is threading.main_thread():
                exit_interrupted(_state["message"]())


def exit_interrupted(message: str) -> None:
    """Print ``message`` on stderr as one line and end the process with status 130, at once."""
    _exiting.acquire()  # a second caller waits here until the first has ended the process
    from .files import remove_temporaries

    remove_temporaries()
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
