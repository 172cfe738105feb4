"""The measurement CSV's text, parsed: its ``# key: value`` lines, its header and its columns of
numbers, with no model in sight (NumPy and msgspec, no JAX): what :func:`~ctfit.read_csv` checks and
makes a :class:`~ctfit.Measurement` of, and what a helper process can parse while the command
that asked for it starts JAX (:mod:`~ctfit._io.read_ahead`).

Large bodies take a vectorised path (a block at a time, decoded as one JSON array of numbers by
msgspec, or by ``numpy.fromstring`` where JSON does not take a field); when that path
meets anything it cannot vouch for, a plain line-by-line parser takes over and either reads the
file the same way or raises :class:`~ctfit.DataError` for the first bad line.
"""

from __future__ import annotations

import array
import dataclasses
import difflib
import os
import re
from collections.abc import Iterable, Iterator
from typing import Any

import numpy as np

from .errors import DataError
from .files import map_utf8
from .json_numbers import json_numbers
from .untrusted import check_input_file, quote, shorten

__all__ = ["CsvTable", "Header", "KNOWN_COLUMNS", "measurement_columns", "read_table"]

ANGLES = ("theta_i", "phi_i", "theta_o", "phi_o")
CHANNELS = ("R", "G", "B")
KNOWN_COLUMNS = (*ANGLES, "wavelength_nm", "channel", "brdf", "sigma")
_META = re.compile(r"#\s*([A-Za-z_][\w.-]*)\s*:\s?(.*)")
_SEPARATORS = {";": "semicolon", "\t": "tab"}
_CHANNEL_CODE = np.full(256, 255, np.uint8)
_CHANNEL_CODE[[ord(c) for c in CHANNELS]] = [0, 1, 2]


@dataclasses.dataclass(frozen=True)
class CsvTable:
    """A measurement CSV as parsed, before its values are checked: ``values`` {column: float64
    array} of the numeric columns present, ``channel`` the RGB codes (0, 1, 2) or None, ``meta``
    the ``# key: value`` lines and ``meta_lines`` the line of each, ``header_line`` the header's
    line number (1-based) and ``cols`` its columns; the first data row is line ``header_line + 1``."""

    values: dict
    channel: np.ndarray | None
    meta: dict
    meta_lines: dict
    header_line: int
    cols: Header
    columns: dict | None = None
    """With ``read_table(prepared=True)``: :func:`measurement_columns` of the values."""
    pairs: tuple[np.ndarray, np.ndarray] | None = None
    """With ``read_table(prepared=True)``: the columns' direction pairs and each sample's pair
    (:func:`~ctfit._model.direction_pairs.unique_direction_pairs`)."""


def read_table(path: str | os.PathLike[str], *, prepared: bool = False) -> CsvTable:
    """Parse the measurement CSV ``path`` (:class:`CsvTable`); a file that cannot be parsed raises
    :class:`~ctfit.DataError` naming the line (and column). ``prepared``: also the Measurement's
    columns and direction pairs, made from values not yet checked (what a helper process can do
    ahead of the checks: :mod:`~ctfit._io.read_ahead`)."""
    check_input_file(path)
    raw, pos = map_utf8(path)  # a large file is mapped, and parsed a block at a time
    if raw.find(b"\r") >= 0:  # Windows (CR LF) and old Mac (CR) line endings
        raw = raw[pos:].replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        pos = 0
    meta, meta_lines, header_line, header, pos = _split_header(raw, path, pos)
    cols = Header(header, header_line, path)
    end = len(raw)
    while end > pos and raw[end - 1] in b" \t\n":
        end -= 1
    if end == pos:
        raise DataError("no data rows after the header", path=path, line=header_line)
    first = header_line + 1
    parsed = _parse_blocks(raw, pos, end, cols)
    values, channel = parsed if parsed is not None else _parse_slow(_lines(raw, pos, end), first, cols, path)
    table = CsvTable(values, channel, meta, meta_lines, header_line, cols)
    if not prepared:
        return table
    from .._model import unique_direction_pairs  # NumPy alone (the subpackage loads its modules on first use)

    columns = measurement_columns(values, channel)
    pairs = unique_direction_pairs(*(columns[n] for n in ANGLES))
    return dataclasses.replace(table, columns=columns, pairs=pairs)


