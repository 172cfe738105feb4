"""The measurement CSV (``docs/measurement-formats.md``): read it into and write it from a
:class:`~ctfit.Measurement`.

Reading is all-or-nothing: any problem raises :class:`~ctfit.DataError` naming the file, the
line (1-based, counting comment lines) and the column, before anything is returned. Large files
take a vectorised path (``numpy.fromstring`` on the whole body); when that path meets anything it
cannot vouch for, a plain line-by-line parser takes over and either reads the file the same way
or reports the first bad line.
"""

from __future__ import annotations

import array
import difflib
import math
import os
import re
from collections.abc import Iterable, Iterator, Mapping
from typing import Any

import numpy as np
from jaxtyping import ArrayLike, Float

from .._model import Measurement, format_value as _fmt, invalid_value
from .errors import DataError
from .files import atomic_write, map_utf8
from .untrusted import check_input_file, quote, shorten

__all__ = ["read_csv", "write_csv"]

ANGLES = ("theta_i", "phi_i", "theta_o", "phi_o")
CHANNELS = ("R", "G", "B")
_KNOWN = (*ANGLES, "wavelength_nm", "channel", "brdf", "sigma")
_META = re.compile(r"#\s*([A-Za-z_][\w.-]*)\s*:\s?(.*)")
_RADIAN_MAX = math.pi / 2 + 1e-9  # largest θ that still looks like radians
_RADIAN_ROWS = 3  # more rows than this with a nonzero θ, all ≤ π/2: "looks like radians"
_TWO_PI = 2 * math.pi + 1e-9  # largest |φ| that still looks like radians
_SEPARATORS = {";": "semicolon", "\t": "tab"}
_CHANNEL_CODE = np.full(256, 255, np.uint8)
_CHANNEL_CODE[[ord(c) for c in CHANNELS]] = [0, 1, 2]
_WRITE_ROWS = 100_000


# --- reading ------------------------------------------------------------------------------------


def read_csv(path: str | os.PathLike[str]) -> Measurement:
    r"""Read a measurement CSV.

    ``# key: value`` lines before the header become ``meta`` (other ``#`` lines are free text
    and are skipped). Columns may come in any order; unknown columns are ignored. Spectral
    bands are the sorted distinct wavelengths, RGB channels are listed in the order R, G, B
    (those present). φ is taken modulo 360. Without a ``brdf`` column, ``brdf`` is None.

    Examples
    --------
    >>> import ctfit
    >>> with open("rgb.csv", "w") as f:
    ...     _ = f.write("# sample: demo\nchannel,theta_i,phi_i,theta_o,phi_o,brdf\nG,30,0,30,-180,0.2\nR,30,0,30,180,0.1\n")
    >>> m = ctfit.read_csv("rgb.csv")
    >>> m.channels, m.band.tolist(), m.phi_o.tolist(), m.meta
    (('R', 'G'), [1, 0], [180.0, 180.0], {'sample': 'demo'})
    >>> with open("bad.csv", "w") as f:
    ...     _ = f.write("theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n95,0,30,180,550,0.1\n")
    >>> ctfit.read_csv("bad.csv")
    Traceback (most recent call last):
    ...
    ctfit._io.errors.DataError: bad.csv:2: column 'theta_i' (1): 95.0 is outside [0, 90] degrees
    """
    check_input_file(path)
    raw, pos = map_utf8(path)  # a large file is mapped, and parsed a block at a time
    if raw.find(b"\r") >= 0:  # Windows (CR LF) and old Mac (CR) line endings
        raw = raw[pos:].replace(b"\r\n", b"\n").replace(b"\r", b"\n")
        pos = 0
    meta, meta_lines, header_line, header, pos = _split_header(raw, path, pos)
    cols = _Header(header, header_line, path)
    end = len(raw)
    while end > pos and raw[end - 1] in b" \t\n":
        end -= 1
    if end == pos:
        raise DataError("no data rows after the header", path=path, line=header_line)
    first = header_line + 1
    parsed = _parse_blocks(raw, pos, end, cols)
    values, channel = parsed if parsed is not None else _parse_slow(_lines(raw, pos, end), first, cols, path)
    _check_values(values, cols, first, path)
    _check_units(values, meta, meta_lines, cols, header_line, path)
    return _measurement(values, channel, meta, path)


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


