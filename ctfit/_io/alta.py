"""ALTA's text data files (``docs/measurement-formats.md``) read into a :class:`~ctfit.Measurement`.

An ALTA file has ``#`` header lines (``#DIM in out``, ``#PARAM_IN name``, ``#PARAM_OUT name``,
``#VS n``, and free ones such as ``#SAMPLE``, ``#ORIGIN``, ``#URL``), then one sample per line,
whitespace separated: the ``in`` input coordinates, the ``out`` values and, with ``#VS 1`` or
``#VS 2``, a confidence interval for each value.

Supported input parametrisations (names as in ALTA's ``params.h``):

- ``ISOTROPIC_TL_TV_PROJ_DPHI``: ``[θ_l, θ_v cos Δφ, θ_v sin Δφ]`` in radians; the light lies in
  the plane φ = 0 (φ = 180° for θ_l < 0), the viewer at θ_v = hypot, φ_v = atan2 of the last two.
- ``COS_TH``: cos θ_h of the half vector. A 1-D slice has no other coordinate, so each sample is
  placed where ALTA itself places it (``params::half_to_cartesian(θ_h, 0, 0, 0)``): θ_d = 0, i.e.
  light and viewer both along the half vector, θ_i = θ_o = θ_h, φ_i = φ_o = 0.

Supported outputs: ``INV_STERADIAN`` (the BRDF, sr⁻¹), ``INV_STERADIAN_COSINE_FACTOR`` (BRDF ×
cos θ_v: divided by cos θ_v here; samples with the viewer on the horizon, θ_v within 1e-6° of
90°, are dropped with a :class:`~ctfit.DataWarning`), both with one value per sample, and ``RGB_COLOR`` (three values:
channels R, G, B, in sr⁻¹). Angles are converted to degrees and rounded to 1e-9° (so that
π/12 written to 32 digits reads as 15°, not 14.999999999999998°); the cosine factor uses the
unrounded angle. One-band data have no wavelength; they get the placeholder band
``wavelength_nm = [550.0]`` with ``band_unknown=True`` (labelled "unknown band", never shown as
550 nm or turned into a colour), and ``meta["wavelength_nm"]`` says so.

Confidence intervals (``#VS``) become ``sigma``: ``#VS 1`` gives a half-width ``dt`` per value
(the interval is value ± dt), ``#VS 2`` lower and upper bounds; σ is the half-width of the
interval. (ALTA calls them confidence intervals without a stated coverage; ctfit takes the
half-width as the standard uncertainty.)

References: ALTA, the BRDF analysis library (Inria, MPL 2.0), sources/core/params.{h,cpp} and
sources/core/data_storage.cpp; https://alta.gforge.inria.fr/.
"""

from __future__ import annotations

import itertools
import math
import os
import re
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

from .._model import Measurement, format_value, not_finite_why
from .errors import DataError, DataWarning
from .files import read_text
from .json_numbers import json_numbers
from .untrusted import check_input_file, quote, shorten

__all__ = ["PARAM_IN", "PARAM_OUT", "PLACEHOLDER_WAVELENGTH_NM", "read_alta"]

PARAM_IN = {
    "ISOTROPIC_TL_TV_PROJ_DPHI": ("theta_l", "theta_v*cos(dphi)", "theta_v*sin(dphi)"),
    "COS_TH": ("cos(theta_h)",),
}
PARAM_OUT = {"INV_STERADIAN": 1, "INV_STERADIAN_COSINE_FACTOR": 1, "RGB_COLOR": 3}
PLACEHOLDER_WAVELENGTH_NM = 550.0
_TOL = 1e-9  # radians (or cosine) beyond a domain edge still read as the edge
_HORIZON_DEG = 90 - 1e-6  # a viewer this close to the horizon has no usable cos θ_v
_HEADER = re.compile(r"#([A-Z][A-Z0-9_]*)(?:\s+(.*))?")


