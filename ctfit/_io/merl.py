"""MERL BRDF database files (``*.binary``, Matusik et al. 2003) to and from a :class:`~ctfit.Measurement`.

Layout (little-endian): three int32 dimensions ``(90, 90, 180)``, then 3 × 90·90·180 float64,
the R, G and B tables, each indexed ``[θ_h index, θ_d index, φ_d index]`` (φ_d fastest) in
Rusinkiewicz's half/difference angles. Stored values times 1/1500, 1.15/1500, 1.66/1500 (R, G,
B) are the BRDF in sr⁻¹; negative values mark cells that were not measured.

Index mapping, as in MERL's reference code (``BRDFRead.cpp``), angles in radians:

- θ_h: ``floor(sqrt(θ_h / (π/2) · 90 · 90))``, a square-root spacing dense near the specular peak;
- θ_d: ``floor(θ_d / (π/2) · 90)``;
- φ_d: ``floor(φ_d / π · 180)`` with φ_d folded into [0, π) (reciprocity: φ_d ≡ φ_d + π);

each clamped to the table. Reading places each cell at its centre in index space,
θ_h = (π/2)·((i + ½)/90)², θ_d = (π/2)·(j + ½)/90, φ_d = π·(k + ½)/180, which the index
mapping sends back to the same cell (the reference code's lookup uses cell lower edges; the
centre is the cell's representative, and avoids the exact edges where rounding decides the bin).
A cell becomes the direction pair with the half vector at (θ_h, φ_h = 0) and the difference
vector at (θ_d, φ_d) (Rusinkiewicz 1998): light L = R_y(θ_h)·d, viewer V = 2(L·H)H − L. Cells
with L or V on or below the horizon are skipped, as are unmeasured (negative) cells.

References: W. Matusik, H. Pfister, M. Brand, L. McMillan, "A Data-Driven Reflectance Model",
ACM TOG 22(3), 2003, doi:10.1145/882262.882343; S. Rusinkiewicz, "A New Change of Variables for
Efficient BRDF Representation", EGWR 1998, doi:10.1007/978-3-7091-6453-2_2.
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
from jaxtyping import ArrayLike, Float, Int

from .._model import Measurement
from .errors import DataError
from .files import atomic_write
from .untrusted import check_input_file

__all__ = [
    "MERL_SCALE",
    "MERL_SHAPE",
    "angles_deg_to_half_diff",
    "angles_deg_to_half_diff_deg",
    "half_diff_deg_to_angles_deg",
    "half_diff_to_angles_deg",
    "merl_cell_centres",
    "merl_phi_d_index",
    "merl_table",
    "merl_theta_d_index",
    "merl_theta_h_index",
    "read_merl",
    "write_merl",
]

MERL_SHAPE = (90, 90, 180)
MERL_SCALE = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
_CELLS = math.prod(MERL_SHAPE)
_HEADER_BYTES = 12
MERL_FILE_BYTES = _HEADER_BYTES + 3 * _CELLS * 8


# --- index mapping ------------------------------------------------------------------------------


def merl_theta_h_index(theta_h: Float[ArrayLike, "*batch"]) -> Int[np.ndarray, "*batch"]:
    """Table index of the half-vector angle θ_h (radians); square-root spacing."""
    theta_h = np.asarray(theta_h, dtype=np.float64)
    i = np.floor(np.sqrt(np.maximum(theta_h, 0) / (np.pi / 2) * 90 * 90))
    return np.clip(i, 0, 89).astype(np.int64)


def merl_theta_d_index(theta_d: Float[ArrayLike, "*batch"]) -> Int[np.ndarray, "*batch"]:
    """Table index of the difference angle θ_d (radians); uniform spacing over [0, π/2)."""
    i = np.floor(np.asarray(theta_d, dtype=np.float64) / (np.pi / 2) * 90)
    return np.clip(i, 0, 89).astype(np.int64)


def merl_phi_d_index(phi_d: Float[ArrayLike, "*batch"]) -> Int[np.ndarray, "*batch"]:
    """Table index of the difference azimuth φ_d (radians), folded into [0, π) by reciprocity."""
    i = np.floor(np.mod(np.asarray(phi_d, dtype=np.float64), np.pi) / np.pi * 180)
    return np.clip(i, 0, 179).astype(np.int64)


def merl_cell_centres() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cell centres ``(θ_h (90,), θ_d (90,), φ_d (180,))`` in radians; each maps back to its index."""
    theta_h = (np.pi / 2) * ((np.arange(90) + 0.5) / 90) ** 2
    theta_d = (np.pi / 2) * (np.arange(90) + 0.5) / 90
    phi_d = np.pi * (np.arange(180) + 0.5) / 180
    return theta_h, theta_d, phi_d


