"""BRDF samples in memory: what every reader returns and what fitting and evaluation consume.

One sample per row, as in the measurement CSV (``docs/formats.md``): light direction
(θ_i, φ_i), viewer direction (θ_o, φ_o) in degrees, a band (a wavelength in nm, or an RGB
channel), the BRDF in sr⁻¹ and optionally its standard uncertainty.

Samples sharing a direction pair share their geometry: :meth:`Measurement.directions` gives the
unique direction pairs and, for each sample, the index of its pair, so the model computes D and
G once per pair and F per (pair, band).
"""

from __future__ import annotations

import copy
import dataclasses
import functools
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from jaxtyping import ArrayLike, Float, Int

from .direction_pairs import unique_direction_pairs
from .names import valid_name

__all__ = ["Measurement", "band_labels", "check_samples", "format_value", "invalid_value", "value_rules"]


def format_value(x: float) -> str:
    """A value as messages show it: ``repr(float(x))``, "NaN" for a NaN."""
    return "NaN" if np.isnan(x) else repr(float(x))


def not_finite_why(x: float) -> str:
    """Why a value that is not finite is refused; an infinite one may be a number past float64's
    range in the file (``1e400`` reads as ``inf``)."""
    beyond = "; a number beyond ±1.8e308, float64's range, reads as infinite" if np.isinf(x) else ""
    return f"{format_value(x)} is not allowed (values must be finite numbers{beyond})"


def value_rules(name: str) -> list:
    """The rules of a column of samples, each ``(test, why)``: ``test(values)`` marks the values
    that break it (any shape), ``why(value)`` says why. Every value finite, and θ in [0, 90]
    degrees, wavelengths > 0, brdf ≥ 0, sigma > 0.

    >>> [why(-1.0) for test, why in value_rules("brdf")]
    ['-1.0 is not allowed (values must be finite numbers)', '-1.0 is negative (a BRDF is ≥ 0 sr⁻¹)']
    """
    rules = [(lambda v: ~np.isfinite(v), not_finite_why)]
    if name.startswith("theta"):
        rules.append((lambda v: (v < 0) | (v > 90), lambda x: f"{format_value(x)} is outside [0, 90] degrees"))
    elif name == "wavelength_nm":
        rules.append((lambda v: v <= 0, lambda x: f"{format_value(x)} is not a positive wavelength in nm"))
    elif name == "brdf":
        rules.append((lambda v: v < 0, lambda x: f"{format_value(x)} is negative (a BRDF is ≥ 0 sr⁻¹)"))
    elif name == "sigma":
        rules.append((lambda v: v <= 0, lambda x: f"{format_value(x)}: sigma must be positive"))
    return rules


def invalid_value(name: str, values: ArrayLike) -> tuple[int, str] | None:
    """The first row of the column ``name`` (theta_i, phi_i, theta_o, phi_o, wavelength_nm, brdf,
    sigma) whose value is not allowed, and why; None when every value is. The one rule of every
    reader (the CSV reader, texel stores) and of :class:`Measurement`.

    >>> invalid_value("theta_o", [10.0, 120.0]), invalid_value("brdf", [0.0, 1.5])
    ((1, '120.0 is outside [0, 90] degrees'), None)
    """
    v = np.asarray(values, dtype=float)
    found = None
    for bad, why in value_rules(name):
        hit = bad(v)
        if hit.any():
            row = int(np.argmax(hit))
            if found is None or row < found[0]:
                found = (row, why(v[row]))
    return found


ANGLES = ("theta_i", "phi_i", "theta_o", "phi_o")
"""The per-sample angle fields of a :class:`Measurement`, in the column order of its direction pairs."""


def _held(m: Measurement, name: str) -> tuple[Any, np.ndarray | None]:
    """A field of ``m`` as it is held: ``(value, None)``, or for an angle held per direction pair
    (:meth:`Measurement.from_direction_pairs`, not read yet) the pairs' column and each sample's
    pair index, so that a check does not gather it per sample."""
    if name in ANGLES and name not in m.__dict__:
        pairs, index = m.__dict__["_directions"]
        return pairs[:, ANGLES.index(name)], index
    return getattr(m, name), None


