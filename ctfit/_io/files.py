"""Reading and writing whole files: UTF-8 text with located decoding errors, atomic writes."""

from __future__ import annotations

import errno
import io
import os
import re
import stat
import threading
from collections.abc import Callable

from .errors import DataError
from .interrupt import deferred

__all__ = [
    "TEMPORARY",
    "atomic_save",
    "atomic_write",
    "map_utf8",
    "read_text",
    "read_utf8",
    "remove_stale_temporaries",
    "remove_temporaries",
    "replace_links_in",
    "temporary_for",
    "writes_in_place",
]

_temporaries: dict[str, tuple[str | None, bool]] = {}  # writes under way: temporary → (the user's path, whether a file is there)
_creating = threading.Lock()  # a temporary is made and listed under it; the last sweep keeps it (see remove_temporaries)


MAP_BYTES = 1 << 26
"""Files of this size and more are mapped (:func:`map_utf8`), not read into memory."""
_CHECK_BLOCK = 1 << 20  # decoded a block at a time: the text is never held whole


def read_utf8(path) -> bytes:
    """The file's bytes, checked to be UTF-8, without a leading byte-order mark.

    Undecodable bytes raise :class:`DataError` naming the line and the byte offset.
    """
    with open(path, "rb") as f:
        raw = f.read()
    _check_utf8(raw, path)
    return raw.removeprefix(b"\xef\xbb\xbf")


def map_utf8(path):
    """The file's bytes as :func:`read_utf8` gives them, but a file of :data:`MAP_BYTES` or more
    is mapped read-only (``mmap``) instead of read: a reader that goes through it block by block
    holds a block at a time, whatever the file's size. Returns (buffer, offset of the first byte
    after a byte-order mark). The buffer supports ``find``, ``rfind``, slicing and ``len``."""
    import mmap

    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        raw: bytes | mmap.mmap
        if size < MAP_BYTES:
            raw = f.read()
        else:
            raw = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
    _check_utf8(raw, path)
    return raw, 3 if raw[:3] == b"\xef\xbb\xbf" else 0


def _check_utf8(raw, path) -> None:
    """:class:`DataError` (line, byte offset) at the first byte of ``raw`` that is not UTF-8,
    decoded block by block (an incremental decoder: a character may span two blocks)."""
    import codecs

    decoder = codecs.getincrementaldecoder("utf-8")()
    for start in range(0, max(len(raw), 1), _CHECK_BLOCK):
        block = raw[start : start + _CHECK_BLOCK]
        if block.isascii():
            continue
        try:
            decoder.decode(block, final=start + _CHECK_BLOCK >= len(raw))
        except UnicodeDecodeError as e:
            at = start + e.start - len(decoder.getstate()[0])
            line = sum(raw[i : min(i + _CHECK_BLOCK, at)].count(b"\n") for i in range(0, at, _CHECK_BLOCK)) + 1
            line_start = raw.rfind(b"\n", 0, at) + 1
            raise DataError(
                f"byte 0x{raw[at]:02x} at byte offset {at} (byte {at - line_start + 1} of the line) "
                "is not UTF-8; save the file as UTF-8 (plain ASCII is fine)",
                path=path,
                line=line,
            ) from None
    try:
        decoder.decode(b"", final=True)
    except UnicodeDecodeError as e:
        at = len(raw) - len(decoder.getstate()[0]) + e.start
        raise DataError(f"the file ends inside a UTF-8 character (byte offset {at}); save the file as UTF-8", path=path) from None


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


def _named(err: OSError, path: str, tmp: str | None) -> OSError:
    """``err`` naming the user's ``path`` where it named the temporary file, or nothing."""
    if err.filename in (None, tmp) and err.errno is not None:
        return type(err)(err.errno, err.strerror, path)
    return err


