"""Ctrl-C in the ``ctfit`` command: exit status 130 and one line, at any moment, no file damaged
(SIGTERM, ``kill``, the same: status 143, the line says "terminated").

:func:`install` (called by ``cli.main``) replaces Python's KeyboardInterrupt with an immediate
exit: the line is printed and the process leaves with ``os._exit(130)``. Nothing needs to
unwind: an atomic write under way is abandoned (its temporary file removed, the old file kept,
and the line says so), its final rename runs in :func:`ctfit._io.interrupt.deferred`, and so do
the HDF5 chain's writes, so a SIGINT during one takes effect when it ends. A Dask cluster made
by the command is shut down first (:func:`ctfit._io.interrupt.on_interrupt`), so that its
processes leave nothing behind. An exception would not do: one raised inside a callback (JAX's
garbage-collection hook) or an import inside a C extension is swallowed or printed as a
traceback, and a normal interpreter exit while XLA's threads still compile can crash (exit
139). Python runs signal handlers only between bytecodes, so a SIGINT during a long call into
XLA (a cold compile) would wait for it: the signal also wakes a watcher thread
(:func:`signal.set_wakeup_fd`), which exits the same way as soon as no deferred write is under
way. The library below the command only marks its writes and cleanups (:mod:`ctfit._io.interrupt`).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Callable

from .._io import remove_temporaries, run_cleanups, set_exit, sigint, wait_for_writes

__all__ = ["exit_interrupted", "install"]

_WAIT_WRITES_S = 30.0  # the longest the watcher waits for a deferred write
_exiting = threading.Lock()  # taken once, by whichever thread exits
_installed = threading.Event()
_terminated = threading.Event()  # SIGTERM (``kill``): the same exit, with status 143 and "terminated"


def exit_interrupted(message: str | Callable[[], str], notes=()) -> None:
    """Print ``message`` (or what ``message()`` gives) on stderr as one line and end the process
    with status 130, at once.

    Writes under way are abandoned (their temporary files removed): the line says which files
    were not written and kept their old content; ``notes`` adds what else to say. Cleanups
    (:func:`ctfit._io.interrupt.on_interrupt`) run first. A callable ``message`` is called only
    by the thread that exits: the main thread and the watcher may both be on their way here,
    and the second must not read the state the first is winding up (a traceback of the watcher
    thread once came before the line)."""
    _exiting.acquire()  # a second caller waits here until the first has ended the process
    if callable(message):
        try:
            message = message()
        except Exception:  # what it describes changed under it: the plain line
            message = "interrupted"
    if _terminated.is_set():
        message = message.replace("interrupted", "terminated", 1)
    notes = [*notes, *remove_temporaries(last=True)]
    notes += run_cleanups()
    message = "; ".join([message, *notes])
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # a closed or broken stream: nothing more to say there
            pass
    try:
        os.write(2, (message + "\n").encode())
    except OSError:
        pass
    os._exit(128 + (signal.SIGTERM if _terminated.is_set() else signal.SIGINT))


def _watch(fd: int, message: Callable[[], str]) -> None:
    while True:
        try:
            got = os.read(fd, 64)
        except OSError:
            return
        if signal.SIGTERM in got:
            _terminated.set()
        if signal.SIGINT in got or signal.SIGTERM in got:
            wait_for_writes(_WAIT_WRITES_S)  # let a deferred write finish
            exit_interrupted(message)


def _on_sigterm(signum, frame) -> None:
    _terminated.set()
    sigint()


def install(message: Callable[[], str]) -> bool:
    """Handle SIGINT (and SIGTERM, where it has its default action) as described in the module
    docstring; ``message()`` gives the line to print.

    Does nothing (returns False) outside the main thread; an ignored SIGINT (a job started in the
    background by a shell) stays ignored, and SIGTERM is handled only where it has its default action.
    """
    if _installed.is_set():
        return True
    if threading.current_thread() is not threading.main_thread():
        return False
    on_int = signal.getsignal(signal.SIGINT) is not signal.SIG_IGN
    on_term = signal.getsignal(signal.SIGTERM) is signal.SIG_DFL  # kill: the same, but status 143 (a terminated job's)
    if not (on_int or on_term):
        return False
    r, w = os.pipe()
    os.set_blocking(w, False)
    set_exit(lambda notes: exit_interrupted(message, notes))
    if on_int:
        signal.signal(signal.SIGINT, lambda signum, frame: sigint())
    if on_term:
        signal.signal(signal.SIGTERM, _on_sigterm)
    signal.set_wakeup_fd(w, warn_on_full_buffer=False)
    threading.Thread(target=_watch, args=(r, message), name="ctfit-interrupt", daemon=True).start()
    _installed.set()
    return True