def measurement_columns(values: dict, channel: np.ndarray | None) -> dict:
    """The :class:`~ctfit.Measurement` fields of parsed values: φ modulo 360, θ with −0 as 0,
    bands the sorted distinct wavelengths (or the channels present, in the order R, G, B) and each
    sample's band, brdf and sigma as read."""
    phi = {n: _mod360(values[n]) for n in ("phi_i", "phi_o")}
    theta = {n: values[n] + 0.0 for n in ("theta_i", "theta_o")}  # -0.0 → 0.0
    if channel is not None:
        present, band = np.unique(channel, return_inverse=True)
        bands: dict[str, object] = dict(channels=tuple(CHANNELS[c] for c in present))
    else:
        wavelength, band = np.unique(values["wavelength_nm"], return_inverse=True)
        bands = dict(wavelength_nm=wavelength)
    return dict(theta_i=theta["theta_i"], phi_i=phi["phi_i"], theta_o=theta["theta_o"], phi_o=phi["phi_o"], band=band.reshape(-1).astype(np.int64),
                brdf=values.get("brdf"), sigma=values.get("sigma"), **bands)


def _mod360(phi: np.ndarray) -> np.ndarray:
    phi = np.mod(phi, 360.0) + 0.0
    phi[phi >= 360.0] = 0.0  # a tiny negative φ rounds to 360
    return phi


def _split_header(raw: Any, path: str | os.PathLike[str], pos: int = 0) -> tuple[dict, dict, int, str, int]:
    """(meta, line number of each meta key, header line number, header text, body offset); the
    file's text starts at ``pos`` (after a byte-order mark)."""
    meta, meta_lines, line_no, blank = {}, {}, 0, True
    while pos <= len(raw):
        end = raw.find(b"\n", pos)
        end = len(raw) if end < 0 else end
        line_no += 1
        if end - pos > MAX_HEADER_BYTES:
            raise DataError(f"{end - pos} bytes without a line break before the header row ends: not a measurement CSV", path=path, line=line_no)
        line = raw[pos:end].decode("utf-8").strip()
        pos = end + 1
        if line.startswith("#"):
            blank = False
            if m := _META.fullmatch(line):
                meta[m[1]] = m[2].strip()
                meta_lines[m[1]] = line_no
        elif line:
            return meta, meta_lines, line_no, line, min(pos, len(raw))
    raise DataError("the file is empty" if blank else "no header row: the file has only comment lines", path=path)


class Header:
    """Column positions from the header row, validated."""

    def __init__(self, header: str, line: int, path: str | os.PathLike[str]) -> None:
        names = [n.strip().strip('"').strip() for n in header.split(",")]
        self.names, self.line = names, line
        err = lambda msg, name=None, i=None: DataError(msg, path=path, line=line, column=name, index=i)
        sep = next((word for c, word in _SEPARATORS.items() if c in header), None)
        if len(names) == 1 and sep is not None:
            raise err(
                f"the header has one column, {quote(header, 60)}: the file seems to be {sep}-separated; "
                "ctfit reads comma-separated CSV (docs/measurement-formats.md)"
            )
        if _is_number(names[0]):
            raise DataError(
                "no header row: this line looks like data; the first line after the # lines must name the columns, "
                "e.g. theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf",
                path=path,
                line=line,
            )
        seen: dict[str, int] = {}
        for i, name in enumerate(names):
            if not name:
                raise err(f"column {i + 1} has no name")
            if name in seen:
                raise err(f"duplicated (also column {seen[name] + 1})", name, i + 1)
            seen[name] = i
        self.index = seen
        for i, name in enumerate(names):
            if name not in KNOWN_COLUMNS and name.lower() in KNOWN_COLUMNS and name.lower() not in seen:
                raise err(f"is this {name.lower()!r}? Column names are case sensitive", name, i + 1)
        for name in ANGLES:
            if name not in seen:
                raise err(f"missing column {name!r}{_did_you_mean(name, names)} (columns: {shorten(','.join(names[:100]))})")
        if "wavelength_nm" in seen and "channel" in seen:
            raise err(
                f"both 'wavelength_nm' ({seen['wavelength_nm'] + 1}) and 'channel' ({seen['channel'] + 1}): "
                "a file is either spectral (wavelength_nm) or RGB (channel)"
            )
        if "wavelength_nm" not in seen and "channel" not in seen:
            hint = _did_you_mean("wavelength_nm", names) or _did_you_mean("channel", names)
            raise err(f"missing column 'wavelength_nm' (or 'channel' for RGB data){hint}")
        if "sigma" in seen and "brdf" not in seen:
            raise err("'sigma' without 'brdf': sigma is the uncertainty of the brdf column", "sigma", seen["sigma"] + 1)
        self.channel = seen.get("channel")
        self.numeric = [n for n in (*ANGLES, "wavelength_nm", "brdf", "sigma") if n in seen]
        self.ignored = [i for i, n in enumerate(names) if n not in KNOWN_COLUMNS]

    def column(self, name: str) -> dict[str, Any]:
        return dict(column=name, index=self.index[name] + 1)