def read_alta(path: str | os.PathLike[str], *, param_out: str | None = None, param_out_default: str | None = None) -> Measurement:
    r"""Read an ALTA text data file.

    ``param_out`` names the output parametrisation for a file without a ``#PARAM_OUT`` line
    (ALTA's own default is "unknown", which ctfit refuses to guess); it must agree with the
    file when the file has one. ``param_out_default`` serves only a file without the line (the
    file's own line wins: ``ctfit --param-out``).

    Examples
    --------
    One sample: light at θ_l = π/12 in the plane φ = 0, viewer at θ_v = π/12 with Δφ = π (the
    mirror direction), BRDF 2.5 sr⁻¹; one band of unknown wavelength:

    >>> import ctfit
    >>> with open("mirror.alta", "w") as f:
    ...     _ = f.write("#DIM 3 1\n#PARAM_IN ISOTROPIC_TL_TV_PROJ_DPHI\n#PARAM_OUT INV_STERADIAN\n"
    ...                 "0.2617993877991494 -0.2617993877991494 0 2.5\n")
    >>> m = ctfit.read_alta("mirror.alta")
    >>> m.theta_i.tolist(), m.theta_o.tolist(), m.phi_o.tolist(), m.brdf.tolist(), m.band_labels
    ([15.0], [15.0], [180.0], [2.5], ['unknown band'])
    """
    check_input_file(path)
    text = read_text(path)
    header, rows, lines = _split(text, path)
    if "PARAM_OUT" not in header and param_out is None:
        param_out = param_out_default
    dim_in, dim_out, pin, pout, vs = _interpret(header, param_out, path)
    names = _column_names(pin, pout, vs)
    data = _numbers(rows, lines, names, path)
    values = data[:, dim_in : dim_in + dim_out]
    for j in range(dim_out):
        _check(values[:, j] < 0, lines, names, dim_in + j, "{} is negative (a BRDF is ≥ 0 sr⁻¹)", data, path)
    sigma = _sigma(data, dim_in, dim_out, vs, lines, names, path)
    theta_i, phi_i, theta_o, phi_o, cos_o = _directions(data[:, :dim_in], pin, lines, names, path)
    meta = {f"alta_{k.lower()}": v for k, (v, _) in header.items() if k not in ("DIM", "VS")}
    meta["alta_param_out"] = pout
    if pout == "INV_STERADIAN_COSINE_FACTOR":
        keep = theta_o < _HORIZON_DEG
        if not keep.all():
            dropped = int(np.count_nonzero(~keep))
            note = f"{dropped} samples with theta_o ≥ 90° dropped (a cosine-weighted value cannot be divided by cos θ_o = 0)"
            if not keep.any():
                raise DataError(f"no samples left: {note}", path=path)
            warnings.warn(f"{os.fspath(path)}: {note}", DataWarning, stacklevel=2)
            meta["dropped"] = note
        theta_i, phi_i, theta_o, phi_o, values, cos_o = (a[keep] for a in (theta_i, phi_i, theta_o, phi_o, values, cos_o))
        values = values / cos_o[:, None]
        sigma = None if sigma is None else sigma[keep] / cos_o[:, None]
    if pout == "RGB_COLOR":
        rep = lambda a: np.repeat(a, 3)  # sample 3r + k is channel k of row r
        bands = dict(channels=("R", "G", "B"), band=np.tile(np.arange(3), len(values)))
    else:
        rep = lambda a: a
        bands = dict(wavelength_nm=np.array([PLACEHOLDER_WAVELENGTH_NM]), band=np.zeros(len(values), np.int64), band_unknown=True)
        meta["wavelength_nm"] = f"unknown (single band); {PLACEHOLDER_WAVELENGTH_NM:g} used as placeholder"
    return Measurement(
        theta_i=rep(theta_i),
        phi_i=rep(phi_i),
        theta_o=rep(theta_o),
        phi_o=rep(phi_o),
        brdf=values.reshape(-1),
        sigma=None if sigma is None else sigma.reshape(-1),
        meta=meta,
        source=os.fspath(path),
        **bands,
    )


def _split(text: str, path: str | os.PathLike[str]) -> tuple[dict[str, tuple[str, int]], list[str], np.ndarray]:
    """Header {KEY: (value, line)}, data lines and their line numbers."""
    header: dict[str, tuple[str, int]] = {}
    rows: list[str] = []
    lines: list[int] = []
    for k, line in enumerate(text.replace("\r\n", "\n").replace("\r", "\n").split("\n"), start=1):  # LF, CR LF or CR
        line = line.strip()
        if line.startswith("#"):
            m = _HEADER.fullmatch(line)
            if m is None:
                continue  # free text
            key, value = m[1], (m[2] or "").strip()
            if key in header and key != "VS":
                raise DataError(f"#{key} appears twice (also line {header[key][1]})", path=path, line=k)
            if key == "VS" and key in header and value != header[key][0]:
                raise DataError(f"#VS {shorten(value)} differs from #VS {shorten(header[key][0])} on line {header[key][1]}", path=path, line=k)
            header.setdefault(key, (value.strip('"') if key in ("SAMPLE", "ORIGIN") else value, k))
        elif line:
            rows.append(line)
            lines.append(k)
    return header, rows, np.array(lines)


def _interpret(header: dict, param_out: str | None, path: str | os.PathLike[str]) -> Any:
    def need(key: str, what: str) -> tuple[str, int]:
        if key not in header:
            raise DataError(f"no #{key} line ({what}); is this an ALTA data file?", path=path)
        return header[key]

    if "FORMAT" in header and header["FORMAT"][0].lower() != "text":
        value, line = header["FORMAT"]
        raise DataError(f"#FORMAT {shorten(value)}: only ALTA's text format is supported", path=path, line=line)
    dim, line = need("DIM", "the numbers of input and output dimensions, e.g. '#DIM 3 1'")
    try:
        dim_in, dim_out = (int(x) for x in dim.split())
    except ValueError:
        raise DataError(f"#DIM {quote(dim)}: expected two integers, e.g. '#DIM 3 1'", path=path, line=line) from None
    pin, line_in = need("PARAM_IN", "the input parametrisation")
    if pin not in PARAM_IN:
        raise DataError(f"#PARAM_IN {shorten(pin)}: not supported (supported: {', '.join(PARAM_IN)})", path=path, line=line_in)
    if dim_in != len(PARAM_IN[pin]):
        raise DataError(f"#DIM says {dim_in} inputs, #PARAM_IN {pin} has {len(PARAM_IN[pin])}", path=path, line=line)
    if "PARAM_OUT" in header:
        pout, line_out = header["PARAM_OUT"]
        if param_out is not None and param_out != pout:
            raise DataError(f"#PARAM_OUT {shorten(pout)} contradicts param_out={param_out!r}", path=path, line=line_out)
    elif param_out is not None:
        pout, line_out = param_out, None
    else:
        raise DataError(
            "no #PARAM_OUT line: the unit of the values is unknown. Add one (e.g. '#PARAM_OUT INV_STERADIAN' for a "
            "BRDF in sr⁻¹, '#PARAM_OUT INV_STERADIAN_COSINE_FACTOR' for BRDF × cos θ_v) or pass param_out=...",
            path=path,
        )
    if pout not in PARAM_OUT:
        raise DataError(f"output {shorten(pout)}: not supported (supported: {', '.join(PARAM_OUT)})", path=path, line=line_out)
    if dim_out != PARAM_OUT[pout]:
        raise DataError(_outputs_mismatch(dim_out, pout, given=line_out is None), path=path, line=line)
    vs, line_vs = header.get("VS", ("0", None))
    if vs not in ("0", "1", "2"):
        raise DataError(f"#VS {shorten(vs)}: expected 0, 1 or 2", path=path, line=line_vs)
    return dim_in, dim_out, pin, pout, int(vs)


def _outputs_mismatch(dim_out: int, pout: str, given: bool) -> str:
    """Why #DIM's outputs and the unit ``pout`` disagree; ``given``: the unit is the ``param_out``
    argument's (the file has no #PARAM_OUT line), so the argument is at fault, not the file.

    >>> _outputs_mismatch(1, "RGB_COLOR", given=True)
    "#DIM says 1 outputs, and param_out='RGB_COLOR' (the file has no #PARAM_OUT line) has 3: give one of INV_STERADIAN, INV_STERADIAN_COSINE_FACTOR"
    """
    if not given:
        return f"#DIM says {dim_out} outputs, {pout} has {PARAM_OUT[pout]}"
    fits = [name for name, n in PARAM_OUT.items() if n == dim_out]
    hint = f"give one of {', '.join(fits)}" if fits else f"no unit has {dim_out} outputs"
    return f"#DIM says {dim_out} outputs, and param_out={pout!r} (the file has no #PARAM_OUT line) has {PARAM_OUT[pout]}: {hint}"


def _column_names(pin: str, pout: str, vs: int) -> list[str]:
    outputs = ("R", "G", "B") if pout == "RGB_COLOR" else ("value",)
    intervals = {0: (), 1: ("{}_halfwidth",), 2: ("{}_lower", "{}_upper")}[vs]
    return [*PARAM_IN[pin], *outputs, *(f.format(o) for o in outputs for f in intervals)]


def _numbers(rows: list[str], lines: np.ndarray, names: list[str], path: str | os.PathLike[str]) -> np.ndarray:
    if not rows:
        raise DataError("no data lines", path=path)
    data = _numbers_at_once(rows, len(names))
    if data is None:
        data = _numbers_by_row(rows, lines, names, path)
    for j in range(len(names)):
        _check(~np.isfinite(data[:, j]), lines, names, j, not_finite_why, data, path)
    return data


def _numbers_at_once(rows: list[str], columns: int) -> np.ndarray | None:
    """The rows' numbers decoded as one JSON array (:func:`~ctfit._io.json_numbers.json_numbers`),
    (rows × ``columns``); None where a row has another count of fields or a field is not a number
    JSON takes: :func:`_numbers_by_row` then reads the rows (or names the first bad one). The same
    values as ``float()`` of each field, a ``-0``'s sign included; 7,397 rows of four 34-digit
    numbers (``measurements/brdf/retro-3M-jaune.dat``): 9.4 ms against 20.6 ms."""
    split = list(map(str.split, rows))
    if (np.fromiter(map(len, split), np.int64, len(rows)) != columns).any():
        return None
    flat = json_numbers(f"[{','.join(itertools.chain.from_iterable(split))}]".encode())
    if flat is None or flat.size != len(rows) * columns:
        return None
    return flat.reshape(len(rows), columns)