def _real_column(m: Measurement, name: str, a: Any) -> np.ndarray:
    kind = np.asarray(a).dtype.kind
    if kind not in "biuf" or np.ndim(a) != 1:
        raise TypeError(f"Measurement {m.source}: {name} must be a 1-D array of real numbers, got {np.asarray(a).dtype} of shape {np.shape(a)}")
    return a


def check_samples(m: Measurement) -> None:
    """Raise (naming the field and the row) unless ``m``'s samples are what every reader
    returns: real numbers of the right domain (:func:`invalid_value`), band indices into its
    bands, positive increasing wavelengths. ``TypeError`` for a wrong kind, ``ValueError`` for a value."""
    for name in (*ANGLES, "brdf", "sigma"):
        values, index = _held(m, name)
        if values is not None:
            found = invalid_value(name, _real_column(m, name, values))
            if found is not None and index is not None:  # a direction pair's value: the first sample of such a pair
                found = invalid_value(name, values[index])
            if found is not None:
                raise ValueError(f"Measurement {m.source}: {name}[{found[0]}]: {found[1]}")
    band = np.asarray(m.band)
    if band.ndim != 1 or band.dtype.kind not in "iu":
        raise TypeError(f"Measurement {m.source}: band must be a 1-D array of integers (band indices), got {band.dtype} of shape {band.shape}")
    out = (band < 0) | (band >= m.n_bands)
    if out.any():
        row = int(np.argmax(out))
        raise ValueError(f"Measurement {m.source}: band[{row}] = {int(band[row])} is not a band index: the data has {m.n_bands} "
                         f"band{'s' if m.n_bands != 1 else ''} (0..{m.n_bands - 1})")
    if m.wavelength_nm is not None:
        wl = _real_column(m, "wavelength_nm", m.wavelength_nm)
        found = invalid_value("wavelength_nm", wl)
        if found is None and np.any(np.diff(np.asarray(wl, dtype=float)) <= 0):
            found = (int(np.argmax(np.diff(np.asarray(wl, dtype=float)) <= 0)) + 1, "the wavelengths must be strictly increasing")
        if found is not None:
            raise ValueError(f"Measurement {m.source}: wavelength_nm[{found[0]}]: {found[1]}")


def band_labels(wavelength_nm: Sequence[float] | np.ndarray | None, channels: Sequence[str] | None, band_unknown: bool = False) -> list[str]:
    """One label per band: "450 nm", a channel name, or "unknown band" (one band whose
    wavelength is not known)."""
    if band_unknown:
        return ["unknown band"]
    if channels is not None:
        return list(channels)
    return [] if wavelength_nm is None else [f"{w:g} nm" for w in np.asarray(wavelength_nm, dtype=float).tolist()]  # Python floats format faster


@dataclasses.dataclass(frozen=True, eq=False)
class Measurement:
    """BRDF samples.

    - ``theta_i, phi_i, theta_o, phi_o``: float arrays (N,), degrees (φ already taken modulo 360);
      held per direction pair, and gathered when first read, by :meth:`from_direction_pairs`.
    - ``band``: int array (N,), index into ``wavelength_nm`` (spectral) or ``channels`` (RGB).
    - ``wavelength_nm``: float array (W,), ascending, or None; ``channels``: e.g. ("R", "G", "B")
      or None. Exactly one of the two is set.
    - ``brdf``: float array (N,) in sr⁻¹, or None (geometry only, e.g. for ``ctfit eval``).
    - ``sigma``: float array (N,) in sr⁻¹, or None.
    - ``meta``: ``# key: value`` metadata; ``source``: where it came from (a path), for messages.
    - ``band_unknown``: the data has one band whose wavelength is not known (ALTA files without
      wavelengths); ``wavelength_nm`` then holds a placeholder that must not be shown as a
      wavelength or turned into a colour.

    Examples
    --------
    Two direction pairs (the mirror direction at 30° and at 45°), each measured in two bands:

    >>> import numpy as np, ctfit
    >>> m = ctfit.Measurement(theta_i=np.array([30.0, 30.0, 45.0, 45.0]), phi_i=np.zeros(4),
    ...                       theta_o=np.array([30.0, 30.0, 45.0, 45.0]), phi_o=np.full(4, 180.0),
    ...                       band=np.array([0, 1, 0, 1]), wavelength_nm=np.array([450.0, 650.0]),
    ...                       brdf=np.array([0.8, 0.9, 0.5, 0.6]))
    >>> len(m), m.band_labels, m.directions()[1].tolist()  # each sample's direction pair
    (4, ['450 nm', '650 nm'], [0, 0, 1, 1])
    """

    theta_i: Float[np.ndarray, " samples"]
    phi_i: Float[np.ndarray, " samples"]
    theta_o: Float[np.ndarray, " samples"]
    phi_o: Float[np.ndarray, " samples"]
    band: Int[np.ndarray, " samples"]
    wavelength_nm: Float[np.ndarray, " bands"] | None = None
    channels: tuple[str, ...] | None = None
    brdf: Float[np.ndarray, " samples"] | None = None
    sigma: Float[np.ndarray, " samples"] | None = None
    meta: dict = dataclasses.field(default_factory=dict)
    source: str = "<memory>"
    band_unknown: bool = False

    def __post_init__(self) -> None:
        if isinstance(self.source, str) and self.source != (source := valid_name(self.source)):
            object.__setattr__(self, "source", source)  # a file name that is not UTF-8 (names.py)
        if (self.wavelength_nm is None) == (self.channels is None):
            raise ValueError("a Measurement has either wavelength_nm or channels, not both or neither")
        if self.band_unknown and self.n_bands != 1:
            raise ValueError(f"band_unknown is for single-band data; this one has {self.n_bands} bands")
        lengths = {name: (None if a is None else len(a if index is None else index))
                   for name in (*ANGLES, "band", "brdf", "sigma") for a, index in [_held(self, name)]}
        n = lengths["theta_i"]
        for name, size in lengths.items():
            if size is not None and size != n:
                raise ValueError(f"{name} has {size} entries, theta_i has {n}")
        check_samples(self)

    def __len__(self) -> int:
        return len(self.band)  # (as long as every column: __post_init__), and held even where the angles are not

    @classmethod
    def from_direction_pairs(cls, pairs: Float[ArrayLike, "pairs 4"], index: Int[ArrayLike, " samples"], **fields: Any) -> Measurement:
        """A measurement whose samples' angles are ``pairs[index]``, held per direction pair: for
        readers that know their pairs (a MERL table's cells). ``pairs`` (D, 4) as (θ_i, φ_i, θ_o,
        φ_o) in degrees, unique; ``index`` (N,) integers (int32 halves its memory); ``fields``
        the other fields, as :class:`Measurement` takes them (``band`` and the bands at least).

        :meth:`directions` returns ``pairs`` and ``index`` with no search, and each of ``theta_i``,
        ``phi_i``, ``theta_o``, ``phi_o`` is gathered per sample when first read (and then kept):
        a fit, which works per pair, reads none of them, so a MERL table's fit does not hold their
        105 MB. Otherwise the measurement is what the constructor with those angles gives.

        Examples
        --------
        >>> import numpy as np, ctfit
        >>> m = ctfit.Measurement.from_direction_pairs(np.array([[30.0, 0, 30, 180], [45, 0, 45, 180]]), np.array([0, 0, 1, 1]),
        ...                                            band=np.array([0, 1, 0, 1]), channels=("R", "G"), brdf=np.array([0.8, 0.9, 0.5, 0.6]))
        >>> len(m), m.directions()[1].tolist(), m.theta_i.tolist()
        (4, [0, 0, 1, 1], [30.0, 30.0, 45.0, 45.0])
        """
        pairs, index = np.asarray(pairs, dtype=np.float64), np.asarray(index)
        if pairs.ndim != 2 or pairs.shape[1] != 4 or index.ndim != 1 or not np.issubdtype(index.dtype, np.integer):
            raise ValueError(f"pairs must have shape (D, 4) and index (N,) integers; got {pairs.shape} and {index.shape} {index.dtype}")
        if len(index) and (int(index.min()) < 0 or int(index.max()) >= len(pairs)):
            raise ValueError(f"index must point into the {len(pairs)} direction pairs; its values are {int(index.min())}..{int(index.max())}")
        pairs.setflags(write=False)
        index.setflags(write=False)
        held = _PerPair(pairs, index)
        return cls(theta_i=held, phi_i=held, theta_o=held, phi_o=held, **fields)  # type: ignore[arg-type]

    @property
    def n_bands(self) -> int:
        bands = self.channels if self.channels is not None else self.wavelength_nm
        return 0 if bands is None else len(bands)  # one of the two is set (__post_init__)

    @property
    def band_labels(self) -> list[str]:
        """One label per band: "450 nm", a channel name, or "unknown band" (``band_unknown``)."""
        return band_labels(self.wavelength_nm, self.channels, self.band_unknown)

    def directions(self) -> tuple[Float[np.ndarray, "pairs 4"], Int[np.ndarray, " samples"]]:
        """Unique direction pairs (D, 4) as (θ_i, φ_i, θ_o, φ_o) and each sample's pair index (N,).

        The pairs are in lexicographic order (a lexsort of the four columns, ~10× faster than
        ``np.unique(axis=0)`` on large files, same result; rows that repeat the row before — the
        bands of one direction pair, as files usually list them — are sorted once), or in the
        order a reader gave them (:meth:`with_directions`). Computed once per Measurement and kept
        by :meth:`replace` while the angles stay (the arrays returned are read-only).
        """
        return self._directions

    def with_directions(self, pairs: Float[ArrayLike, "pairs 4"], index: Int[ArrayLike, " samples"]) -> Measurement:
        """This measurement with its direction pairs given, for readers that know them (a MERL
        table's cells): ``pairs`` (D, 4) unique, ``index`` (N,) with ``pairs[index]`` equal to each
        sample's angles (any integer type: int32 halves its memory). Saves the search in
        :meth:`directions` (and its memory) on large files."""
        pairs, index = np.asarray(pairs, dtype=np.float64), np.asarray(index)
        if pairs.ndim != 2 or pairs.shape[1] != 4 or index.shape != (len(self),) or not np.issubdtype(index.dtype, np.integer):
            raise ValueError(f"pairs must have shape (D, 4) and index ({len(self)},) integers; got {pairs.shape} and {index.shape} {index.dtype}")
        pairs.setflags(write=False)
        index.setflags(write=False)
        new = copy.copy(self)  # the same samples, checked already: no second check of every value (0.07 s on a MERL table)
        new.__dict__.pop("repeats", None)  # found from the direction pairs
        new.__dict__["_directions"] = (pairs, index)
        return new

    @functools.cached_property
    def _directions(self) -> tuple[np.ndarray, np.ndarray]:
        return unique_direction_pairs(self.theta_i, self.phi_i, self.theta_o, self.phi_o)

    @functools.cached_property
    def repeats(self) -> bool:
        """Whether some (direction pair, band) cell has more than one sample (repeated measurements)."""
        pairs, index = self.directions()
        flat = index.astype(np.intp) * self.n_bands + self.band
        cells = len(pairs) * self.n_bands
        if cells <= 4 * len(flat):  # a count per cell: O(N), no sort
            return bool(np.bincount(flat, minlength=cells).max(initial=0) > 1)
        return len(np.unique(flat)) != len(flat)

    def grid(self) -> tuple[Float[np.ndarray, "pairs 4"], Int[np.ndarray, " samples"]] | None:
        """The samples as a dense (D, W) grid when every pair has every band exactly once.

        Returns ``(pairs (D, 4), order (N,))`` with ``order`` such that
        ``brdf[order].reshape(D, W)`` is the grid, or None when the data is not a full grid.
        """
        pairs, index = self.directions()
        d, w = len(pairs), self.n_bands
        if d * w != len(self) or self.repeats:
            return None
        flat = index.astype(np.intp) * w + self.band
        order = np.argsort(flat, kind="stable")
        return pairs, order

    def with_lines(self, first_line: int, columns: Mapping[str, int]) -> Measurement:
        """This measurement with the place of its samples in the text file they were read from (a
        measurement CSV, one line a sample with no line between): sample ``i`` on line
        ``first_line + i``, column ``name`` the ``columns[name]``-th (both 1-based). A value refused
        later (a fit's checks of the data's scale, :func:`~ctfit._fitting.validate.sample_error`) is
        then named by its line and column, as a reader names one. :meth:`replace` keeps it while the
        samples stay (another ``source`` or ``meta``), and drops it when they change.

        >>> import numpy as np, ctfit
        >>> m = ctfit.Measurement(theta_i=np.array([30.0, 45.0]), phi_i=np.zeros(2), theta_o=np.array([30.0, 45.0]),
        ...                       phi_o=np.full(2, 180.0), band=np.zeros(2, int), wavelength_nm=np.array([550.0]), brdf=np.array([0.8, 0.5]))
        >>> m.file_place(1, "brdf"), m.with_lines(3, {"brdf": 6}).file_place(1, "brdf")
        (None, (4, 6))
        """
        new = copy.copy(self)  # the same samples, checked already
        new.__dict__["_lines"] = (int(first_line), {str(k): int(v) for k, v in columns.items()})
        return new

    def file_place(self, row: int, column: str) -> tuple[int, int] | None:
        """(line, column index), both 1-based, of sample ``row``'s (0-based) ``column`` in the file
        the samples were read from (:meth:`with_lines`); None for samples made in memory, read
        from a file of other lines (ALTA, RGL) or a binary table (MERL), or changed since."""
        lines = self.__dict__.get("_lines")
        if lines is None or column not in lines[1] or not 0 <= row < len(self):
            return None
        return lines[0] + int(row), lines[1][column]

    def replace(self, **changes: Any) -> Measurement:
        """A copy with ``changes``; it keeps the direction pairs found already when the angles stay
        (and angles held per pair, :meth:`from_direction_pairs`, held so), and the samples' lines in
        their file (:meth:`with_lines`) when no sample's value changes."""
        if not changes.keys() & set(ANGLES) and any(name not in self.__dict__ for name in ANGLES):
            fields = {f.name: self.__dict__[f.name] for f in dataclasses.fields(self) if f.name not in ANGLES}
            new = type(self).from_direction_pairs(*self._directions, **{**fields, **changes})
        else:
            new = dataclasses.replace(self, **changes)
        if "_directions" in self.__dict__ and not changes.keys() & set(ANGLES):
            new.__dict__["_directions"] = self.__dict__["_directions"]
        if "_lines" in self.__dict__ and not changes.keys() & {"theta_i", "phi_i", "theta_o", "phi_o", "band", "brdf", "sigma"}:
            new.__dict__["_lines"] = self.__dict__["_lines"]
        return new