def _did_you_mean(name: str, names: list[str]) -> str:
    close = difflib.get_close_matches(name, [n for n in names if n not in KNOWN_COLUMNS and len(n) < 3 * len(name)], n=1, cutoff=0.75)
    return f" (is {quote(close[0])} meant to be {name!r}?)" if close else ""


def _is_number(token: str) -> bool:
    try:
        _number(token)
    except ValueError:
        return False
    return True


def _number(token: str) -> float:
    """``float`` without its extensions: ASCII only, no digit-group underscores."""
    token = token.strip()
    if "_" in token or not token.isascii():
        raise ValueError(token)
    return float(token)


MAX_HEADER_BYTES = 1 << 26
"""The longest line read before the data rows (comments, metadata, the header): 64 MiB."""

PARSE_BLOCK = 1 << 23
"""Bytes of the body parsed at once by the fast parser (whole lines): its temporaries — a few
times the block — stay small however large the file is."""


def _parse_blocks(raw: Any, pos: int, end: int, cols: Header) -> tuple[dict, np.ndarray | None] | None:
    """:func:`_parse_fast` over blocks of about ``PARSE_BLOCK`` bytes of whole lines, the columns
    joined; None when any block needs a closer look (the slow parser then reads the whole body)."""
    parts = []
    while pos < end:
        stop = end if end - pos <= PARSE_BLOCK else raw.find(b"\n", pos + PARSE_BLOCK, end)
        stop = end if stop < 0 else stop
        part = _parse_fast(raw, pos, stop, cols) if stop > pos else None  # an empty line: the slow parser's
        if part is None:
            return None
        parts.append(part)
        pos = stop + 1
    if len(parts) == 1:
        return parts[0]
    values = {n: np.concatenate([p[0][n] for p in parts]) for n in parts[0][0]}
    return values, None if parts[0][1] is None else np.concatenate([p[1] for p in parts])


