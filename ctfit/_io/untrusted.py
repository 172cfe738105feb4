"""Reading files that may be hostile: only regular files, text that is text, error messages that
quote a bounded part of a file, and parsers' depth and number limits turned into one error that
names the file.

Every reader calls :func:`check_input_file` before it reads: a device (``/dev/zero``, or a link
to it), a FIFO or a socket is refused before anything is read (it may never end), and a text
format's first block is looked at for what text never holds (NUL bytes, a UTF-16 or UTF-32
byte-order mark, bytes that are not UTF-8), so that a large binary file is refused at once
rather than read whole. Messages quote at most :data:`QUOTE_CHARS` characters of a field
(:func:`quote`), however long the file's line.
"""

from __future__ import annotations

import codecs
import hashlib
import json
import os
import re
import stat
import sys
from typing import Any

from .._model import valid_name
from .errors import DataError

__all__ = ["MAX_NESTING", "QUOTE_CHARS", "SNIFF_BYTES", "check_input_file", "check_nesting", "input_sha256", "parse_json", "quote", "read_json_or_none",
           "shorten", "too_deep", "too_many_digits", "valid_text"]

QUOTE_CHARS = 80
"""The most characters of a file's content that an error message quotes."""
SNIFF_BYTES = 64 * 1024
"""The first block of a text file that is checked for being text before the file is read."""
MAX_NESTING = 64
"""The deepest nesting of lists and tables a material, result or scheduler file may have (a
material has 3 levels): a deeper one is refused when read, not when it is written back."""
_KINDS = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISCHR, "a character device (such as /dev/zero)"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISSOCK, "a socket"),
)
_WIDE_BOMS = {codecs.BOM_UTF32_LE: "UTF-32", codecs.BOM_UTF32_BE: "UTF-32", codecs.BOM_UTF16_LE: "UTF-16", codecs.BOM_UTF16_BE: "UTF-16"}


def shorten(text, limit: int = QUOTE_CHARS) -> str:
    """``text`` cut to ``limit`` characters, "…" marking the cut.

    >>> shorten("x" * 100, 5)
    'xxxxx…'
    """
    text = str(text)
    return text if len(text) <= limit else text[:limit] + "…"


def quote(value, limit: int = QUOTE_CHARS) -> str:
    """``repr(value)`` cut to about ``limit`` characters, "…" marking a cut: how a message quotes a
    field or a value of a file (a string keeps its quotes).

    >>> quote("abc"), quote("x" * 100, 5), quote(list(range(100)), 10)
    ("'abc'", "'xxxxx'…", '[0, 1, 2, …')
    """
    if isinstance(value, str):
        return repr(value) if len(value) <= limit else repr(value[:limit]) + "…"
    if isinstance(value, (list, tuple, dict)) and len(value) > limit:
        value = type(value)(list(value)[:limit]) if not isinstance(value, dict) else dict(list(value.items())[:limit])
    return shorten(repr(value), limit)


def check_input_file(path, *, text: bool = True, max_bytes: int | None = None) -> None:
    """Raise :class:`DataError` unless ``path`` is a regular file (links followed) that looks like
    what a reader can read; nothing is read beyond the first :data:`SNIFF_BYTES`.

    ``text``: the first block must be UTF-8 text (no NUL byte, no UTF-16 or UTF-32 byte-order
    mark, no byte that is not UTF-8). ``max_bytes``: the largest size accepted. A missing or
    unreadable file raises the ``OSError`` that ``open`` would.

    >>> check_input_file("/dev/zero")
    Traceback (most recent call last):
    ...
    ctfit._io.errors.DataError: /dev/zero: not a regular file but a character device (such as /dev/zero); ctfit reads files only
    >>> with open("binary.csv", "wb") as f:
    ...     _ = f.write(b"theta_i,\\x00\\x01\\n")
    >>> check_input_file("binary.csv")
    Traceback (most recent call last):
    ...
    ctfit._io.errors.DataError: binary.csv:1: a NUL byte at byte offset 8: a binary file, or text not saved as UTF-8 (UTF-16?); save it as UTF-8 text
    """
    mode = os.stat(path).st_mode
    if not stat.S_ISREG(mode):
        kind = next((what for test, what in _KINDS if test(mode)), "not a file")
        raise DataError(f"not a regular file but {kind}; ctfit reads files only", path=path)
    if max_bytes is not None and (size := os.stat(path).st_size) > max_bytes:
        raise DataError(f"{size} bytes: larger than the {max_bytes >> 20} MiB a file of this kind may have", path=path)
    if text:
        with open(path, "rb") as f:
            head = f.read(SNIFF_BYTES)
        _check_text(head, path)