@dataclasses.dataclass(frozen=True, eq=False)
class _PerPair:
    """What :meth:`Measurement.from_direction_pairs` gives the constructor for each angle: the
    direction pairs and each sample's pair, which the measurement holds instead of the angle."""

    pairs: np.ndarray
    index: np.ndarray


class _Angle:
    """The descriptor of a per-sample angle of :class:`Measurement` (``theta_i`` ...): the array
    it was given, or, held per direction pair (:class:`_PerPair`), that pair column gathered per
    sample on first read and kept."""

    def __init__(self, name: str) -> None:
        self.name, self.column = name, ANGLES.index(name)

    def __get__(self, obj: Measurement | None, owner: type | None = None) -> Any:
        if obj is None:
            return self
        held = obj.__dict__
        if self.name not in held:
            pairs, index = held["_directions"]
            held[self.name] = pairs[index, self.column]  # (another thread reading it at once gathers the same values)
        return held[self.name]

    def __set__(self, obj: Measurement, value: Any) -> None:
        if isinstance(value, _PerPair):
            obj.__dict__["_directions"] = (value.pairs, value.index)
        else:
            obj.__dict__[self.name] = value


for _name in ANGLES:  # set after the dataclass is made: a class attribute there would be the field's default
    setattr(Measurement, _name, _Angle(_name))
del _name