TEMPORARY = re.compile(r"^\.ctfit-(\d+)-[0-9a-f]{8}\.tmp$")
"""The name of a write's temporary file: ``.ctfit-PID-RANDOM.tmp`` beside its target (fixed
length, whatever the target's name; the PID says which process writes it)."""

_swept: set[str] = set()  # folders already cleared of stale temporaries by this process
_replacing: set[str] = set()  # folders whose links are replaced, not written through


def replace_links_in(folder) -> None:
    """Atomic writes into ``folder`` replace a symbolic link found at the target's name
    instead of writing through it: for output folders whose file names ``ctfit`` chooses."""
    _replacing.add(os.path.abspath(os.fspath(folder)))


def _alive(pid: int, since: float) -> bool:
    """Whether process ``pid`` runs and started no later than ``since`` (not a reused PID)."""
    import psutil

    try:
        return psutil.Process(pid).create_time() <= since + 1.0
    except (psutil.NoSuchProcess, psutil.ZombieProcess):
        return False
    except psutil.Error:  # another user's process: not ours to judge
        return True


def remove_stale_temporaries(folder) -> list[str]:
    """Remove the temporaries (:data:`TEMPORARY`) that a killed ``ctfit`` left in ``folder``:
    this user's, whose process has ended (or whose PID now belongs to a later process).
    Returns the names removed. Done once per folder by the first write into it."""
    removed: list[str] = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        m = TEMPORARY.match(entry.name)
        if m is None or entry.path in _temporaries:
            continue
        try:
            st = entry.stat(follow_symlinks=False)
            if st.st_uid != os.getuid() or not stat.S_ISREG(st.st_mode) or _alive(int(m[1]), st.st_mtime):
                continue
            os.unlink(entry.path)
            removed.append(entry.name)
        except OSError:
            pass
    return removed


def _destination(path: str) -> str:
    """Where the write goes: a link's target, or (in a folder of :func:`replace_links_in`) the link itself."""
    if os.path.islink(path) and os.path.dirname(os.path.abspath(path)) in _replacing:
        return os.path.abspath(path)
    return os.path.realpath(path)


def _write_in_place(path: str, chunks) -> None:
    """Write into a device or pipe; a pipe whose reader has gone (``-o /dev/stdout | head``) ends the write quietly."""
    try:
        with open(path, "wb") as f:
            for chunk in chunks:
                f.write(chunk.encode("utf-8") if isinstance(chunk, str) else chunk)
    except BrokenPipeError:
        return
    except OSError as e:
        raise _named(e, path, None) from None


def temporary_for(path) -> tuple[str, str, int | None]:
    """(temporary, target, mode): where a new file for ``path`` is made before it is renamed over
    ``target`` (:func:`atomic_write`'s rules: a link's target, or the link in a folder of
    :func:`replace_links_in`), and the permissions to give it (the old file's; None: the umask's).
    A read-only file is refused (``PermissionError``); the first call for a folder removes its
    stale temporaries (:func:`remove_stale_temporaries`). The temporary is not made here."""
    path = os.fspath(path)
    target = _destination(path)
    try:
        mode: int | None = stat.S_IMODE(os.stat(target, follow_symlinks=False).st_mode)
    except FileNotFoundError:
        mode = None
    if mode is not None and os.path.islink(target):
        mode = None  # a link replaced by a new file: the umask's mode
    if mode is not None and not mode & 0o222:
        raise PermissionError(errno.EACCES, "the file is read-only (no write permission); not replaced", path)
    folder = os.path.dirname(target)
    if folder not in _swept:
        _swept.add(folder)
        remove_stale_temporaries(folder)
    return os.path.join(folder, f".ctfit-{os.getpid()}-{os.urandom(4).hex()}.tmp"), target, mode