def merl_table(fn: Callable[..., Any]) -> Float[np.ndarray, "3 90 90 180"]:
    """A (3, 90, 90, 180) table of ``fn(θ_h, θ_d, φ_d)`` at the cell centres.

    ``fn`` gets broadcastable arrays of shapes (90, 1, 1), (1, 90, 1), (1, 1, 180) in radians and
    returns values broadcastable to (90, 90, 180) (the same in R, G and B), or a sequence of three
    such (one per channel); NaN marks a cell as unmeasured.

    Examples
    --------
    A Lambertian surface of albedo 0.5 (R = 0.5/π in every cell and channel):

    >>> import numpy as np, ctfit
    >>> table = ctfit.merl_table(lambda theta_h, theta_d, phi_d: 0.5 / np.pi)
    >>> table.shape, round(float(table[1, 10, 20, 30] * np.pi), 12)
    ((3, 90, 90, 180), 0.5)
    """
    th, td, pd = merl_cell_centres()
    values = fn(th[:, None, None], td[None, :, None], pd[None, None, :])
    if isinstance(values, (tuple, list)):
        if len(values) != 3:
            raise ValueError(f"fn returned {len(values)} channels; a MERL table has 3 (R, G, B)")
        return np.stack([np.broadcast_to(np.asarray(v, dtype=np.float64), MERL_SHAPE) for v in values])
    return np.broadcast_to(np.asarray(values, dtype=np.float64), (3, *MERL_SHAPE)).copy()


# --- half/difference angles ---------------------------------------------------------------------


def half_diff_deg_to_angles_deg(
    theta_h: Float[ArrayLike, "*#batch"], theta_d: Float[ArrayLike, "*#batch"], phi_d: Float[ArrayLike, "*#batch"]
) -> tuple[Float[np.ndarray, "*batch"], Float[np.ndarray, "*batch"], Float[np.ndarray, "*batch"], Float[np.ndarray, "*batch"]]:
    """(θ_i, φ_i, θ_o, φ_o) in degrees for half/difference angles (θ_h, θ_d, φ_d) in degrees, φ_h = 0.

    L is the difference vector rotated by θ_h about the y axis, V its mirror about the half
    vector H (Rusinkiewicz 1998). Directions below the horizon come out with θ > 90.

    Examples
    --------
    θ_h = 0 puts H on the normal: light and viewer are mirror images at θ_d:

    >>> import ctfit
    >>> [round(float(a), 6) for a in ctfit.half_diff_deg_to_angles_deg(0.0, 30.0, 0.0)]
    [30.0, 0.0, 30.0, 180.0]
    """
    return _half_diff_rad_to_angles_deg(*(np.deg2rad(np.asarray(a, dtype=np.float64)) for a in (theta_h, theta_d, phi_d)))


def angles_deg_to_half_diff_deg(
    theta_i: Float[ArrayLike, "*#batch"], phi_i: Float[ArrayLike, "*#batch"], theta_o: Float[ArrayLike, "*#batch"], phi_o: Float[ArrayLike, "*#batch"]
) -> tuple[Float[np.ndarray, "*batch"], Float[np.ndarray, "*batch"], Float[np.ndarray, "*batch"]]:
    """(θ_h, θ_d, φ_d) in degrees, φ_d in (−180, 180], for directions in degrees (the inverse of
    :func:`half_diff_deg_to_angles_deg`).

    Examples
    --------
    Light at 40° and viewer at 20° on the same side, in one plane: H bisects them at 30°, 10° from each:

    >>> import ctfit
    >>> [round(float(a), 6) for a in ctfit.angles_deg_to_half_diff_deg(40.0, 0.0, 20.0, 0.0)]
    [30.0, 10.0, 0.0]
    >>> angles = ctfit.half_diff_deg_to_angles_deg(20.0, 30.0, 90.0)
    >>> [round(float(a), 6) for a in ctfit.angles_deg_to_half_diff_deg(*angles)]  # the round trip
    [20.0, 30.0, 90.0]
    """
    theta_h, theta_d, phi_d = _angles_deg_to_half_diff_rad(theta_i, phi_i, theta_o, phi_o)
    return np.rad2deg(theta_h), np.rad2deg(theta_d), np.rad2deg(phi_d)