def _numbers_by_row(rows: list[str], lines: np.ndarray, names: list[str], path: str | os.PathLike[str]) -> np.ndarray:
    """Each field read by ``float()``, row by row; the first bad row or field raises ``DataError``."""
    data = np.empty((len(rows), len(names)))
    for r, row in enumerate(rows):
        fields = row.split()
        if len(fields) != len(names):
            raise DataError(f"expected {len(names)} numbers ({' '.join(names)}), found {len(fields)}", path=path, line=int(lines[r]))
        for j, field in enumerate(fields):
            try:
                data[r, j] = float(field)
            except ValueError:
                raise DataError(f"{quote(field)} is not a number", path=path, line=int(lines[r]), column=names[j], index=j + 1) from None
    return data


def _check(bad: np.ndarray, lines: np.ndarray, names: list[str], j: int, message: str | Callable[[float], str], data: np.ndarray,
           path: str | os.PathLike[str]) -> None:
    """A :class:`DataError` at the first ``bad`` row of column ``j``; ``message``: a format of the value, or what says why from it."""
    if bad.any():
        r = int(np.argmax(bad))
        x = data[r, j]
        text = message(x) if callable(message) else message.format(format_value(x))
        raise DataError(text, path=path, line=int(lines[r]), column=names[j], index=j + 1)


def _sigma(
    data: np.ndarray, dim_in: int, dim_out: int, vs: int, lines: np.ndarray, names: list[str], path: str | os.PathLike[str]
) -> np.ndarray | None:
    if vs == 0:
        return None
    values = data[:, dim_in : dim_in + dim_out]
    extra = data[:, dim_in + dim_out :]
    if vs == 1:
        sigma = extra
        for j in range(dim_out):
            _check(sigma[:, j] <= 0, lines, names, dim_in + dim_out + j, "{}: the half-width must be positive", data, path)
        return sigma
    lower, upper = extra[:, 0::2], extra[:, 1::2]
    for j in range(dim_out):
        col = dim_in + dim_out + 2 * j
        _check(lower[:, j] > values[:, j], lines, names, col, "{}: the lower bound exceeds the value", data, path)
        _check(upper[:, j] < values[:, j], lines, names, col + 1, "{}: the upper bound is below the value", data, path)
        _check(upper[:, j] <= lower[:, j], lines, names, col + 1, "{}: the interval is empty", data, path)
    return 0.5 * (upper - lower)


def _directions(x: np.ndarray, pin: str, lines: np.ndarray, names: list[str], path: str | os.PathLike[str]) -> tuple[np.ndarray, ...]:
    """(θ_i, φ_i, θ_o, φ_o) in degrees, and cos θ_o, from the input coordinates."""
    if pin == "COS_TH":
        c = x[:, 0]
        _check((c < -_TOL) | (c > 1 + _TOL), lines, names, 0, "{} is not the cosine of a half vector above the surface (0 to 1)", x, path)
        theta = _degrees(np.arccos(np.clip(c, 0, 1)))
        zero = np.zeros_like(theta)
        return theta, zero, theta.copy(), zero.copy(), np.clip(c, 0, 1)
    theta_l, u, v = x.T
    _check(np.abs(theta_l) > math.pi / 2 + _TOL, lines, names, 0, "{} rad: the light is below the horizon", x, path)
    theta_v = np.hypot(u, v)
    below = theta_v > math.pi / 2 + _TOL
    if below.any():
        r = int(np.argmax(below))
        raise DataError(
            f"θ_v = hypot({float(u[r])!r}, {float(v[r])!r}) = {float(theta_v[r])!r} rad > π/2: the viewer is below the horizon",
            path=path,
            line=int(lines[r]),
            column=f"{names[1]}, {names[2]}",
            index=2,
        )
    theta_i = np.minimum(_degrees(np.abs(theta_l)), 90.0)
    phi_i = np.where(theta_l < 0, 180.0, 0.0)
    theta_o = np.minimum(_degrees(theta_v), 90.0)
    phi_o = np.mod(_degrees(np.arctan2(v, u)), 360.0) + 0.0
    phi_o[phi_o >= 360.0] = 0.0
    return theta_i, phi_i, theta_o, phi_o, np.cos(theta_v)


def _degrees(radians: np.ndarray) -> np.ndarray:
    """Degrees rounded to 1e-9° (far below any goniometer's resolution), so that π/12 reads as 15°."""
    return np.round(np.rad2deg(radians), 9) + 0.0