def atomic_write(path, chunks, *, quiet: bool = False, existing: Callable[[str], None] | None = None) -> None:
    """Write ``chunks`` (all ``str`` or all ``bytes``) to a new file beside ``path``, then rename it
    over ``path``: readers see the old file or the whole new one, never a part.

    A symbolic link stays a link: the file it leads to is replaced (in a folder of
    :func:`replace_links_in`, the link itself is replaced). A device, a FIFO or ``/dev/stdout``
    is written straight into (:func:`writes_in_place`). A file whose mode has no write bit is
    not replaced (``PermissionError``, even for root); the new file keeps the old one's
    permissions. Errors name ``path``, never the temporary file (:data:`TEMPORARY`), which is
    removed on any error; the first write into a folder removes stale ones
    (:func:`remove_stale_temporaries`). In the ``ctfit`` command a Ctrl-C during the write
    removes the temporary file and keeps the old one, and says so (``_cli/interrupt.py``);
    ``quiet``: a write of ctfit's own (a cache entry), removed but not mentioned then.
    ``existing``: the new file is placed where no file is (linked in place, which fails where one
    is; where the file system has no links, checked just before); where one is at that moment,
    ``existing(path)`` is called first and may raise to keep it (even one that another process
    put there a moment before).
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        raise IsADirectoryError(errno.EISDIR, "is a folder, not a file", path)
    if writes_in_place(path):
        _write_in_place(path, chunks)
        return
    tmp, target, mode = temporary_for(path)
    try:
        with _creating:  # made and listed together: a sweep sees both or neither
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)  # the umask applies, as for open()
            _temporaries[tmp] = (None if quiet else path, mode is not None or os.path.lexists(target))
        with os.fdopen(fd, "wb") as f:
            if mode is not None:
                os.fchmod(f.fileno(), mode)
            for chunk in chunks:
                f.write(chunk.encode("utf-8") if isinstance(chunk, str) else chunk)
            f.flush()
            os.fsync(f.fileno())
        with deferred(done=None if quiet else f"{path} was written in full"):
            if existing is None:
                os.replace(tmp, target)
            else:
                _place_new(tmp, target, lambda: existing(path))
            _temporaries.pop(tmp, None)
    except BaseException as e:
        remove_temporaries([tmp])
        if isinstance(e, OSError):
            raise _named(e, path, tmp) from None
        raise
    finally:
        _temporaries.pop(tmp, None)


def _place_new(tmp: str, target: str, existing: Callable[[], None]) -> None:
    """``tmp`` renamed to ``target`` where no file is; where one is, after ``existing()`` (which
    raises to keep it)."""
    try:
        os.link(tmp, target)
    except OSError as e:  # a file there, or no hard links here (some network and FAT file systems): checked, then renamed
        if isinstance(e, FileExistsError) or os.path.lexists(target):
            existing()
        os.replace(tmp, target)
        return
    os.unlink(tmp)


def atomic_save(path, save) -> None:
    """``save(buffer)`` into memory, then :func:`atomic_write` to ``path``: for writers that want a
    file object (``fig.savefig(buffer, format=...)``, Pillow's ``image.save(buffer, format=...)``)."""
    buffer = io.BytesIO()
    save(buffer)
    atomic_write(path, [buffer.getvalue()])


def remove_temporaries(paths=None, *, last: bool = False) -> list[str]:
    """Remove the temporary files of writes under way (all of them by default): for an exit that
    cannot wait for them to finish (Ctrl-C, see ``_cli/interrupt.py``). Returns what that means
    for each file: ``"PATH was not written (its old content is kept)"`` (or ``"… not created"``).

    ``last``: the process ends next (``os._exit``). No temporary is made after this sweep: a write
    in another thread (the program store's, in the background) waits at its first step until the
    process has gone, instead of leaving a new temporary file behind."""
    if last:
        _creating.acquire()  # never released: the process is ending
    said = []
    for tmp in list(_temporaries if paths is None else paths):
        path, existed = _temporaries.get(tmp, (None, False))
        try:
            os.unlink(tmp)
        except OSError:
            continue
        if path is not None:
            said.append(f"{path} was not written (its old content is kept)" if existed else f"{path} was not created")
    return said