def _check_text(head: bytes, path) -> None:
    """Raise :class:`DataError` when the first block ``head`` of a file is not UTF-8 text."""
    for bom, name in _WIDE_BOMS.items():
        if head.startswith(bom):
            raise DataError(f"{name} text (the file starts with a {name} byte-order mark); save it as UTF-8", path=path)
    line = lambda at: head.count(b"\n", 0, at) + 1
    if (at := head.find(b"\0")) >= 0:
        raise DataError(
            f"a NUL byte at byte offset {at}: a binary file, or text not saved as UTF-8 (UTF-16?); save it as UTF-8 text",
            path=path,
            line=line(at),
        )
    try:
        head.decode("utf-8")
    except UnicodeDecodeError as e:
        if e.end < len(head) or e.reason != "unexpected end of data":  # not a character cut by the block's end
            column = e.start - head.rfind(b"\n", 0, e.start)
            raise DataError(
                f"byte 0x{head[e.start]:02x} at byte offset {e.start} (byte {column} of the line) is not UTF-8: a binary "
                "file, or text in another encoding; save it as UTF-8 (plain ASCII is fine)",
                path=path,
                line=line(e.start),
            ) from None


def too_deep(source) -> str:
    """The message for a document nested deeper than ctfit reads (:data:`MAX_NESTING`, or its
    parser's recursion limit).

    >>> too_deep("m.toml")
    'm.toml: nested too deeply to read (lists or tables inside each other more than 64 levels deep)'
    """
    return f"{source}: nested too deeply to read (lists or tables inside each other more than 64 levels deep)"


def check_nesting(doc, source, limit: int = MAX_NESTING) -> None:
    """Raise ``ValueError`` (:func:`too_deep`) when lists and dicts in ``doc`` nest deeper than
    ``limit``: what a parser read may still be too deep for the functions that walk it
    (Python's recursion limit); looked at without recursion.

    >>> check_nesting({"a": [[1]]}, "m.json", limit=3)
    >>> check_nesting({"a": [[[1]]]}, "m.json", limit=3)
    Traceback (most recent call last):
    ...
    ValueError: m.json: nested too deeply to read (lists or tables inside each other more than 64 levels deep)
    """
    level = [doc]
    for _ in range(limit):
        level = [v for x in level for v in (x.values() if isinstance(x, dict) else x) if isinstance(v, (dict, list))]
        if not level:
            return
    raise ValueError(too_deep(source))


def parse_json(text: str, source):
    """``json.loads(text)``, its every failure a ``ValueError`` whose message names ``source``:
    syntax (with line and column), nesting deeper than :data:`MAX_NESTING`, an integer of more
    digits than Python converts, a document too large for memory.

    >>> parse_json('{"a": [1, 2]}', "x.json")
    {'a': [1, 2]}
    >>> parse_json("[" * 100_000 + "]" * 100_000, "deep.json")
    Traceback (most recent call last):
    ...
    ValueError: deep.json: nested too deeply to read (lists or tables inside each other more than 64 levels deep)
    >>> parse_json("1" * 5000, "big.json")
    Traceback (most recent call last):
    ...
    ValueError: big.json: a number of more than 4300 digits; not a value ctfit can read
    >>> parse_json('{"s": 1, "s": 0.5}', "dup.json")  # JSON leaves which one counts to the reader: neither
    Traceback (most recent call last):
    ...
    ValueError: dup.json:1:10: key 's' given twice in one object
    """
    try:
        doc = json.loads(text, object_pairs_hook=_unique_keys)
    except _DuplicateKey as dup:
        raise ValueError(f"{source}{_second_place(text, dup.key)}: key {dup.key!r} given twice in one object") from None
    except json.JSONDecodeError as err:
        raise ValueError(f"{source}:{err.lineno}:{err.colno}: JSON syntax error: {err.msg}") from None
    except RecursionError:
        raise ValueError(too_deep(source)) from None
    except MemoryError:
        raise ValueError(f"{source}: too large to read into memory") from None
    except ValueError:  # int() past sys.get_int_max_str_digits()
        raise ValueError(too_many_digits(source)) from None
    check_nesting(doc, source)
    return doc