def _parse_fast(raw: Any, pos: int, end: int, cols: Header) -> tuple[dict, np.ndarray | None] | None:
    """({name: values}, channel codes or None) from ``raw[pos:end]``, or None when the body needs
    a closer look."""
    n = end - pos
    if n >= 2**31 - 1:
        return None
    work = bytearray(n + 2)  # "[" + the lines + "]": the numbers as one JSON array (_numbers)
    work[0], work[1 : n + 1], work[n + 1] = ord("["), memoryview(raw)[pos:end], ord("\n")
    buf = np.frombuffer(work, np.uint8)[1:]
    ncols = len(cols.names)
    sep = np.flatnonzero((buf == 44) | (buf == 10))
    nrows = int(np.count_nonzero(buf[:n] == 10)) + 1
    line_ends = sep[ncols - 1 :: ncols]
    # Every row has ncols fields iff there are nrows·ncols separators and each ncols-th is a newline.
    if len(sep) != nrows * ncols or not (buf[line_ends] == 10).all():
        return None
    starts = np.empty_like(sep)
    starts[0], starts[1:] = 0, sep[:-1] + 1
    if cols.ignored:  # overwrite ignored fields (free text, say) with a zero: "n/a" → "0  "
        token = np.concatenate([np.arange(j, len(sep), ncols) for j in cols.ignored])
        if (sep[token] == starts[token]).any():
            return None
        inside = np.zeros(len(buf) + 1, np.int8)
        inside[starts[token]], inside[sep[token]] = 1, -1
        buf[np.cumsum(inside[:-1], dtype=np.int8).view(bool)] = ord(" ")
        buf[starts[token]] = ord("0")
    if raw.find(b" ", pos, end) >= 0 or raw.find(b"\t", pos, end) >= 0:  # fromstring reads a blank field as -1
        filled = np.zeros(len(buf) + 1, np.int32)
        np.cumsum(((buf != 32) & (buf != 9)).view(np.int8), dtype=np.int32, out=filled[1:])
        if (filled[sep] == filled[starts]).any():
            return None
    channel = None
    if cols.channel is not None:
        first = starts[cols.channel :: ncols]
        channel = _CHANNEL_CODE[buf[first]]
        if (channel == 255).any() or (sep[cols.channel :: ncols] - first != 1).any():
            return None
        buf[first] = ord("0")
    buf[line_ends] = ord(",")
    flat = _numbers(work, starts)
    if flat is None or flat.size != nrows * ncols:
        return None
    table = flat.reshape(nrows, ncols)
    return {n: table[:, cols.index[n]].copy() for n in cols.numeric}, channel


def _numbers(work: bytearray, starts: np.ndarray) -> np.ndarray | None:
    """The comma-separated fields of ``work`` ("[" + fields, each ending in "," + one byte; field
    k at ``starts[k] + 1``) as float64, or None where one is not a number: decoded as one JSON
    array (:func:`~ctfit._io.json_numbers.json_numbers`), or, where JSON does not take a field,
    by ``numpy.fromstring``, which reads those as it always has."""
    work[-1] = ord("]")
    flat = json_numbers(work, starts + 1)
    if flat is not None:
        return flat
    work[-1] = ord(",")
    try:
        return np.fromstring(bytes(work[1:]), sep=",")
    except ValueError:  # a field that is not a number
        return None


def _lines(raw: Any, pos: int, end: int) -> Iterator[str]:
    """The lines of ``raw[pos:end]``, decoded one at a time (the file is UTF-8, checked)."""
    while pos <= end:
        stop = raw.find(b"\n", pos, end)
        stop = end if stop < 0 else stop
        yield raw[pos:stop].decode("utf-8")
        pos = stop + 1


def _parse_slow(lines: Iterable[str], first: int, cols: Header, path: str | os.PathLike[str]) -> tuple[dict, np.ndarray | None]:
    """Line by line; raises at the first bad line."""
    names, ncols = cols.names, len(cols.names)
    numeric = [(n, cols.index[n]) for n in cols.numeric]
    out = {n: array.array("d") for n in cols.numeric}
    channel = array.array("B")
    for k, line in enumerate(lines):
        line_no = first + k
        if not line.strip():
            raise DataError("empty line: data rows must be contiguous (blank lines may only end the file)", path=path, line=line_no)
        if line.lstrip().startswith("#"):
            raise DataError("a # line after the header: comments and metadata must come before the header", path=path, line=line_no)
        fields = line.split(",")
        if len(fields) != ncols:
            raise DataError(f"expected {ncols} fields ({shorten(','.join(names[:100]))}), found {len(fields)}", path=path, line=line_no)
        for name, j in numeric:
            try:
                out[name].append(_number(fields[j]))
            except ValueError:
                what = "empty value" if not fields[j].strip() else f"{quote(fields[j].strip())} is not a number"
                raise DataError(what, path=path, line=line_no, column=name, index=j + 1) from None
        if cols.channel is not None:
            token = fields[cols.channel].strip()
            if token not in CHANNELS:
                raise DataError(f"{quote(token)} is not a channel (R, G or B)", path=path, line=line_no, column="channel", index=cols.channel + 1)
            channel.append(CHANNELS.index(token))
    values = {n: np.array(v, np.float64) for n, v in out.items()}
    return values, (np.array(channel, np.uint8) if cols.channel is not None else None)