class _Header:
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
            if name not in _KNOWN and name.lower() in _KNOWN and name.lower() not in seen:
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
        self.ignored = [i for i, n in enumerate(names) if n not in _KNOWN]

    def column(self, name: str) -> dict[str, Any]:
        return dict(column=name, index=self.index[name] + 1)


def _did_you_mean(name: str, names: list[str]) -> str:
    close = difflib.get_close_matches(name, [n for n in names if n not in _KNOWN and len(n) < 3 * len(name)], n=1, cutoff=0.75)
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


def _parse_blocks(raw: Any, pos: int, end: int, cols: _Header) -> tuple[dict, np.ndarray | None] | None:
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


def _parse_fast(raw: Any, pos: int, end: int, cols: _Header) -> tuple[dict, np.ndarray | None] | None:
    """({name: values}, channel codes or None) from ``raw[pos:end]``, or None when the body needs
    a closer look."""
    n = end - pos
    if n >= 2**31 - 1:
        return None
    work = bytearray(n + 1)
    work[:n], work[n] = memoryview(raw)[pos:end], ord("\n")
    buf = np.frombuffer(work, np.uint8)
    ncols = len(cols.names)
    sep = np.flatnonzero((buf == 44) | (buf == 10))
    nrows = int(np.count_nonzero(buf[:n] == 10)) + 1
    line_ends = sep[ncols - 1 :: ncols]
    # Every row has ncols fields iff there are nrows·ncols separators and each ncols-th is a newline.
    if len(sep) != nrows * ncols or not (buf[line_ends] == 10).all():
        return None
    starts = np.empty_like(sep)
    starts[0], starts[1:] = 0, sep[:-1] + 1
    if cols.ignored:  # overwrite ignored fields (free text, say) with zeros: "n/a" → "000"
        token = np.concatenate([np.arange(j, len(sep), ncols) for j in cols.ignored])
        if (sep[token] == starts[token]).any():
            return None
        inside = np.zeros(len(buf) + 1, np.int8)
        inside[starts[token]], inside[sep[token]] = 1, -1
        buf[np.cumsum(inside[:-1], dtype=np.int8).view(bool)] = ord("0")
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
    try:
        flat = np.fromstring(bytes(work), sep=",")
    except ValueError:  # a field that is not a number
        return None
    if flat.size != nrows * ncols:
        return None
    table = flat.reshape(nrows, ncols)
    return {n: table[:, cols.index[n]].copy() for n in cols.numeric}, channel


def _lines(raw: Any, pos: int, end: int) -> Iterator[str]:
    """The lines of ``raw[pos:end]``, decoded one at a time (the file is UTF-8, checked)."""
    while pos <= end:
        stop = raw.find(b"\n", pos, end)
        stop = end if stop < 0 else stop
        yield raw[pos:stop].decode("utf-8")
        pos = stop + 1


def _parse_slow(lines: Iterable[str], first: int, cols: _Header, path: str | os.PathLike[str]) -> tuple[dict, np.ndarray | None]:
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


def _check_values(values: dict, cols: _Header, first: int, path: str | os.PathLike[str]) -> None:
    """Raise for the earliest (line, column) with a value out of its domain (the rule every
    reader shares: :func:`~ctfit._model.measurement.invalid_value`)."""
    worst = None
    for name, v in values.items():
        found = invalid_value(name, v)
        if found is not None:
            key = (found[0], cols.index[name])
            if worst is None or key < worst[0]:
                worst = (key, name, found[1])
    if worst is not None:
        (row, _), name, message = worst
        raise DataError(message, path=path, line=first + row, **cols.column(name))


