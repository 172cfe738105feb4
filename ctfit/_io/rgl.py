"""The RGL material database's ``.bsdf`` files (Dupuy & Jakob 2018) read at their measured points.

A ``.bsdf`` file is a Mitsuba *tensor file* (``tensor_file\\0``, version 1.0, then named
little-endian arrays; Mitsuba's ``tensor_io.py``). An RGL BRDF holds, for each measured incident
direction (``phi_i`` × ``theta_i``, radians), a 2-D table over a square "sample space"
``[0, 1]²`` whose nodes are the measured points (``spectra`` (φ_i, θ_i, λ, n, n) with
``wavelengths`` in nm, or ``rgb`` (φ_i, θ_i, 3, n, n)), the visible-normal distribution
``vndf`` that warps sample space onto microfacet normals, the distribution of normals ``ndf``,
the projected area ``sigma``, a ``luminance`` table (for sampling only), a ``jacobian`` flag and
a ``description``.

Each node (u₁, u₂) = (k/(n−1), j/(n−1)) of a slice (φ_i, θ_i) becomes one direction pair, by the
warp Mitsuba's ``measured`` plugin inverts when it evaluates (``src/bsdfs/measured.cpp``): the
``vndf`` slice, a bilinear :func:`marginal_sample` (Mitsuba's continuous ``Marginal2D``), maps
the node to u_m; θ_m = u_m,x² π/2, φ_m = (2 u_m,y − 1) π (plus φ_i for isotropic files, whose
φ_m is relative to the light); the light ω_i at (θ_i, φ_i) is reflected about the normal m,
ω_o = 2 (ω_i·m) m − ω_i. The value is the node's, times D(u_m) / (4 σ(u_ω_i)) (``ndf`` and
``sigma`` interpolated bilinearly) when the jacobian flag is set: what Mitsuba's ``eval``
returns there, f_r cos θ_o. Dividing by cos θ_o gives the BRDF in sr⁻¹.

Dropped, and counted in ``meta``: cells the optional ``valid`` field marks 0; points with the
light or the viewer within ``MIN_COS`` of the horizon (cos θ < 0.01: Mitsuba returns 0 at and
below it and the division by cos θ_o is ill-conditioned next to it); negative values (RGB files
can hold them after the spectral → RGB conversion; a :class:`DataWarning` says how many).

Reference: J. Dupuy, W. Jakob, "An Adaptive Parameterization for Efficient Material Acquisition
and Rendering", ACM TOG 37(6), 2018, doi:10.1145/3272127.3275059; https://rgl.epfl.ch/materials.
"""

from __future__ import annotations

import math
import os
import warnings
from typing import Any

import numpy as np

from .._model import Measurement
from .errors import DataError, DataWarning
from .untrusted import check_input_file

__all__ = ["MIN_COS", "TENSOR_MAGIC", "bilinear", "marginal_sample", "read_rgl", "read_tensor_file"]

TENSOR_MAGIC = b"tensor_file\0"
MIN_COS = 0.01  # points with cos θ_i or cos θ_o below this are dropped
_DTYPES = {1: "u1", 2: "i1", 3: "<u2", 4: "<i2", 5: "<u4", 6: "<i4", 7: "<u8", 8: "<i8", 9: "<f2", 10: "<f4", 11: "<f8"}
_EPS, _ONE_MINUS_EPS = 2.0**-24, 1.0 - 2.0**-24  # Dr.Jit's float32 Epsilon, OneMinusEpsilon
_REQUIRED = ("description", "jacobian", "theta_i", "phi_i", "ndf", "sigma", "vndf", "luminance")


# --- tensor files -------------------------------------------------------------------------------


MAX_TENSOR_BYTES = 1 << 31
"""The largest tensor file read (the database's files are tens of MB): a larger one is refused
before it is read into memory."""