def half_diff_to_angles_deg(
    theta_h: Float[ArrayLike, "*#batch"], theta_d: Float[ArrayLike, "*#batch"], phi_d: Float[ArrayLike, "*#batch"]
) -> tuple[Float[np.ndarray, "*batch"], Float[np.ndarray, "*batch"], Float[np.ndarray, "*batch"], Float[np.ndarray, "*batch"]]:
    """Deprecated: takes θ_h, θ_d, φ_d in *radians*; use :func:`half_diff_deg_to_angles_deg` (degrees).

    Examples
    --------
    >>> import warnings, numpy as np, ctfit
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     angles = ctfit.half_diff_to_angles_deg(0.0, np.radians(30.0), 0.0)
    >>> caught[0].category.__name__, [round(float(a), 6) for a in angles]
    ('DeprecationWarning', [30.0, 0.0, 30.0, 180.0])
    """
    warnings.warn("half_diff_to_angles_deg takes radians despite its name and is deprecated: "
                  "use half_diff_deg_to_angles_deg, which takes degrees", DeprecationWarning, stacklevel=2)
    return _half_diff_rad_to_angles_deg(theta_h, theta_d, phi_d)


def angles_deg_to_half_diff(
    theta_i: Float[ArrayLike, "*#batch"], phi_i: Float[ArrayLike, "*#batch"], theta_o: Float[ArrayLike, "*#batch"], phi_o: Float[ArrayLike, "*#batch"]
) -> tuple[Float[np.ndarray, "*batch"], Float[np.ndarray, "*batch"], Float[np.ndarray, "*batch"]]:
    """Deprecated: returns θ_h, θ_d, φ_d in *radians*; use :func:`angles_deg_to_half_diff_deg` (degrees).

    Examples
    --------
    >>> import warnings, numpy as np, ctfit
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     half = ctfit.angles_deg_to_half_diff(40.0, 0.0, 20.0, 0.0)
    >>> caught[0].category.__name__, [round(float(np.degrees(a)), 6) for a in half]
    ('DeprecationWarning', [30.0, 10.0, 0.0])
    """
    warnings.warn("angles_deg_to_half_diff returns radians and is deprecated: "
                  "use angles_deg_to_half_diff_deg, which returns degrees", DeprecationWarning, stacklevel=2)
    return _angles_deg_to_half_diff_rad(theta_i, phi_i, theta_o, phi_o)


def _half_diff_rad_to_angles_deg(
    theta_h: ArrayLike, theta_d: ArrayLike, phi_d: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(θ_i, φ_i, θ_o, φ_o) in degrees for half/difference angles in radians, with φ_h = 0."""
    theta_h, theta_d, phi_d = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (theta_h, theta_d, phi_d)))
    sd, cd = np.sin(theta_d), np.cos(theta_d)
    sh, ch = np.sin(theta_h), np.cos(theta_h)
    dx, dy = sd * np.cos(phi_d), sd * np.sin(phi_d)
    lx, ly, lz = dx * ch + cd * sh, dy, cd * ch - dx * sh
    vx, vy, vz = 2 * cd * sh - lx, -ly, 2 * cd * ch - lz
    return (*_angles_deg(lx, ly, lz), *_angles_deg(vx, vy, vz))


def _angles_deg_to_half_diff_rad(
    theta_i: ArrayLike, phi_i: ArrayLike, theta_o: ArrayLike, phi_o: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(θ_h, θ_d, φ_d) in radians, φ_d in (−π, π], for directions in degrees."""
    l = _unit(theta_i, phi_i)
    v = _unit(theta_o, phi_o)
    h = l + v
    h = h / np.linalg.norm(h, axis=0)
    theta_h = np.arctan2(np.hypot(h[0], h[1]), h[2])
    phi_h = np.arctan2(h[1], h[0])
    # Rotate L by −φ_h about z, then by −θ_h about y: the difference vector.
    c, s = np.cos(phi_h), np.sin(phi_h)
    x, y, z = c * l[0] + s * l[1], c * l[1] - s * l[0], l[2]
    c, s = np.cos(theta_h), np.sin(theta_h)
    x, z = c * x - s * z, s * x + c * z
    return theta_h, np.arctan2(np.hypot(x, y), z), np.arctan2(y, x)


def _unit(theta_deg: ArrayLike, phi_deg: ArrayLike) -> np.ndarray:
    t, p = np.deg2rad(np.asarray(theta_deg, dtype=np.float64)), np.deg2rad(np.asarray(phi_deg, dtype=np.float64))
    return np.stack(np.broadcast_arrays(np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)))