def _check_units(values: dict, meta: dict, meta_lines: dict, cols: _Header, header_line: int, path: str | os.PathLike[str]) -> None:
    """Radian-looking angles are an error unless ``# angle_unit: degrees`` confirms degrees:
    every θ ≤ π/2, or (θ in degrees) every φ within ±2π with some not whole numbers."""
    unit = meta.get("angle_unit")
    if unit is not None and unit.lower() not in ("degrees", "degree", "deg"):
        raise DataError(
            f"angle_unit {unit!r} is not supported: ctfit reads degrees (convert with degrees = radians × 180/π)",
            path=path,
            line=meta_lines["angle_unit"],
        )
    if unit is not None:
        return
    ti, to = values["theta_i"], values["theta_o"]
    nonzero = int(np.count_nonzero((ti > 0) | (to > 0)))
    if nonzero > _RADIAN_ROWS and max(ti.max(), to.max()) <= _RADIAN_MAX:
        raise DataError(
            f"every theta_i and theta_o is ≤ {math.pi / 2:.4f} (π/2): the angles look like radians, but ctfit reads "
            "degrees. Convert them (degrees = radians × 180/π), or, if they really are degrees, add the line "
            "'# angle_unit: degrees' before the header",
            path=path,
            line=header_line,
            **cols.column("theta_i"),
        )
    _check_phi_units(values, cols, header_line, path)


def _check_phi_units(values: dict, cols: _Header, header_line: int, path: str | os.PathLike[str]) -> None:
    """φ in radians beside θ in degrees: every |φ| ≤ 2π, some φ not whole, θ up to more than 2π.

    Whole-numbered φ within ±2π (0 and 180 in-plane data has larger ones anyway; 0 alone, or
    0, 1, 2 degrees) reads as degrees."""
    theta_max = max(values["theta_i"].max(), values["theta_o"].max())
    phi = np.stack([values["phi_i"], values["phi_o"]])
    if theta_max <= _TWO_PI or np.abs(phi).max() > _TWO_PI or np.count_nonzero(np.any(phi != 0, axis=0)) <= _RADIAN_ROWS:
        return
    fractional = np.abs(phi - np.round(phi)) > 1e-9
    if not fractional.any():
        return
    which, row = np.unravel_index(np.argmax(fractional.T.reshape(-1)), fractional.T.shape)[::-1]
    name = ("phi_i", "phi_o")[which]
    raise DataError(
        f"{_fmt(values[name][row])}: every phi_i and phi_o is within ±2π (±{2 * math.pi:.4f}) and some are not whole "
        f"numbers, while theta goes up to {theta_max:g}: phi looks like radians, but ctfit reads degrees. Convert phi "
        f"(degrees = radians × 180/π ≈ radians × {180 / math.pi:.4f}), or, if it really is in degrees, add the line "
        "'# angle_unit: degrees' before the header",
        path=path,
        line=header_line + 1 + int(row),
        **cols.column(name),
    )


def _measurement(values: dict, channel: np.ndarray | None, meta: dict, path: str | os.PathLike[str]) -> Measurement:
    phi = {n: _mod360(values[n]) for n in ("phi_i", "phi_o")}
    theta = {n: values[n] + 0.0 for n in ("theta_i", "theta_o")}  # -0.0 → 0.0
    if channel is not None:
        present, band = np.unique(channel, return_inverse=True)
        bands: dict[str, object] = dict(channels=tuple(CHANNELS[c] for c in present))
    else:
        wavelength, band = np.unique(values["wavelength_nm"], return_inverse=True)
        bands = dict(wavelength_nm=wavelength)
    return Measurement(
        theta_i=theta["theta_i"],
        phi_i=phi["phi_i"],
        theta_o=theta["theta_o"],
        phi_o=phi["phi_o"],
        band=band.reshape(-1).astype(np.int64),
        brdf=values.get("brdf"),
        sigma=values.get("sigma"),
        meta=meta,
        source=os.fspath(path),
        **bands,
    )


def _mod360(phi: np.ndarray) -> np.ndarray:
    phi = np.mod(phi, 360.0) + 0.0
    phi[phi >= 360.0] = 0.0  # a tiny negative φ rounds to 360
    return phi


# --- writing ------------------------------------------------------------------------------------