class _DuplicateKey(Exception):
    def __init__(self, key: str):
        self.key = key


def _unique_keys(pairs: list) -> dict:
    """A JSON object as a dict; :class:`_DuplicateKey` for a key given twice (``json.loads`` keeps the last)."""
    doc = dict(pairs)
    if len(doc) != len(pairs):
        seen: set = set()
        for key, _ in pairs:
            if key in seen:
                raise _DuplicateKey(key)
            seen.add(key)
    return doc


def _second_place(text: str, key: str) -> str:
    """":line:column" of the repeated ``"key":`` where ``text`` gives that key exactly twice (then the
    second is the repeat), else "": with more, which pair shares an object is not told here (the
    key of every lobe), and an escaped key is not found."""
    found = list(re.finditer(re.escape(json.dumps(key)) + r"\s*:", text))
    if len(found) != 2:
        return ""
    at = found[1].start()
    line = text.count("\n", 0, at) + 1
    return f":{line}:{at - (text.rfind(chr(10), 0, at) + 1) + 1}"


def too_many_digits(source) -> str:
    """The message for an integer of more digits than Python converts (``sys.get_int_max_str_digits``).

    >>> too_many_digits("m.json")
    'm.json: a number of more than 4300 digits; not a value ctfit can read'
    """
    return f"{source}: a number of more than {sys.get_int_max_str_digits()} digits; not a value ctfit can read"


def read_json_or_none(path):
    """The JSON document in ``path``, or None when it is not a regular file, cannot be read or does
    not parse for any reason (nesting and huge numbers included): for files a command looks at
    only to decide what to do (an earlier result), never reading a FIFO or a device.

    >>> with open("deep.json", "w") as f:
    ...     _ = f.write("[" * 100_000 + "]" * 100_000)
    >>> read_json_or_none("deep.json") is None, read_json_or_none("/dev/zero") is None
    (True, True)
    """
    try:
        check_input_file(path, max_bytes=1 << 30)
        with open(path, encoding="utf-8") as f:
            return parse_json(f.read(), path)
    except (OSError, ValueError, MemoryError):
        return None


def valid_text(x: Any) -> Any:
    r"""``x`` with every string made valid UTF-8: the bytes of a file name that is not UTF-8
    (which Python holds as lone surrogates, ``os.fsdecode``) as U+FFFD, as a terminal shows
    them; any other lone surrogate as ``?``. JSON text cannot hold them: a fit-result document
    names its input so (``"data": "x\ufffd.csv"``), and a rerun knows it by that name.

    >>> valid_text({"data": "x\udcff.csv", "n": [1.5]}) == {"data": "x\ufffd.csv", "n": [1.5]}
    True
    """
    if isinstance(x, str):
        return valid_name(x)
    if isinstance(x, dict):
        return {valid_text(k): valid_text(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [valid_text(v) for v in x]
    return x


def input_sha256(path: str | os.PathLike[str]) -> str:
    """The SHA-256 of a file's bytes (read in blocks): what a stored result was fitted from. A
    device or FIFO, which may never end, raises :class:`~ctfit.DataError` unread."""
    check_input_file(path, text=False)
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()
