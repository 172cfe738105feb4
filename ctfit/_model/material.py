"""A material: its static structure, its parameters (a pytree) and the spectral bands they live on.

The structure (number of lobes, distribution, geometry term, Fresnel form, presence of a
specular and of a diffuse part, normalisation) is static: it decides which terms the compiled
model contains. Parameters a structure does not use are ``None`` in :class:`Params` — they do
not exist in the pytree, so they are neither traced nor fitted.
"""

from __future__ import annotations

import dataclasses
import numbers
from collections.abc import Callable, Sequence
from typing import Literal

import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .measurement import band_labels
from .names import valid_name
from .pytrees import pytree

__all__ = ["Structure", "Params", "Material", "used", "wrong_size",
           "DISTRIBUTIONS", "GEOMETRIES", "FRESNELS", "DIFFUSES", "NORMALIZATIONS", "FAMILIES", "MAX_LOBES"]

DISTRIBUTIONS = ("beckmann", "gaussian")
GEOMETRIES = ("v-cavity", "smith", "smith-rational")
MAX_LOBES = 8
"""Most Beckmann/Gaussian lobes in one structure (paper eq. 5's weighted sum); every reader and the CLI use this."""
FRESNELS = ("f0", "n", "conductor")
DIFFUSES = (None, "F0/pi", "spectrum", "constant", "transmitted")
FAMILIES = ("metal", "plastic")
"""The paper's two kinds of material (§4): a *metal* (F0(λ), or n(λ) and k(λ); its diffuse part,
if any, is the paper's R_d = F0/π or a free spectrum) and a *plastic* (a dielectric: one real index
n for every band, the specular part the colour of the light, and an independent diffuse R_d(λ),
Lambertian or Fresnel-transmitted)."""
NORMALIZATIONS = ("normalized", "cook-torrance-1982")