def read_tensor_file(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The named arrays of a Mitsuba tensor file, each checked to lie inside the file.

    Examples
    --------
    >>> import ctfit
    >>> with open("notes.bsdf", "wb") as f:
    ...     _ = f.write(b"hello")
    >>> ctfit.read_rgl("notes.bsdf")
    Traceback (most recent call last):
    ...
    ctfit._io.errors.DataError: notes.bsdf: not a tensor file: it does not start with 'tensor_file\\0' (an RGL .bsdf file does)
    """
    check_input_file(path, text=False, max_bytes=MAX_TENSOR_BYTES)  # a regular file, of a size a tensor file can have
    with open(path, "rb") as f:
        raw = f.read()
    if not raw.startswith(TENSOR_MAGIC):
        raise DataError("not a tensor file: it does not start with 'tensor_file\\0' (an RGL .bsdf file does)", path=path)
    pos = len(TENSOR_MAGIC)

    def take(fmt: str, count: int = 1) -> Any:
        nonlocal pos
        size = np.dtype(fmt).itemsize * count
        if pos + size > len(raw):
            raise DataError(f"truncated: the header ends at byte {len(raw)}, in the middle of a field description (byte {pos})", path=path)
        out = np.frombuffer(raw, fmt, count, pos)
        pos += size
        return out

    version = tuple(int(v) for v in take("u1", 2))
    if version != (1, 0):
        raise DataError(f"tensor file version {version[0]}.{version[1]}: only version 1.0 is known", path=path)
    fields = {}
    for _ in range(int(take("<u4")[0])):
        name = bytes(take("u1", int(take("<u2")[0]))).decode("utf-8", errors="replace")
        ndim, code, offset = int(take("<u2")[0]), int(take("u1")[0]), int(take("<u8")[0])
        shape = tuple(int(s) for s in take("<u8", ndim))
        if code not in _DTYPES:
            raise DataError(f"field {name!r}: unknown data type code {code} (tensor files use 1–11)", path=path)
        if name in fields:
            raise DataError(f"field {name!r} appears twice", path=path)
        dtype = np.dtype(_DTYPES[code])
        count = math.prod(shape)  # Python's integers: NumPy's int64 product wrapped (2³¹ × 2³¹ × 24 bytes read as 0)
        end = offset + dtype.itemsize * count
        if end > len(raw):
            raise DataError(
                f"truncated: field {name!r} ({dtype.name}, shape {shape}) takes bytes {offset}–{end}, the file has {len(raw)} bytes",
                path=path,
            )
        fields[name] = np.frombuffer(raw, dtype, count, offset).reshape(shape)
    return fields


def _structure(fields: dict, path: str | os.PathLike[str]) -> dict:
    """The fields of an RGL BRDF, checked as Mitsuba's ``measured`` plugin checks them."""
    spectral = "wavelengths" in fields
    values = "spectra" if spectral else "rgb"
    missing = [k for k in (*_REQUIRED, values) if k not in fields]
    if missing:
        raise DataError(
            f"a tensor file, but not an RGL BRDF: no field {', '.join(map(repr, missing))} (an RGL .bsdf file has "
            f"{', '.join(_REQUIRED)} and rgb, or spectra and wavelengths)",
            path=path,
        )
    f = {k: fields[k] for k in (*_REQUIRED, values, "wavelengths", "valid") if k in fields}
    p, t = len(f["phi_i"]), len(f["theta_i"])
    data = f[values]
    bands = len(f["wavelengths"]) if spectral else 3
    n = data.shape[3] if data.ndim == 5 else 0
    expect = {
        "description": ("uint8", 1, None), "jacobian": ("uint8", 1, (1,)), "theta_i": ("float32", 1, None),
        "phi_i": ("float32", 1, None), "ndf": ("float32", 2, None), "sigma": ("float32", 2, None),
        "vndf": ("float32", 4, (p, t, None, None)), "luminance": ("float32", 4, (p, t, n, n)),
        values: ("float32", 5, (p, t, bands, n, n)), "wavelengths": ("float32", 1, None), "valid": (None, 4, (p, t, n, n)),
    }
    for name, a in f.items():
        dtype, ndim, shape = expect[name]
        ok = (dtype is None or a.dtype == np.dtype(dtype)) and a.ndim == ndim
        ok = ok and (shape is None or all(s is None or s == d for s, d in zip(shape, a.shape)))
        if not ok:
            want = f"{dtype or 'any'} with {ndim} axes" + (f" of shape {tuple('*' if s is None else s for s in shape)}" if shape else "")
            raise DataError(f"field {name!r} is {a.dtype.name} of shape {a.shape}; an RGL BRDF has {want}", path=path)
    for name in ("ndf", "sigma", "vndf", values):
        if min(f[name].shape[-2:]) < 2 or min(p, t) < 1:
            raise DataError(f"field {name!r} of shape {f[name].shape}: a table needs at least 2 × 2 nodes, and one incident direction", path=path)
    for name in ("theta_i", "phi_i", "ndf", "sigma", "vndf", values, "wavelengths"):
        if name in f and not np.all(np.isfinite(f[name])):
            bad = tuple(int(i[0]) for i in np.nonzero(~np.isfinite(f[name])))
            raise DataError(f"field {name!r}, index {bad}: {f[name][bad]} is not a finite number", path=path)
    for name in ("ndf", "sigma", "vndf"):
        if np.any(f[name] < 0):
            raise DataError(f"field {name!r} has negative values: it is a density", path=path)
    empty = np.argwhere(~np.any(f["vndf"] > 0, axis=(2, 3)))
    if empty.size:  # (its normalisation divided by 0: an IndexError from a NaN index)
        raise DataError(f"field 'vndf', slice (phi_i {empty[0][0]}, theta_i {empty[0][1]}) is 0 everywhere: a density that places no "
                        "measured point", path=path)
    outside = np.flatnonzero((f["theta_i"] < 0) | (f["theta_i"] > np.pi / 2))
    if outside.size:  # (a negative one crashed the reader's look-up with an IndexError)
        v = float(f["theta_i"][outside[0]])
        raise DataError(f"field 'theta_i', index {int(outside[0])}: {v:.6g} rad ({np.degrees(v):.6g}°) is not an incident direction above the "
                        "surface (0 to π/2 rad)", path=path)
    if spectral and not (np.all(np.diff(f["wavelengths"]) > 0) and f["wavelengths"][0] > 0):
        raise DataError("field 'wavelengths' must be positive and increasing (nm)", path=path)
    return dict(f, values=data, spectral=spectral)


# --- Mitsuba's continuous Marginal2D --------------------------------------------------------------


def _sample_segment(s: np.ndarray, inv_width: float, v0: np.ndarray, v1: np.ndarray) -> np.ndarray:
    """Invert the integral of a linear density v0 → v1 over one cell (Mitsuba's ``sample_segment``)."""
    non_const = np.abs(v0 - v1) > 1e-4 * (v0 + v1)
    divisor = np.where(non_const, v0 - v1, v0 + v1)
    s = s * 2.0 * inv_width
    s = np.where(non_const, v0 - np.sqrt(np.maximum(v0 * v0 + s * (v1 - v0), 0.0)), s)
    return np.where(divisor != 0, s / np.where(divisor != 0, divisor, 1.0), s)


def marginal_sample(density: np.ndarray, sample: np.ndarray) -> np.ndarray:
    """Warp points of ``[0, 1]²`` (N, 2) by the bilinear density ``density`` (h, w), x along w.

    Mitsuba's ``Marginal2D<Float, 0, true>::sample`` (``include/mitsuba/core/distr_2d.h``,
    continuous): the row from the marginal CDF of the rows' integrals, then the column from the
    conditional CDF interpolated between the two rows, each inverted on its linear segment.

    Examples
    --------
    A uniform density leaves points where they are; one rising along x pushes them to larger x:

    >>> import numpy as np
    >>> from ctfit._io import marginal_sample
    >>> marginal_sample(np.ones((3, 4)), np.array([[0.25, 0.5]])).round(6).tolist()
    [[0.25, 0.5]]
    >>> bool(marginal_sample(np.array([[0.0, 1.0], [0.0, 1.0]]), np.array([[0.25, 0.5]]))[0, 0] > 0.25)
    True
    """
    d = np.asarray(density, dtype=np.float64)
    h, w = d.shape
    cond = np.cumsum(0.5 / (w - 1) * (d[:, :-1] + d[:, 1:]), axis=1)  # (h, w − 1)
    marg = np.cumsum(0.5 / (h - 1) * (cond[:-1, -1] + cond[1:, -1]))  # (h − 1,)
    norm = 1.0 / marg[-1]
    cond, marg, d = cond * norm, marg * norm, d * norm
    s = np.clip(np.asarray(sample, dtype=np.float64), _EPS, _ONE_MINUS_EPS)
    x, y = s[:, 0], s[:, 1]
    row = np.minimum(np.count_nonzero(marg[None, :] < y[:, None], axis=1), h - 2)
    y = y - np.where(row > 0, marg[row - 1], 0.0)
    r0, r1 = cond[row, -1], cond[row + 1, -1]
    y = _sample_segment(y, h - 1, r0, r1)
    x = x * (r0 + (r1 - r0) * y)
    cc = cond[row] + (cond[row + 1] - cond[row]) * y[:, None]  # conditional CDF between the rows
    col = np.minimum(np.count_nonzero(cc < x[:, None], axis=1), w - 2)
    x = x - np.where(col > 0, cc[np.arange(len(x)), col - 1], 0.0)
    c0 = d[row, col] + (d[row + 1, col] - d[row, col]) * y
    c1 = d[row, col + 1] + (d[row + 1, col + 1] - d[row, col + 1]) * y
    x = _sample_segment(x, w - 1, c0, c1)
    return np.stack([(col + x) / (w - 1), (row + y) / (h - 1)], axis=1)


def bilinear(table: np.ndarray, pos: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of ``table`` (h, w) at points ``pos`` (N, 2) of ``[0, 1]²`` (x along
    w), as Mitsuba's ``Marginal2D::eval`` of an unnormalised table.

    >>> import numpy as np
    >>> from ctfit._io import bilinear
    >>> bilinear(np.array([[0.0, 1.0], [2.0, 3.0]]), np.array([[0.5, 0.5], [1.0, 0.0]])).tolist()
    [1.5, 1.0]
    """
    t = np.asarray(table, dtype=np.float64)
    h, w = t.shape
    p = np.clip(np.asarray(pos, dtype=np.float64), 0.0, 1.0) * [w - 1, h - 1]
    i = np.minimum(p.astype(np.int64), [w - 2, h - 2])
    fx, fy = (p - i).T
    x, y = i.T
    top = t[y, x] + (t[y, x + 1] - t[y, x]) * fx
    bottom = t[y + 1, x] + (t[y + 1, x + 1] - t[y + 1, x]) * fx
    return top + (bottom - top) * fy


# --- measured points ----------------------------------------------------------------------------


def _azimuth_seen(theta_i: float, phi_i: float) -> float:
    """φ_i as Mitsuba computes it from the light's direction: atan2, in (−π, π]; 0 at θ_i = 0."""
    return 0.0 if theta_i == 0 else float(np.arctan2(np.sin(phi_i), np.cos(phi_i)))


def _slice_points(f: dict, p: int, t: int, nodes: np.ndarray, isotropic: bool, path: str | os.PathLike[str]) -> tuple[Any, Any, np.ndarray, Any]:
    """The light (θ_i, φ_i), the viewers (N, 3) and the factor D/(4σ) (or 1) of one slice's nodes."""
    theta_i = float(f["theta_i"][t])
    phi_i = _azimuth_seen(theta_i, float(f["phi_i"][p]))
    u_m = marginal_sample(f["vndf"][p, t], nodes)
    theta_m = u_m[:, 0] ** 2 * (np.pi / 2)
    phi_m = (2 * u_m[:, 1] - 1) * np.pi + (phi_i if isotropic else 0.0)
    m = np.stack([np.cos(phi_m) * np.sin(theta_m), np.sin(phi_m) * np.sin(theta_m), np.cos(theta_m)], axis=1)
    wi = np.array([np.sin(theta_i) * np.cos(phi_i), np.sin(theta_i) * np.sin(phi_i), np.cos(theta_i)])
    wo = 2 * (m @ wi)[:, None] * m - wi
    factor = np.ones(len(nodes))
    if f["jacobian"][0]:
        u_wi = np.array([[np.sqrt(theta_i * 2 / np.pi), (phi_i + np.pi) / (2 * np.pi)]])
        area = float(bilinear(f["sigma"], u_wi)[0])
        if area == 0:  # (the values came out infinite, with NumPy's divide-by-zero warning)
            raise DataError(f"field 'sigma' is 0 at the light of slice (phi_i {p}, theta_i {t}): a projected area that divides the values",
                            path=path)
        factor = bilinear(f["ndf"], u_m) / (4 * area)
    return theta_i, phi_i, wo, factor


def _anisotropy_error(f: dict, path: str | os.PathLike[str]) -> DataError:
    phi = np.degrees(f["phi_i"].astype(np.float64))
    return DataError(
        f"anisotropic BRDF: {len(phi)} incident azimuths φ_i from {phi[0]:g}° to {phi[-1]:g}° (an isotropic file has at "
        "most 2); ctfit's Cook–Torrance model is isotropic. To fit it anyway, read every azimuth's points with "
        "read_rgl(path, anisotropic=True) (the fit then averages over azimuth, in the least-squares sense)",
        path=path,
    )


def _points(f: dict, isotropic: bool, path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """Every kept node's angles (N, 4) in degrees, values (N, bands) in sr⁻¹, and the drop counts."""
    n_phi, n_theta, n_bands, n = f["values"].shape[:4]
    g = np.linspace(0.0, 1.0, n)
    nodes = np.stack([np.tile(g, n), np.repeat(g, n)], axis=1)  # row j (axis 3) outer, column k (axis 4) inner
    valid = f["valid"] != 0 if "valid" in f else np.ones((n_phi, n_theta, n, n), bool)
    angles, values = [], []
    counts = dict(invalid=int(np.count_nonzero(~valid)), horizon=0, normal=0)
    for p in range(n_phi):
        for t in range(n_theta):
            if f["theta_i"][t] == 0 and n_phi > 1 and abs(_azimuth_seen(1.0, float(f["phi_i"][p]))) > 1e-6:
                counts["normal"] += 1  # the same light as the φ_i = 0 slice, where Mitsuba reads it
                continue
            theta_i, phi_i, wo, factor = _slice_points(f, p, t, nodes, isotropic, path)
            seen = valid[p, t].reshape(-1) & (wo[:, 2] >= MIN_COS) & (np.cos(theta_i) >= MIN_COS)
            counts["horizon"] += int(np.count_nonzero(valid[p, t].reshape(-1) & ~seen))
            wo = wo[seen]
            theta_o = np.degrees(np.arctan2(np.hypot(wo[:, 0], wo[:, 1]), wo[:, 2]))
            phi_o = np.mod(np.degrees(np.arctan2(wo[:, 1], wo[:, 0])), 360.0)
            k = len(wo)
            angles.append(np.stack([np.full(k, np.degrees(theta_i)), np.full(k, np.mod(np.degrees(phi_i), 360.0)), theta_o, phi_o], 1))
            stored = f["values"][p, t].reshape(n_bands, n * n).T[seen].astype(np.float64)
            values.append(stored * (factor[seen] / wo[:, 2])[:, None])
    return np.concatenate(angles), np.concatenate(values), counts


def read_rgl(path: str | os.PathLike[str], *, anisotropic: bool = False) -> Measurement:
    """Read an RGL material database ``.bsdf`` file (spectral or RGB) at its measured points.

    Each node of each measured slice becomes one direction pair (see the module's description
    and ``docs/measurement-formats.md``), with the value Mitsuba's ``measured`` plugin returns
    there divided by cos θ_o: the BRDF in sr⁻¹. Spectral files give bands at their
    ``wavelengths``; RGB files channels R, G, B. ``meta["description"]`` is the file's
    description. Anisotropic files (more than 2 incident azimuths) are refused unless
    ``anisotropic=True``, which reads every azimuth's points (for an isotropic fit, an average
    over azimuth). Samples are ordered by slice (φ_i, then θ_i), node, then band.

    Examples
    --------
    A tensor file without the BRDF's fields:

    >>> import numpy as np, struct, ctfit
    >>> with open("other.bsdf", "wb") as f:
    ...     _ = f.write(b"tensor_file\\0" + struct.pack("<BBI", 1, 0, 0))
    >>> ctfit.read_rgl("other.bsdf")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ctfit._io.errors.DataError: other.bsdf: a tensor file, but not an RGL BRDF: no field 'description', ...
    """
    f = _structure(read_tensor_file(path), path)
    isotropic = len(f["phi_i"]) <= 2
    if not isotropic and not anisotropic:
        raise _anisotropy_error(f, path)
    angles, values, counts = _points(f, isotropic, path)
    n_bands = values.shape[1]
    keep = values >= 0
    negative = int(np.count_nonzero(~keep))
    if negative:
        warnings.warn(
            f"{os.fspath(path)}: {negative} negative values dropped (of {values.size}; an RGB file's spectral → RGB conversion "
            "can give them, and a BRDF is ≥ 0)", DataWarning, stacklevel=2,
        )
    pair, band = np.nonzero(keep)
    if len(pair) == 0:
        raise DataError("no measured point left (every one invalid, at the horizon or negative)", path=path)
    description = " ".join(bytes(f["description"]).decode("utf-8", errors="replace").split())
    n_phi, n_theta, _, n, _ = f["values"].shape
    meta = {
        "format": "RGL",
        "description": description,
        "rgl_resolution": f"{n_phi} phi_i x {n_theta} theta_i x {n} x {n} points x {n_bands} {'wavelengths' if f['spectral'] else 'channels'}",
        "rgl_isotropic": str(isotropic).lower(),
        "rgl_jacobian": str(int(f["jacobian"][0])),
        "rgl_invalid_cells": str(counts["invalid"]),
        "rgl_points_at_horizon": str(counts["horizon"]),
        "rgl_negative_values": str(negative),
    }
    if counts["normal"]:
        meta["rgl_normal_incidence_slices_skipped"] = str(counts["normal"])
    bands = dict(wavelength_nm=f["wavelengths"].astype(np.float64)) if f["spectral"] else dict(channels=("R", "G", "B"))
    a = angles[pair]
    return Measurement(theta_i=a[:, 0], phi_i=a[:, 1], theta_o=a[:, 2], phi_o=a[:, 3], band=band.astype(np.int16),
                       brdf=values[pair, band], meta=meta, source=os.fspath(path), **bands)