def write_csv(
    measurement: Measurement, path: str | os.PathLike[str], brdf: Float[ArrayLike, " samples"] | None = None,
    extra_columns: Mapping[str, ArrayLike] | None = None, *, meta: Mapping[str, object] | None = None,
) -> None:
    """Write ``measurement`` as a measurement CSV, atomically (a temporary file, then a rename).

    ``brdf`` replaces the measurement's BRDF values (e.g. model values); ``extra_columns`` maps
    further column names to numeric arrays, written after the standard columns; ``meta``
    adds to (and overrides) ``measurement.meta`` in the ``# key: value`` lines. Numbers are
    written with Python's ``repr`` (at most 17 significant digits), so they read back exactly.

    Examples
    --------
    >>> import numpy as np, ctfit
    >>> from pathlib import Path
    >>> m = ctfit.Measurement(theta_i=np.array([30.0]), phi_i=np.zeros(1), theta_o=np.array([30.0]), phi_o=np.array([180.0]),
    ...                       band=np.zeros(1, int), wavelength_nm=np.array([550.0]), brdf=np.array([1 / 3]))
    >>> ctfit.write_csv(m, "one.csv", meta={"sample": "demo"})
    >>> print(Path("one.csv").read_text(), end="")
    # sample: demo
    theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf
    30.0,0.0,30.0,180.0,550.0,0.3333333333333333
    >>> bool(ctfit.read_csv("one.csv").brdf[0] == 1 / 3)  # read back exactly
    True
    """
    m = measurement
    n = len(m)
    if n == 0:
        raise ValueError("no samples to write: a measurement CSV has at least one data row")
    brdf = m.brdf if brdf is None else brdf
    columns = [(name, np.asarray(getattr(m, name), dtype=np.float64)) for name in ANGLES]
    band = np.asarray(m.band)
    if m.channels is not None:
        if not set(m.channels) <= set(CHANNELS):
            raise ValueError(f"channels {m.channels} cannot be written: the CSV knows R, G and B")
        columns.append(("channel", np.asarray(m.channels)[band]))
    else:
        columns.append(("wavelength_nm", np.asarray(m.wavelength_nm, dtype=np.float64)[band]))
    if brdf is not None:
        columns.append(("brdf", np.asarray(brdf, dtype=np.float64)))
    if m.sigma is not None:
        columns.append(("sigma", np.asarray(m.sigma, dtype=np.float64)))
    for name, values in (extra_columns or {}).items():
        if not name or name.lower() in _KNOWN or any(c in name for c in ',\n\r"#') or name != name.strip():
            raise ValueError(f"extra column name {name!r} is empty, a standard column, or contains , \" # or spaces at its ends")
        columns.append((name, np.asarray(values, dtype=np.float64)))
    for name, values in columns:
        if len(values) != n:
            raise ValueError(f"column {name!r} has {len(values)} values for {n} samples")
        if values.dtype.kind == "f" and not np.isfinite(values).all():
            raise ValueError(f"column {name!r} has non-finite values; the CSV cannot hold them")
    lines = _meta_lines({**m.meta, **(meta or {})})
    lines.append(",".join(name for name, _ in columns))
    atomic_write(path, _chunks(lines, [v for _, v in columns], n))


def _meta_lines(meta: dict) -> list[str]:
    lines = []
    for key, value in meta.items():
        value = str(value)
        if not re.fullmatch(r"[A-Za-z_][\w.-]*", str(key)) or "\n" in value or "\r" in value:
            raise ValueError(f"metadata {key!r}: {value!r} cannot be written as a '# key: value' line")
        lines.append(f"# {key}: {value}")
    return lines


def _chunks(head: list[str], columns: list[np.ndarray], n: int) -> Iterator[str]:
    yield "\n".join(head) + "\n"
    for start in range(0, n, _WRITE_ROWS):
        cells = [_strings(c[start : start + _WRITE_ROWS]) for c in columns]
        yield "\n".join(map(",".join, zip(*cells))) + "\n"


def _strings(values: np.ndarray) -> list[str]:
    if values.dtype.kind == "f":
        return list(map(repr, values.tolist()))
    return list(map(str, values.tolist()))