@dataclasses.dataclass(frozen=True)
class Structure:
    """Static shape of a Cook–Torrance material (hashable; a jit static argument).

    - ``lobes``: number of facet-slope distributions in the specular sum Σ w_j D(m_j)
      (paper eq. 5); 0 means no specular part (s = 0).
    - ``distribution``: "beckmann" (eq. 4) or "gaussian" (eq. 3).
    - ``geometry``: "v-cavity" (the paper's G, eq. 8), "smith" (Beckmann–Smith, per lobe) or
      "smith-rational" (the same with Walter et al.'s rational G1, as Mitsuba 3 evaluates it).
    - ``fresnel``: how F is parameterised — "f0" (normal reflectance with the paper's
      effective index, k = 0), "n" (real index, k = 0) or "conductor" (n + i k).
    - ``diffuse``: None (d = 0), "F0/pi" (R_d = F0/π, the paper's homogeneous material),
      "spectrum" (an independent Lambertian R_d per band), "constant" (one R_d for all bands) or
      "transmitted" (plastic only: R_d(λ) weighted by the Fresnel transmission into and out of
      the surface, (1 − F(θ_i))(1 − F(θ_o)) / (n² (1 − F_dr,int)), as Mitsuba 3's ``plastic``
      and ``roughplastic``; see :func:`~ctfit.transmitted_diffuse_factor`).
    - ``normalization``: "normalized" (R_s = F D G/(4 (N·L)(N·V)), D = D̂/π) or
      "cook-torrance-1982" (R_s = F D̂ G/(π (N·L)(N·V))); the latter is 4× the former.
    - ``family``: "metal" (default) or "plastic" (:data:`FAMILIES`). A plastic's Fresnel term is
      a dielectric's with *one* real index n for every band, fitted inside
      :data:`~ctfit.PLASTIC_INDEX_RANGE` (``fresnel`` is "n"; left at its default it is set so),
      and its diffuse part is independent of it ("spectrum", "constant" or "transmitted").

    Examples
    --------
    >>> import ctfit
    >>> st = ctfit.Structure(lobes=2, diffuse="F0/pi")  # two Beckmann lobes and R_d = F0/π
    >>> st.has_s, st == ctfit.Structure(lobes=2, diffuse="F0/pi")  # s is fitted; equal structures compile once
    (True, True)
    >>> ctfit.Structure(family="plastic", diffuse="transmitted").fresnel  # one real index for all bands
    'n'
    >>> ctfit.Structure(lobes=0)
    Traceback (most recent call last):
    ...
    ValueError: a material needs a specular part (lobes ≥ 1) or a diffuse part
    """

    lobes: int = 1
    distribution: Literal["beckmann", "gaussian"] = "beckmann"
    geometry: Literal["v-cavity", "smith", "smith-rational"] = "v-cavity"
    fresnel: Literal["f0", "n", "conductor"] = "f0"
    diffuse: Literal["F0/pi", "spectrum", "constant", "transmitted"] | None = None
    normalization: Literal["normalized", "cook-torrance-1982"] = "normalized"
    family: Literal["metal", "plastic"] = "metal"

    def __post_init__(self) -> None:
        if self.family == "plastic" and self.fresnel == "f0":
            object.__setattr__(self, "fresnel", "n")  # a plastic's index is a real n
        if isinstance(self.lobes, numbers.Integral) and not isinstance(self.lobes, (bool, np.bool_)):
            object.__setattr__(self, "lobes", int(self.lobes))  # np.int64(2) is 2: one hash, one compiled program
        if not isinstance(self.lobes, int) or isinstance(self.lobes, bool) or not 0 <= self.lobes <= MAX_LOBES:
            raise ValueError(f"lobes must be an integer in 0..{MAX_LOBES}, got {self.lobes!r}")
        for name, allowed in (
            ("distribution", DISTRIBUTIONS),
            ("geometry", GEOMETRIES),
            ("fresnel", FRESNELS),
            ("diffuse", DIFFUSES),
            ("normalization", NORMALIZATIONS),
            ("family", FAMILIES),
        ):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {allowed}, got {getattr(self, name)!r}")
        if self.lobes == 0 and self.diffuse is None:
            raise ValueError("a material needs a specular part (lobes ≥ 1) or a diffuse part")
        if self.family == "plastic" and (self.fresnel != "n" or self.diffuse == "F0/pi"):
            raise ValueError("a plastic has one real index n (fresnel 'n') and a diffuse part of its own "
                             f"(diffuse 'spectrum', 'constant', 'transmitted' or None), got fresnel={self.fresnel!r}, diffuse={self.diffuse!r}")
        if self.diffuse == "transmitted" and self.family != "plastic":
            raise ValueError("diffuse 'transmitted' (through a dielectric interface) needs family='plastic'")

    @property
    def has_specular(self) -> bool:
        return self.lobes > 0

    @property
    def has_diffuse(self) -> bool:
        return self.diffuse is not None

    @property
    def has_s(self) -> bool:
        """Whether s is a parameter (both parts present; otherwise s is 1 or 0 exactly)."""
        return self.has_specular and self.has_diffuse

    @property
    def needs_fresnel_params(self) -> bool:
        return self.has_specular or self.diffuse in ("F0/pi", "transmitted")

    @property
    def has_rd(self) -> bool:
        """Whether R_d is a parameter of its own (not F0/π)."""
        return self.diffuse in ("spectrum", "constant", "transmitted")

    @property
    def shared_index(self) -> bool:
        """Whether n is one value for every band (a plastic) rather than a spectrum."""
        return self.family == "plastic"


