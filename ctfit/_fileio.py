"""Reading and writing whole files: UTF-8 text with located decoding errors, atomic writes."""

from __future__ import annotations

import os

from ._errors import DataError

__all__ = ["atomic_write", "read_text", "read_utf8"]


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


def atomic_write(path, chunks) -> None:
    """Write ``chunks`` (all ``str`` or all ``bytes``) to a new file beside ``path``, then rename it
    over ``path``: readers see the old file or the whole new one, never a part."""
    path = os.fspath(path)
    folder, name = os.path.split(os.path.abspath(path))
    tmp = os.path.join(folder, f".{name}.{os.getpid()}.{os.urandom(4).hex()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)  # the umask applies, as for open()
    try:
        with os.fdopen(fd, "wb") as f:
            for chunk in chunks:
                f.write(chunk.encode("utf-8") if isinstance(chunk, str) else chunk)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise
