"""The measurement CSV (``docs/measurement-formats.md``): read it into and write it from a
:class:`~ctfit.Measurement`.

Reading is all-or-nothing: any problem raises :class:`~ctfit.DataError` naming the file, the
line (1-based, counting comment lines) and the column, before anything is returned. The text is
parsed by :mod:`~ctfit._io.csv_table` (NumPy and msgspec); its values are checked here.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterator, Mapping

import numpy as np
from jaxtyping import ArrayLike, Float

from .._model import Measurement, format_value as _fmt, invalid_value, valid_name
from .csv_table import ANGLES, CHANNELS, KNOWN_COLUMNS, CsvTable, Header, measurement_columns, read_table
from .errors import DataError
from .files import atomic_write

__all__ = ["measurement_from_table", "read_csv", "write_csv"]

_RADIAN_MAX = math.pi / 2 + 1e-9  # largest θ that still looks like radians
_RADIAN_ROWS = 3  # more rows than this with a nonzero θ, all ≤ π/2: "looks like radians"
_TWO_PI = 2 * math.pi + 1e-9  # largest |φ| that still looks like radians
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
    return measurement_from_table(read_table(path), path)


def measurement_from_table(table: CsvTable, path: str | os.PathLike[str]) -> Measurement:
    """The :class:`~ctfit.Measurement` of a parsed CSV (:func:`~ctfit._io.csv_table.read_table`),
    its values checked first (:class:`~ctfit.DataError` for the earliest bad one)."""
    first = table.header_line + 1
    _check_values(table.values, table.cols, first, path)
    _check_units(table.values, table.meta, table.meta_lines, table.cols, table.header_line, path)
    return _measurement(table, path)


def _check_values(values: dict, cols: Header, first: int, path: str | os.PathLike[str]) -> None:
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


def _check_units(values: dict, meta: dict, meta_lines: dict, cols: Header, header_line: int, path: str | os.PathLike[str]) -> None:
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
    if _theta_looks_radian(values["theta_i"], values["theta_o"]):
        raise DataError(
            f"every theta_i and theta_o is ≤ {math.pi / 2:.4f} (π/2): the angles look like radians, but ctfit reads "
            "degrees. Convert them (degrees = radians × 180/π), or, if they really are degrees, add the line "
            "'# angle_unit: degrees' before the header",
            path=path,
            line=header_line,
            **cols.column("theta_i"),
        )
    _check_phi_units(values, cols, header_line, path)


def _theta_looks_radian(ti: np.ndarray, to: np.ndarray) -> bool:
    """Every θ ≤ π/2, in more than a few rows with a θ above 0: the reader takes such angles for radians."""
    return int(np.count_nonzero((ti > 0) | (to > 0))) > _RADIAN_ROWS and max(ti.max(), to.max()) <= _RADIAN_MAX


def _phi_looks_radian(theta_max: float, phi: np.ndarray) -> bool:
    """φ (2, rows) within ±2π, some not whole, in more than a few rows, beside θ up to more than 2π:
    the reader takes such φ for radians."""
    if theta_max <= _TWO_PI or np.abs(phi).max() > _TWO_PI or np.count_nonzero(np.any(phi != 0, axis=0)) <= _RADIAN_ROWS:
        return False
    return bool((np.abs(phi - np.round(phi)) > 1e-9).any())


def _check_phi_units(values: dict, cols: Header, header_line: int, path: str | os.PathLike[str]) -> None:
    """φ in radians beside θ in degrees: every |φ| ≤ 2π, some φ not whole, θ up to more than 2π.

    Whole-numbered φ within ±2π (0 and 180 in-plane data has larger ones anyway; 0 alone, or
    0, 1, 2 degrees) reads as degrees."""
    theta_max = max(values["theta_i"].max(), values["theta_o"].max())
    phi = np.stack([values["phi_i"], values["phi_o"]])
    if not _phi_looks_radian(theta_max, phi):
        return
    fractional = np.abs(phi - np.round(phi)) > 1e-9
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


BAND_UNKNOWN = "unknown"
"""The ``# band:`` line's first word for data whose one band has no known wavelength
(``Measurement.band_unknown``: an ALTA file's values): the ``wavelength_nm`` column's single value
only stands in. :func:`write_csv` writes it; :func:`read_csv` reads the band as unknown again (it
read as a real band, and a colour was made of an ALTA fit's values evaluated and read back)."""


def _measurement(table: CsvTable, path: str | os.PathLike[str]) -> Measurement:
    columns = table.columns if table.columns is not None else measurement_columns(table.values, table.channel)
    unknown = str(table.meta.get("band", "")).split(" ", 1)[0] == BAND_UNKNOWN
    bands = columns.get("wavelength_nm")
    if unknown and (bands is None or len(bands) != 1):
        kind = "RGB channels" if bands is None else f"{len(bands)} wavelengths"
        raise DataError(f"'# band: {BAND_UNKNOWN}' marks data of one band whose wavelength is not known, but the file has {kind}",
                        path=path, line=table.meta_lines["band"])
    m = Measurement(**columns, meta=table.meta, source=os.fspath(path), band_unknown=unknown)
    # Its rows are the file's lines after the header, one a sample (no blank or # line among them): a
    # value refused later (a fit's checks of the data's scale) is named by its line and column.
    m = m.with_lines(table.header_line + 1, {name: i + 1 for name, i in table.cols.index.items() if name in KNOWN_COLUMNS})
    return m if table.pairs is None else m.with_directions(*table.pairs)


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
        if not name or name.lower() in KNOWN_COLUMNS or any(c in name for c in ',\n\r"#') or name != name.strip():
            raise ValueError(f"extra column name {name!r} is empty, a standard column, or contains , \" # or spaces at its ends")
        columns.append((name, np.asarray(values, dtype=np.float64)))
    for name, values in columns:
        if len(values) != n:
            raise ValueError(f"column {name!r} has {len(values)} values for {n} samples")
        if values.dtype.kind == "f" and not np.isfinite(values).all():
            raise ValueError(f"column {name!r} has non-finite values; the CSV cannot hold them")
    meta = {**m.meta, **(meta or {})}
    if m.band_unknown and str(meta.get("band", "")).split(" ", 1)[0] != BAND_UNKNOWN:  # read back as unknown, not as a real band
        meta["band"] = f"{BAND_UNKNOWN} (no known wavelength; {float(m.wavelength_nm[0]):g} nm stands in)"
    ti, to = columns[0][1], columns[2][1]  # ANGLES: theta_i, phi_i, theta_o, phi_o
    if "angle_unit" not in meta and (_theta_looks_radian(ti, to) or _phi_looks_radian(max(ti.max(), to.max()), np.stack([columns[1][1], columns[3][1]]))):
        meta["angle_unit"] = "degrees"  # what the reader would take for radians: the file says they are degrees, so it reads back
    lines = _meta_lines(meta)
    lines.append(",".join(name for name, _ in columns))
    atomic_write(path, _chunks(lines, [v for _, v in columns], n))


def _meta_lines(meta: dict) -> list[str]:
    lines = []
    for key, value in meta.items():
        value = valid_name(str(value))  # a name from a file that is not UTF-8: its bytes as U+FFFD (UTF-8 text cannot hold them)
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