@pytree
@dataclasses.dataclass(frozen=True, eq=False)
class Params:
    """Parameters of a material; fields a structure does not use are None.

    - ``s``: specular fraction (scalar), d = 1 − s (only when both parts exist).
    - ``m``: rms slopes, shape (lobes,); ``w``: lobe weights, shape (lobes,), Σ w = 1.
    - ``f0``: normal reflectance per band (fresnel "f0"); ``n``: real index per band
      (fresnel "n" or "conductor"); ``k``: extinction coefficient per band ("conductor").
    - ``rd``: diffuse BRDF R_d in sr⁻¹ per band ("spectrum") or a scalar ("constant").
      An albedo ρ corresponds to R_d = ρ/π.

    Examples
    --------
    A pytree whose leaves are the fields that are set (here s, k, n and rd are None):

    >>> import jax, numpy as np, ctfit
    >>> p = ctfit.Params(m=np.array([0.3, 0.1]), w=np.array([0.6, 0.4]), f0=np.array([0.04]))
    >>> p.s is None, len(jax.tree.leaves(p))
    (True, 3)
    """

    s: Float[Array | np.ndarray, ""] | None = None
    m: Float[Array | np.ndarray, " lobes"] | None = None
    w: Float[Array | np.ndarray, " lobes"] | None = None
    f0: Float[Array | np.ndarray, " bands"] | None = None
    n: Float[Array | np.ndarray, "*bands"] | None = None
    k: Float[Array | np.ndarray, " bands"] | None = None
    rd: Float[Array | np.ndarray, "*bands"] | None = None


_SPECTRAL_FIELDS = ("f0", "n", "k", "rd")


def used(value: Array | np.ndarray | None) -> Array | np.ndarray:
    """A parameter the structure uses, so one that is set (``Params`` leaves only the others None).

    >>> used(None)
    Traceback (most recent call last):
    ...
    ValueError: the structure uses a parameter that is None in Params
    """
    if value is None:
        raise ValueError("the structure uses a parameter that is None in Params")
    return value