def _angles_deg(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    theta = np.rad2deg(np.arctan2(np.hypot(x, y), z))
    phi = np.mod(np.rad2deg(np.arctan2(y, x)), 360.0) + 0.0
    return theta, np.where(phi >= 360.0, 0.0, phi)


def _cell_directions() -> tuple[np.ndarray, np.ndarray]:
    """(θ_i, φ_i, θ_o, φ_o) of every cell's centre, shape (cells, 4) in file order (the direction
    pairs are its rows: one gather), and the above-horizon mask. Computed one θ_h row at a time,
    so the temporaries stay small (a MERL table has 1.46M cells); not kept between reads (47 MB)."""
    th, td, pd = merl_cell_centres()
    angles = np.empty((_CELLS, 4))
    row = MERL_SHAPE[1] * MERL_SHAPE[2]
    for i, t in enumerate(th):
        for k, a in enumerate(_half_diff_rad_to_angles_deg(t, td[:, None], pd[None, :])):
            angles[i * row:(i + 1) * row, k] = a.reshape(-1)
    return angles, (angles[:, 0] < 90) & (angles[:, 2] < 90)


# --- files --------------------------------------------------------------------------------------


def read_merl(path: str | os.PathLike[str]) -> Measurement:
    """Read a MERL ``.binary`` file as an RGB measurement (channels R, G, B).

    Samples are ordered by cell (file order), and within a cell by channel. ``meta`` counts the
    unmeasured (negative) values and the cells skipped below the horizon. The direction pairs
    are known from the cells, so :meth:`Measurement.directions` gives them in cell order
    without a search for repeated rows.

    Examples
    --------
    A file must hold the whole table (see :func:`write_merl` for one that does):

    >>> import numpy as np, ctfit
    >>> with open("header-only.binary", "wb") as f:
    ...     _ = f.write(np.array([90, 90, 180], "<i4").tobytes())
    >>> ctfit.read_merl("header-only.binary")
    Traceback (most recent call last):
    ...
    ctfit._io.errors.DataError: header-only.binary: truncated: 12 bytes; a (90, 90, 180) table of 3 channels takes 34992012 bytes
    """
    check_input_file(path, text=False)
    with open(path, "rb") as f:
        raw = f.read(MERL_FILE_BYTES + 1)  # no more: a file of another size is refused
        size = os.fstat(f.fileno()).st_size
    if len(raw) < _HEADER_BYTES:
        raise DataError(f"truncated: {len(raw)} bytes; a MERL file starts with three int32 dimensions (12 bytes)", path=path)
    dims = tuple(int(d) for d in np.frombuffer(raw, "<i4", 3))
    if dims != MERL_SHAPE:
        raise DataError(f"dimensions {dims} in the header (bytes 0–11): a MERL file has {MERL_SHAPE} (θ_h, θ_d, φ_d)", path=path)
    if len(raw) != MERL_FILE_BYTES:
        what = "truncated" if len(raw) < MERL_FILE_BYTES else "too long"
        raise DataError(f"{what}: {size} bytes; a {MERL_SHAPE} table of 3 channels takes {MERL_FILE_BYTES} bytes", path=path)
    table = np.frombuffer(raw, "<f8", 3 * _CELLS, _HEADER_BYTES).reshape(3, _CELLS)
    bad = ~np.isfinite(table)
    if bad.any():
        ch, cell = (int(x[0]) for x in np.nonzero(bad))
        raise DataError(
            f"{'RGB'[ch]} table, cell {tuple(int(i) for i in np.unravel_index(cell, MERL_SHAPE))} (byte offset "
            f"{_HEADER_BYTES + 8 * (ch * _CELLS + cell)}): {table[ch, cell]} is not a finite number",
            path=path,
        )
    angles, above = _cell_directions()
    measured = table.T >= 0  # (cells, 3)
    keep = measured & above[:, None]
    cells = np.flatnonzero(keep.any(axis=1))  # the direction pairs, in file order
    if cells.size == 0:  # (read as 0 samples: 'no samples to write', '0 samples, 4 free parameters', the file unnamed or unexplained)
        raise DataError("no measured value: every cell is unmeasured (negative) or has the light or the viewer below the horizon", path=path)
    pairs = angles[cells]
    del angles
    keep = keep[cells]
    pair, band = np.nonzero(keep)  # samples: by cell, then channel
    brdf = table.T[cells][keep] * MERL_SCALE[band]
    return Measurement.from_direction_pairs(  # the angles held per cell (35 MB), not per sample (105 MB)
        pairs,
        pair.astype(np.int32),  # < 1.46M cells
        band=band.astype(np.int8),
        channels=("R", "G", "B"),
        brdf=brdf,
        meta={
            "format": "MERL",
            "merl_unmeasured_values": str(int(np.count_nonzero(~measured))),
            "merl_cells_below_horizon": str(int(np.count_nonzero(~above))),
            "merl_cell_position": "centre",
        },
        source=os.fspath(path),
    )


def write_merl(path: str | os.PathLike[str], rgb_table: Float[ArrayLike, "3 90 90 180"]) -> None:
    """Write a (3, 90, 90, 180) table of BRDF values (sr⁻¹) as a MERL ``.binary`` file, atomically.

    NaN or negative values are written as unmeasured cells (−1).

    Examples
    --------
    A Lambertian surface of albedo 0.5 written (35 MB) and read back: every cell with light and
    viewer above the horizon, in R, G and B, with R = 0.5/π:

    >>> import numpy as np, ctfit
    >>> ctfit.write_merl("lambert.binary", ctfit.merl_table(lambda theta_h, theta_d, phi_d: 0.5 / np.pi))
    >>> m = ctfit.read_merl("lambert.binary")
    >>> len(m), m.channels, m.meta["merl_cells_below_horizon"], bool(np.allclose(np.pi * m.brdf, 0.5))
    (3288648, ('R', 'G', 'B'), '361784', True)
    """
    if np.iscomplexobj(rgb_table):  # (its imaginary part was dropped with a warning)
        raise ValueError("a MERL table holds real BRDF values, got complex ones")
    table = np.asarray(rgb_table, dtype=np.float64)
    if table.shape != (3, *MERL_SHAPE):
        raise ValueError(f"a MERL table has shape {(3, *MERL_SHAPE)}, got {table.shape}")
    if np.isinf(table).any():
        raise ValueError("a MERL table cannot hold infinite values")
    with np.errstate(over="ignore"):
        stored = np.where(np.isnan(table) | (table < 0), -1.0, table / MERL_SCALE[:, None, None, None])
    if np.isinf(stored).any():  # a value above ~1.2e305 sr⁻¹ stored as MERL's scaled float: read_merl refused the file
        channel, *cell = (int(i[0]) for i in np.nonzero(np.isinf(stored)))
        raise ValueError(f"channel {'RGB'[channel]}, cell {tuple(cell)}: {table[(channel, *cell)]:g} sr⁻¹ is too large for a MERL file "
                         f"(stored as value / {MERL_SCALE[channel]:g}, it overflows a double)")
    atomic_write(path, [np.array(MERL_SHAPE, "<i4").tobytes(), stored.astype("<f8").tobytes()])
