"""Reading and writing whole files: UTF-8 text with located decoding errors, atomic writes."""

from __future__ import annotations

import errno
import io
import os
import stat

from .errors import DataError
from .interrupt import deferred

__all__ = ["atomic_save", "atomic_write", "read_text", "read_utf8", "remove_temporaries", "writes_in_place"]

_temporaries: set[str] = set()  # writes under way


def read_utf8(path) -> bytes:
    """The file's bytes, checked to be UTF-8, without a leading byte-order mark.

    Undecodable bytes raise :class:`DataError` naming the line and the byte offset.
    """
    with open(path, "rb") as f:
        raw = f.read()
    if not raw.isascii():
        try:
            raw.decode("utf-8")
        except UnicodeDecodeError as e:
            line = raw.count(b"\n", 0, e.start) + 1
            line_start = raw.rfind(b"\n", 0, e.start) + 1
            raise DataError(
                f"byte 0x{raw[e.start]:02x} at byte offset {e.start} (byte {e.start - line_start + 1} of the line) "
                "is not UTF-8; save the file as UTF-8 (plain ASCII is fine)",
                path=path,
                line=line,
            ) from None
    return raw.removeprefix(b"\xef\xbb\xbf")


def read_text(path) -> str:
    """The file decoded as UTF-8 (see :func:`read_utf8`)."""
    return read_utf8(path).decode("utf-8")


def writes_in_place(path) -> bool:
    """Whether ``path`` is written straight into rather than replaced: a device or FIFO
    (``/dev/null``), or whatever a process's descriptor leads to (``/dev/stdout``, ``/proc/self/fd/1``)."""
    p = os.path.abspath(os.fspath(path))
    for _ in range(40):  # follow links one at a time: /proc's links lead to no real path
        if p.startswith(("/proc/", "/dev/fd/")):
            return os.path.exists(p)
        if not os.path.islink(p):
            break
        p = os.path.normpath(os.path.join(os.path.dirname(p), os.readlink(p)))
    try:
        mode = os.stat(p).st_mode
    except OSError:
        return False
    return not stat.S_ISREG(mode) and not stat.S_ISDIR(mode)


def _named(err: OSError, path: str, tmp: str) -> OSError:
    """``err`` naming the user's ``path`` where it named the temporary file, or nothing."""
    if err.filename in (None, tmp) and err.errno is not None:
        return type(err)(err.errno, err.strerror, path)
    return err


def atomic_write(path, chunks) -> None:
    """Write ``chunks`` (all ``str`` or all ``bytes``) to a new file beside ``path``, then rename it
    over ``path``: readers see the old file or the whole new one, never a part.

    A symbolic link stays a link: the file it leads to is replaced. A device, a FIFO or
    ``/dev/stdout`` is written straight into (:func:`writes_in_place`). A file whose mode has no
    write bit is not replaced (``PermissionError``, even for root); the new file keeps the old
    one's permissions. Errors name ``path``, never the temporary file, which is removed on any
    error. In the ``ctfit`` command a Ctrl-C waits for the write to end (``_io/interrupt.py``).
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        raise IsADirectoryError(errno.EISDIR, "is a folder, not a file", path)
    if writes_in_place(path):
        with open(path, "wb") as f:
            for chunk in chunks:
                f.write(chunk.encode("utf-8") if isinstance(chunk, str) else chunk)
        return
    target = os.path.realpath(path)
    try:
        mode = stat.S_IMODE(os.stat(target).st_mode)
    except FileNotFoundError:
        mode = None
    if mode is not None and not mode & 0o222:
        raise PermissionError(errno.EACCES, "the file is read-only (no write permission); not replaced", path)
    folder, name = os.path.split(target)
    tmp = os.path.join(folder, f".{name}.{os.getpid()}.{os.urandom(4).hex()}.tmp")
    with deferred():
        _temporaries.add(tmp)
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)  # the umask applies, as for open()
            with os.fdopen(fd, "wb") as f:
                if mode is not None:
                    os.fchmod(f.fileno(), mode)
                for chunk in chunks:
                    f.write(chunk.encode("utf-8") if isinstance(chunk, str) else chunk)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, target)
        except BaseException as e:
            remove_temporaries([tmp])
            if isinstance(e, OSError):
                raise _named(e, path, tmp) from None
            raise
        finally:
            _temporaries.discard(tmp)


def atomic_save(path, save) -> None:
    """``save(buffer)`` into memory, then :func:`atomic_write` to ``path``: for writers that want a
    file object (``fig.savefig(buffer, format=...)``, Pillow's ``image.save(buffer, format=...)``)."""
    buffer = io.BytesIO()
    save(buffer)
    atomic_write(path, [buffer.getvalue()])


def remove_temporaries(paths=None) -> None:
    """Remove the temporary files of writes under way (all of them by default): for an exit that
    cannot wait for them to finish (Ctrl-C, see ``_io/interrupt.py``)."""
    for tmp in list(_temporaries if paths is None else paths):
        try:
            os.unlink(tmp)
        except OSError:
            pass
