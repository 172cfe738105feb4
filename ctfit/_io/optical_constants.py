"""Optical constants tables: wavelength, n, k (and F0) of a metal, as CSV; six ship with ctfit.

The format is documented in ``docs/formats.md``. A table is named by a path, or by the name of
a table that ships with ctfit (package data: ``ctfit/data/optical_constants/<name>.csv``).
Every problem raises :class:`MaterialError` naming the file (and the line).
"""

from __future__ import annotations

import importlib.resources
import os
import pathlib
from typing import Any

import numpy as np

from .._model import f0_from_nk
from .errors import DataError, MaterialError
from .files import read_text
from .untrusted import check_input_file, quote

__all__ = ["TABLE_FOLDERS", "read_material_text", "is_table_name", "table_folders", "table_names", "read_optical_constants"]

_TABLES = importlib.resources.files("ctfit") / "data" / "optical_constants"  # package data
TABLE_FOLDERS = "CTFIT_OPTICAL_CONSTANTS"
"""The environment variable that lists further folders (``os.pathsep``-separated) where a
material file's ``optical_constants`` path may lead, beside the material file's own folder."""
MAX_TEXT_BYTES = 64 << 20
"""The largest material or optical-constants file read."""


def table_folders() -> list[pathlib.Path]:
    """The folders of :data:`TABLE_FOLDERS` (absolute ones; others are ignored).

    >>> import os
    >>> os.environ[TABLE_FOLDERS] = os.pathsep.join(["/srv/tables", "relative"])
    >>> table_folders()
    [PosixPath('/srv/tables')]
    >>> del os.environ[TABLE_FOLDERS]
    """
    return [pathlib.Path(p) for p in os.environ.get(TABLE_FOLDERS, "").split(os.pathsep) if p and os.path.isabs(p)]


def read_material_text(path: str | os.PathLike[str]) -> str:
    """The text of a material or optical-constants file (:func:`~ctfit._io.files.read_text`:
    UTF-8, a byte-order mark dropped); a missing, unreadable or undecodable file raises
    :class:`MaterialError` naming it, as does a file that is not a regular file, is not text or is
    larger than :data:`MAX_TEXT_BYTES` (:func:`~ctfit._io.untrusted.check_input_file`)."""
    try:
        if isinstance(path, (str, os.PathLike)):
            check_input_file(path, max_bytes=MAX_TEXT_BYTES)
        return read_text(path)
    except FileNotFoundError:
        raise MaterialError(f"{path}: no such file") from None
    except DataError as err:  # not UTF-8: names the file, line and byte
        raise MaterialError(str(err)) from None
    except OSError as err:
        raise MaterialError(f"{path}: cannot read: {err}") from err


def is_table_name(name: object) -> bool:
    """A bare name (``"Cu"``) rather than a path: a string without folder or suffix."""
    return isinstance(name, str) and bool(name) and pathlib.PurePath(name).name == name and "." not in name and "\\" not in name


def table_names() -> list[str]:
    """The optical constants tables that ship with ctfit (package data), by name."""
    return sorted(p.name[: -len(".csv")] for p in _TABLES.iterdir() if p.name.endswith(".csv"))


def _bundled_table(name: str) -> Any:
    """The package-data file of table ``name`` (an ``importlib.resources`` Traversable)."""
    resource = _TABLES / f"{name}.csv"
    if not resource.is_file():
        raise MaterialError(f"{name!r}: no such optical constants table; ctfit ships {', '.join(table_names())}")
    return resource


def _parse(path: str | os.PathLike[str], lines: list[str]) -> tuple[dict, list[str], list[list[float]], list[int]]:
    """``(meta, header, rows, row_lines)`` of the table's lines (``row_lines``: each row's 1-based line)."""
    meta: dict[str, str] = {}
    header: list[str] | None = None
    rows: list[list[float]] = []
    row_lines: list[int] = []
    for lineno, line in enumerate(lines, 1):
        if not line.strip():
            continue
        if line.startswith("#"):
            if header is None and ":" in line:
                key, value = line[1:].split(":", 1)
                meta[key.strip()] = value.strip()
            continue
        cells = [c.strip() for c in line.split(",")]
        if header is None:
            header = cells
            missing = [c for c in ("wavelength_nm", "n", "k") if c not in header]
            if missing:
                raise MaterialError(  # the content of a file that is no table is not shown
                    f"{path}:{lineno}: header lacks column(s) {missing}: not an optical constants table (docs/formats.md)"
                )
            continue
        if len(cells) != len(header):
            raise MaterialError(f"{path}:{lineno}: {len(cells)} values, header has {len(header)}")
        try:
            rows.append([float(c) for c in cells])
        except ValueError:
            j = next(j for j, c in enumerate(cells) if not _is_float(c))
            raise MaterialError(f"{path}:{lineno}: column {quote(header[j])} ({j + 1}): {quote(cells[j])} is not a number") from None
        row_lines.append(lineno)
    if header is None or not rows:  # (no header: no rows either)
        raise MaterialError(f"{path}: no data rows")
    return meta, header, rows, row_lines


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


