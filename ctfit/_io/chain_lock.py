"""One run at a time writes an HDF5 chain file: a lock beside it, held from its check to the run's end.

emcee's HDF5 backend opens and closes the chain file at every step, and HDF5 locks the file
while it is open: a second run that opened the same file meanwhile (to check it, continue it or
start it again) made the first one's next step fail ("unable to lock file"), and a long
sampling run died. A run now takes an exclusive ``flock`` on a file beside the chain before it
reads the chain, and keeps it until it ends (the resume check, the steps, the new chain's
rename over the old one); a second run on the same file is refused at its start
(:func:`~ctfit._io.output_paths.check_backend`).

Why a file beside the chain, ``.NAME.lock`` in its folder: not the chain itself (HDF5 takes its
own ``flock`` there, and a POSIX lock, ``fcntl.lockf``, is dropped by each close HDF5 makes at
every step), and not a per-user folder (two users, or two hosts sharing the folder, would not
see each other's locks). It is named after the chain's real path (links followed): every
spelling of the file, and the temporary file a new chain is written to before it replaces the
chain (:class:`~ctfit._sampling.backend.NewChain`), are under one lock. A hard link is another name of the
same file with a lock of its own: a chain file of several names is not continued
(:func:`~ctfit._io.output_paths.check_backend`).

A killed run leaves no lock behind: the kernel drops a ``flock`` with the process (the file is
opened close-on-exec: no program the run starts keeps it). The file is removed when the run
ends, while it is still locked (an interrupted command too: :func:`~ctfit._io.interrupt.on_interrupt`);
a run that got the lock of a file removed meanwhile sees its inode gone from the name and tries
again. Where the file cannot be made or locked (a read-only folder, a link there, a file system
without locks, no ``fcntl``) the run goes on unlocked, as before.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from .files import writes_in_place
from .interrupt import on_interrupt

try:
    import fcntl
except ImportError:  # not POSIX (Windows): runs go unlocked
    fcntl = None  # type: ignore[assignment]

__all__ = ["hold_chain", "lock_path"]

_TRIES = 8  # locks of files removed under it before a run gives up (each one another run's end)


@dataclass
class _Held:
    fd: int
    depth: int  # the holder's nested hold_chain blocks
    thread: int
    withdraw: Callable[[], None]  # of the removal on an interrupted exit (on_interrupt)


_held: dict[str, _Held] = {}  # lock file → this process's hold of it
_holding = threading.Lock()


def lock_path(path) -> Path:
    """The lock file of the chain file ``path``: ``.NAME.lock`` in the folder of the file it names
    (links followed); where that name is too long for the folder, ``.DIGEST.lock``."""
    real = Path(os.path.realpath(path))
    name = f".{real.name}.lock"
    try:
        longest = os.pathconf(real.parent, "PC_NAME_MAX")
    except (OSError, ValueError):
        longest = 255
    if len(os.fsencode(name)) > longest:
        name = f".{hashlib.sha256(os.fsencode(real.name)).hexdigest()[:32]}.lock"
    return real.parent / name


@contextlib.contextmanager
def hold_chain(path):
    """Hold the lock of the chain file ``path`` (:func:`lock_path`) for the block; raises
    ``BlockingIOError`` where another run holds it: another process, or another thread of this
    one. The thread that holds it may enter again (the command's check, then ``sample``'s). A
    device or pipe, or a lock that cannot be made, is not locked."""
    key = _take(path)
    try:
        yield
    finally:
        if key is not None:
            _give_back(key)


def _take(path) -> str | None:
    """The lock file now held (or held again) by this thread, or None: not locked."""
    if fcntl is None or writes_in_place(path):
        return None
    key = os.fspath(lock_path(path))
    with _holding:
        held = _held.get(key)
        if held is not None:
            if held.thread != threading.get_ident():
                raise BlockingIOError(errno.EWOULDBLOCK, "another thread of this program holds the lock", key)
            held.depth += 1
            return key
        fd = _locked(key)
        if fd is None:
            return None
        _held[key] = _Held(fd, 1, threading.get_ident(), on_interrupt(lambda: _remove(fd, key)))
    return key


def _locked(key: str) -> int | None:
    """A descriptor of ``key`` under an exclusive ``flock``; None where it cannot be made or locked."""
    for _ in range(_TRIES):
        try:
            fd = os.open(key, os.O_RDONLY | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)  # flock needs no write access
        except OSError:
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise
        except OSError:
            os.close(fd)
            return None
        if _names(fd, key):
            return fd
        os.close(fd)  # the run that held it removed it when it ended: lock the file there now
    raise BlockingIOError(errno.EWOULDBLOCK, "the lock file is made and removed without end", key)


def _names(fd: int, key: str) -> bool:
    """Whether ``key`` still names the file open at ``fd``."""
    try:
        at = os.stat(key, follow_symlinks=False)
    except OSError:
        return False
    own = os.fstat(fd)
    return (at.st_dev, at.st_ino) == (own.st_dev, own.st_ino)


def _give_back(key: str) -> None:
    """End one hold of ``key``; the last one removes the file (still locked) and unlocks it."""
    with _holding:
        held = _held[key]
        held.depth -= 1
        if held.depth:
            return
        del _held[key]
        held.withdraw()
        _remove(held.fd, key)
        os.close(held.fd)


def _remove(fd: int, key: str) -> None:
    """Remove the lock file ``key`` where it is still the one open at ``fd`` (held: no other run
    has it). Also the cleanup of an interrupted command, which exits at once (``os._exit``): a
    Ctrl-C left ``.NAME.lock`` beside the chain."""
    if _names(fd, key):
        with contextlib.suppress(OSError):  # a folder made read-only meanwhile: the file stays, unlocked
            os.unlink(key)