@dataclasses.dataclass(frozen=True, eq=False)
class Material:
    """Structure + parameters + the bands they are given on.

    ``wavelength_nm`` (for spectral materials) or ``channels`` (e.g. ("R", "G", "B")) names the
    bands of the per-band parameters. ``name`` and ``meta`` are free text carried along.
    ``band_unknown``: one band whose wavelength is not known (a fit of single-band data, e.g. an
    ALTA file); ``wavelength_nm`` is then a placeholder, and the material has no colour.

    Examples
    --------
    >>> import numpy as np, ctfit
    >>> gold = ctfit.Material(ctfit.Structure(), ctfit.Params(m=np.array([0.2]), w=np.array([1.0]), f0=np.array([0.4, 0.9])),
    ...                       wavelength_nm=np.array([450.0, 650.0]), name="gold")
    >>> gold.band_labels
    ['450 nm', '650 nm']
    >>> gold.params_at([550.0]).f0.round(6).tolist()  # linear in λ between the listed wavelengths
    [0.65]
    """

    structure: Structure
    params: Params
    wavelength_nm: Float[np.ndarray, " bands"] | None = None
    channels: tuple[str, ...] | None = None
    name: str = ""
    meta: dict = dataclasses.field(default_factory=dict)
    band_unknown: bool = False

    def __post_init__(self) -> None:
        if isinstance(self.name, str) and self.name != (name := valid_name(self.name)):
            object.__setattr__(self, "name", name)  # a material file's name that is not UTF-8 (names.py)
        if self.band_unknown and (self.wavelength_nm is None or len(self.wavelength_nm) != 1):
            raise ValueError(f"material {self.name!r}: band_unknown needs exactly one wavelength band (a placeholder)")

    def check_shapes(self) -> Material:
        """The material itself, when its parameters have its structure's shapes — m and the
        weights one per lobe, F0, n, k, R_d one per band (or one for all) — else a ``ValueError``
        naming the parameter (a structure of two lobes with one m evaluated its lobe twice).

        >>> import numpy as np, ctfit
        >>> ctfit.Material(ctfit.Structure(lobes=2), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.5])),
        ...                wavelength_nm=np.array([550.0])).check_shapes()
        Traceback (most recent call last):
        ...
        ValueError: material '': m has 1 values; its structure has 2 lobes
        """
        bands = len(self.channels) if self.channels is not None else (len(self.wavelength_nm) if self.wavelength_nm is not None else None)
        bad = wrong_size(self.structure, self.params, bands)
        if bad is None:
            return self
        name, got = bad
        lobes = f"; its structure has {self.structure.lobes} lobe{'s' * (self.structure.lobes != 1)}"
        takes = {"m": lobes, "w": lobes,
                 "s": "; s is one number"}.get(name, f" for its {bands} band{'s' * (bands != 1)}")
        raise ValueError(f"material {self.name!r}: {name} has {got} values{takes}")

    @property
    def is_rgb(self) -> bool:
        return self.channels is not None

    def check_colour_channels(self) -> Material:
        """The material itself where it has a colour's bands — wavelengths, or the channels R, G, B
        in any order — else a ``ValueError`` naming its channels: a colour, a rendering and an
        export (glTF, MERL, Mitsuba) need them, and a channel ``"X"`` is no colour's.

        >>> import numpy as np, ctfit
        >>> ctfit.Material(ctfit.Structure(), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.5])), channels=("X",),
        ...                name="x").check_colour_channels()
        Traceback (most recent call last):
        ...
        ValueError: material 'x' has channels ['X'], not R, G, B: it has no colour to report, render or export (give it R, G, B or wavelengths)
        """
        if self.channels is None or sorted(self.channels) == ["B", "G", "R"]:
            return self
        raise ValueError(f"material {self.name!r} has channels {list(self.channels)}, not R, G, B: it has no colour to report, render or export "
                         "(give it R, G, B or wavelengths)")

    @property
    def band_labels(self) -> list[str]:
        """One label per band: "450 nm", a channel name, or "unknown band" (``band_unknown``)."""
        return band_labels(self.wavelength_nm, self.channels, self.band_unknown)

    def params_at(self, wavelength_nm: Float[ArrayLike, " bands"] | None = None, channels: Sequence[str] | None = None) -> Params:
        """Per-band parameters resampled to other bands.

        Spectral: linear interpolation between the listed wavelengths, held at the end values
        outside (``docs/formats.md``). RGB: the channels are picked by name.
        """
        p = self.params
        if channels is not None:
            if self.channels is None:
                raise ValueError(f"material {self.name!r} is spectral; data asks for channels {list(channels)}")
            missing = [c for c in channels if c not in self.channels]
            if missing:
                raise ValueError(f"material {self.name!r} has no channel(s) {missing}")
            idx = [self.channels.index(c) for c in channels]
            return _map_bands(p, lambda a: np.asarray(a)[idx])
        if wavelength_nm is None:
            return p
        if self.wavelength_nm is None:
            raise ValueError(f"material {self.name!r} has RGB channels; data asks for wavelengths")
        wl = np.asarray(wavelength_nm, dtype=float)
        src = np.asarray(self.wavelength_nm, dtype=float)

        return _map_bands(p, lambda a: np.interp(wl, src, np.asarray(a, dtype=float)))


def wrong_size(structure: Structure, params: Params, bands: int | None) -> tuple[str, int] | None:
    """(name, number of values) of the first of ``params`` whose size is not what ``structure``
    takes on ``bands`` bands — m and the weights one per lobe, s one, F0, n, k, R_d one per band
    or one for all (``bands`` None: not checked) — or None where every one fits."""
    lobes = structure.lobes if structure.has_specular else None
    for name in ("m", "w"):
        value = getattr(params, name)
        if lobes is not None and value is not None and np.size(value) != lobes:
            return name, int(np.size(value))
    if params.s is not None and np.size(params.s) != 1:
        return "s", int(np.size(params.s))
    for name in _SPECTRAL_FIELDS:
        value = getattr(params, name)
        if bands is not None and value is not None and np.size(value) not in (1, bands):
            return name, int(np.size(value))
    return None


def _map_bands(p: Params, fn: Callable[[Array], Array | np.ndarray]) -> Params:
    """Apply ``fn`` to every per-band (non-scalar) spectral field of ``p``."""
    out = {}
    for f in _SPECTRAL_FIELDS:
        a = getattr(p, f)
        out[f] = a if a is None or np.ndim(a) == 0 else fn(a)
    return Params(s=p.s, m=p.m, w=p.w, **out)