_F0_TOLERANCE = 1e-4
"""How far a table's F0 column may be from ((n − 1)² + k²)/((n + 1)² + k²) (the tables that ship
with ctfit round each column to 6 decimals)."""


def _check_values(path: Any, header: list[str], table: np.ndarray, row_lines: list[int]) -> None:
    """The first value that breaks the table's rules, named by line and column: every number finite,
    wavelengths positive and strictly increasing, n and k ≥ 0, F0 the normal reflectance of n + i k.
    (A negative n, a negative k or a wavelength of 0 nm were read, and F0 = 2.1 from n = −1.2.)"""
    with np.errstate(invalid="ignore", over="ignore"):
        computed = f0_from_nk(table[:, header.index("n")], table[:, header.index("k")])
    rules = [(name, "is not a finite number", lambda v: ~np.isfinite(v)) for name in header]
    rules += [("wavelength_nm", "is not a wavelength (a positive number of nm)", lambda v: v <= 0),
              ("wavelength_nm", "is not above the row before's: wavelengths must be strictly increasing",
               lambda v: np.r_[False, np.diff(v) <= 0]),
              ("n", "is negative (a refractive index is ≥ 0)", lambda v: v < 0), ("k", "is negative (an extinction coefficient is ≥ 0)", lambda v: v < 0)]
    if "F0" in header:
        rules.append(("F0", "is not ((n − 1)² + k²)/((n + 1)² + k²) of its n and k", lambda v: ~(np.abs(v - computed) <= _F0_TOLERANCE)))
    for name, why, bad in rules:
        j = header.index(name)
        rows = np.flatnonzero(bad(table[:, j]))
        if rows.size:
            i = int(rows[0])
            extra = f" ({computed[i]:.6g})" if name == "F0" else ""
            raise MaterialError(f"{path}:{row_lines[i]}: column {quote(name)} ({j + 1}): {table[i, j]:g} {why}{extra}")


def read_optical_constants(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read an optical constants CSV (``docs/formats.md``): a path, or the name of a table that
    ships with ctfit (``"Cu"``, ``"Au"``, ``"Ag"``, ``"Al"``, ``"Fe"``, ``"stainless-steel"``;
    a name has no folder and no suffix).

    ``#`` lines first (``# key: value`` pairs go to ``meta``), then the header
    ``wavelength_nm,n,k[,F0]`` and one wavelength per row, strictly increasing. A missing
    ``F0`` column is computed as ((n − 1)² + k²)/((n + 1)² + k²).

    Returns ``{"wavelength_nm", "n", "k", "F0"}`` as float64 arrays plus ``"meta"`` (a dict).

    >>> gold = read_optical_constants("Au")
    >>> i = int(abs(gold["wavelength_nm"] - 600).argmin())
    >>> print(f'{gold["wavelength_nm"][i]:g} nm: F0 = {gold["F0"][i]:.3f}')  # gold reflects red well
    600 nm: F0 = 0.910
    >>> gold["meta"]["material"]
    'Gold (Au)'
    """
    path = _bundled_table(str(path)) if is_table_name(path) else pathlib.Path(path)
    meta, header, rows, row_lines = _parse(path, read_material_text(path).splitlines())
    table = np.asarray(rows, dtype=float)
    _check_values(path, header, table, row_lines)
    out: dict = {name: table[:, header.index(name)] for name in ("wavelength_nm", "n", "k")}
    out["F0"] = table[:, header.index("F0")] if "F0" in header else f0_from_nk(out["n"], out["k"])
    out["meta"] = meta
    return out
