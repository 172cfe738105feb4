"""Material files: TOML configs and fit-result JSON to and from :class:`~ctfit.Material`.

The format is documented in ``docs/formats.md`` ("Material file (TOML) and fit result
(JSON)"). ctfit extends it with:

- ``fresnel = "f0" | "n" | "conductor"``: which Fresnel quantity is the parameter (inferred
  when absent: ``k`` given → conductor, else ``F0`` → f0, else ``n``); results always say it.
- ``optical_constants = "Cu"``: wavelengths, n, k and F0 from a table that ships with ctfit,
  or ``"path/to/table.csv"``, an optical constants CSV in the file's folder or below it, or in
  a folder of ``$CTFIT_OPTICAL_CONSTANTS`` (see :func:`read_optical_constants`); no other file
  is read. Fresnel is then "conductor" unless ``fresnel`` says otherwise.
- ``channels = ["R", "G", "B"]`` in place of ``wavelength_nm`` for RGB materials.
- ``F0``, ``n``, ``k`` may be single numbers, meaning the same value in every band.
- ``family = "metal" | "plastic"`` (default metal): a plastic has one real index ``n`` for every
  band and a diffuse part ``Rd`` of its own; with it, ``diffuse = "lambertian" | "transmitted"``
  (default lambertian) says whether ``Rd`` is seen through the dielectric interface
  (:func:`~ctfit.transmitted_diffuse_factor`).
- ``name``; every other key (``fit``, ``uncertainty``, ...) is kept in ``Material.meta`` and
  written back unchanged. A key that looks like a misspelt model key is an error.

Every problem raises :class:`MaterialError` naming the file, and the key (``lobes[1].weight``)
or the line and column of a syntax error.
"""

from __future__ import annotations

import datetime
import difflib
import functools
import math
import os
import pathlib
import re
import tomllib
from collections.abc import Sequence
from typing import Any

import msgspec
import numpy as np
from jaxtyping import ArrayLike

from .._model import (
    DISTRIBUTIONS,
    FRESNELS,
    GEOMETRIES,
    MAX_LOBES,
    NORMALIZATIONS,
    PUBLIC_NAMES,
    Material,
    Params,
    Structure,
    f0_from_n,
    f0_from_nk,
    n_from_f0,
    value_domain,
)
from .errors import MaterialError
from .files import atomic_write
from .optical_constants import TABLE_FOLDERS, is_table_name, read_material_text, read_optical_constants, table_folders, table_names
from .untrusted import check_nesting, parse_json, quote, shorten, too_deep, too_many_digits, valid_text

__all__ = ["load_material", "material_file_inputs", "material_from_dict", "material_to_dict", "material_json", "save_material_json", "float_list", "jsonable"]

_TOL = 1e-9
_WEIGHT_ROUNDING = 1e-6
"""Lobe weights that sum to 1 within this (float32 rounding) are renormalised when saved; others are refused."""
_MODEL_KEYS = (
    "name", "s", "d", "lobes", "distribution", "geometry", "normalization", "fresnel",
    "wavelength_nm", "channels", "optical_constants", "F0", "n", "k", "Rd", "band_unknown", "family", "diffuse",
)  # fmt: skip
_DIFFUSE_FORMS = ("lambertian", "transmitted")
_FRESNEL_KEYS = {"f0": ("F0",), "n": ("n",), "conductor": ("n", "k")}


def _toml_position(err: tomllib.TOMLDecodeError, text: str) -> tuple[int, int, str]:
    """Line, column and message of a TOML syntax error (attributes only from Python 3.14)."""
    msg = err.args[0] if err.args else str(err)
    lineno, colno = getattr(err, "lineno", None), getattr(err, "colno", None)
    if lineno is not None and colno is not None:
        return lineno, colno, getattr(err, "msg", msg)
    found = re.search(r"\s*\(at line (\d+), column (\d+)\)$", msg)
    if found:
        return int(found[1]), int(found[2]), msg[: found.start()]
    lines = text.split("\n")
    return len(lines), len(lines[-1]) + 1, re.sub(r"\s*\(at end of document\)$", "", msg)


def _given_twice(msg: str, text: str, line: int) -> str:
    """The key that a TOML "Cannot overwrite a value" (or "Cannot declare … twice") error is about,
    from its line: ``" (key 'name' given twice)"``, or nothing where the line holds no key."""
    if not msg.startswith(("Cannot overwrite", "Cannot declare")):
        return ""
    lines = text.split("\n")
    found = re.match(r"\s*\[*\s*([^=\]\[]+?)\s*(=|\])", lines[line - 1]) if 0 < line <= len(lines) else None
    return f" (key {found[1]!r} given twice)" if found else ""


def _read_document(path: pathlib.Path) -> dict:
    suffix = path.suffix.lower()
    if suffix not in (".toml", ".json"):
        raise MaterialError(f"{path}: unknown material file type {suffix!r}; expected .toml or .json")
    text = read_material_text(path)
    if suffix == ".json":
        try:
            data = parse_json(text, path)
        except ValueError as err:
            raise MaterialError(str(err)) from None
    else:
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as err:
            line, col, msg = _toml_position(err, text)
            raise MaterialError(f"{path}:{line}:{col}: TOML syntax error: {msg}{_given_twice(msg, text, line)}") from None
        except RecursionError:
            raise MaterialError(too_deep(path)) from None
        except ValueError:  # int() past sys.get_int_max_str_digits()
            raise MaterialError(too_many_digits(path)) from None
        except MemoryError:
            raise MaterialError(f"{path}: too large to read into memory") from None
        try:
            check_nesting(data, path)  # a deep note would fail where the material is written back
        except ValueError as err:
            raise MaterialError(str(err)) from None
    if not isinstance(data, dict):
        raise MaterialError(f"{path}: the top level must be a JSON object, got {type(data).__name__}")
    return data


def load_material(path: str | os.PathLike[str]) -> Material:
    """Load a material from a TOML config or a fit-result JSON file (chosen by the suffix).

    >>> import pathlib
    >>> _ = pathlib.Path("plastic.toml").write_text('''
    ... name = "plastic"
    ... s = 0.2
    ... lobes = [{ m = 0.15 }]
    ... wavelength_nm = [450, 550, 650]
    ... F0 = 0.04
    ... Rd = [0.05, 0.1, 0.3]
    ... ''')
    >>> m = load_material("plastic.toml")
    >>> m.name, m.structure.lobes, m.structure.fresnel, m.structure.diffuse
    ('plastic', 1, 'f0', 'spectrum')
    """
    path = pathlib.Path(path)
    data = _read_document(path)
    return material_from_dict(data, source=str(path), base_dir=path.parent, default_name=path.stem)


def material_file_inputs(path: str | os.PathLike[str]) -> list[pathlib.Path]:
    r"""The files that loading the material file ``path`` reads: the file itself and, where its
    ``optical_constants`` names a CSV (not a table that ships with ctfit), that CSV where
    :func:`load_material` finds it. What a command counts as its inputs, which no output of it may
    replace. Only a regular file is read here (a pipe is read once, by the load); a document that
    cannot be read, or whose table cannot be found, gives the file alone (loading it says why).

    >>> import pathlib
    >>> _ = pathlib.Path("oc.csv").write_text("wavelength_nm,n,k\n400,1.2,2.1\n700,0.3,4.0\n")
    >>> _ = pathlib.Path("local.toml").write_text('s = 1\nlobes = [{ m = 0.2 }]\noptical_constants = "oc.csv"\n')
    >>> [p.name for p in material_file_inputs("local.toml")]
    ['local.toml', 'oc.csv']
    """
    path = pathlib.Path(path)
    if not path.is_file():
        return [path]
    try:
        data = _read_document(path)
        name = data.get("optical_constants") if isinstance(data, dict) else None
        where = _Parser(data, str(path), path.parent).resolve(name) if isinstance(name, str) else None  # the loader's own lookup
    except (ValueError, OSError):  # MaterialError is a ValueError
        where = None
    return [path, where] if isinstance(where, pathlib.Path) else [path]  # a shipped table's name is no file of the user's


# --- validation ---------------------------------------------------------------------------------


def _is_number(v: object) -> bool:
    """A number of a document: Python's or NumPy's (a dict made in a notebook), not a bool."""
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


@functools.lru_cache(maxsize=256)
def _close_model_key(key: str) -> str | None:
    """The model key that ``key`` is likely a misspelling of (a document's other keys, such as a
    fit's ``fit`` and ``data``, are looked up again in every document read back)."""
    return next(iter(difflib.get_close_matches(key, _MODEL_KEYS, 1, 0.8)), None)


class _Parser:
    """Turns the keys of one material document into a Material; errors name source and key."""

    def __init__(self, data: dict, source: str, base_dir: str | os.PathLike[str] | None) -> None:
        self.data, self.source, self.base_dir = data, source, base_dir

    def error(self, key: str, msg: str) -> MaterialError:
        return MaterialError(f"{self.source}: key '{shorten(key)}': {msg}")

    def number(self, value: Any, key: str, lo: float = -math.inf, hi: float = math.inf, lo_open: bool = False) -> float:
        if not _is_number(value):
            raise self.error(key, f"must be a number, got {quote(value)}")
        try:
            x = float(value)
        except OverflowError:  # an int past float's range (a document made in Python)
            x = math.inf if value > 0 else -math.inf
        if not math.isfinite(x) or x < lo or x > hi or (lo_open and x == lo):
            lo_txt = f"({lo:g}" if lo_open else f"[{lo:g}"
            raise self.error(key, f"{x!r} is outside {lo_txt}, {hi:g}]")
        return x

    def numbers(self, values: list, key: str, lo: float = -math.inf, hi: float = math.inf, lo_open: bool = False,
                allow_null: bool = False) -> np.ndarray:
        """A list of :meth:`number` (``allow_null``: None is NaN) as an array; its errors name
        ``key[i]``. Plain ints and floats in range are checked at once (a fit's document has
        some hundred of them); anything else goes through :meth:`number`, which says what is wrong."""
        if values and all(type(v) is float or type(v) is int for v in values):
            try:
                out = np.array(values, dtype=float)
            except OverflowError:  # an int beyond float: number() says so
                out = np.full(1, np.nan)
            inside = (out >= lo) & (out <= hi) & np.isfinite(out)
            if lo_open:
                inside &= out != lo
            if bool(np.all(inside)):
                return out
        return np.asarray(
            [math.nan if v is None and allow_null else self.number(v, f"{key}[{i}]", lo, hi, lo_open) for i, v in enumerate(values)],
            dtype=float,
        )

    def choice(self, key: str, allowed: Sequence[Any], default: Any) -> Any:
        value = self.data.get(key, default)
        if value not in allowed:
            raise self.error(key, f"must be one of {list(allowed)}, got {quote(value)}")
        return value

    def meta(self) -> dict:
        meta = {}
        lowered = {k.lower(): k for k in _MODEL_KEYS}
        for key, value in self.data.items():
            if key in _MODEL_KEYS:
                continue
            close = lowered.get(key.lower()) or _close_model_key(key)
            if close:
                raise self.error(key, f"unknown key; did you mean '{close}'?")
            if key == "fixed" and not (isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value)):
                raise self.error(key, f"must be a list of parameter names (fixed = [\"m\", \"s\"]), got {quote(value)}")
            meta[key] = value
        return meta

    def fractions(self) -> tuple[float, float]:
        has_s, has_d = "s" in self.data, "d" in self.data
        if not (has_s or has_d):
            raise self.error("s", "missing: give the specular and diffuse fractions s and d (s + d = 1)")
        s = self.number(self.data["s"], "s", *value_domain("s")) if has_s else None
        d = self.number(self.data["d"], "d", *value_domain("s")) if has_d else None  # d = 1 − s
        if s is not None and d is not None and abs(s + d - 1) > _TOL:
            raise self.error("d", f"s + d = {s + d:.12g}, must be 1")
        if s is not None:
            return s, 1 - s
        assert d is not None  # has_s or has_d
        return 1 - d, d

    def lobes(self, s: float) -> tuple[list[float], list[float]]:
        raw = self.data.get("lobes", [])
        if not isinstance(raw, list):
            raise self.error("lobes", "must be a list of tables {m = ..., weight = ...}")
        if s == 0:
            if raw:
                raise self.error("lobes", "must be absent or empty when s = 0 (no specular part)")
            return [], []
        if not raw:
            raise self.error("lobes", "missing: s > 0 needs at least one lobe {m = ..., weight = ...}")
        if len(raw) > MAX_LOBES:
            raise self.error("lobes", f"{len(raw)} lobes, at most {MAX_LOBES} are supported")
        ms, ws = [], []
        for j, lobe in enumerate(raw):
            key = f"lobes[{j}]"
            if not isinstance(lobe, dict):
                raise self.error(key, f"must be a table {{m = ..., weight = ...}}, got {quote(lobe)}")
            for extra in sorted(set(lobe) - {"m", "weight"}):
                raise self.error(f"{key}.{extra}", "unknown key; a lobe has 'm' and 'weight'")
            if "m" not in lobe:
                raise self.error(f"{key}.m", "missing: the rms slope m of the lobe")
            ms.append(self.number(lobe["m"], f"{key}.m", *value_domain("m")))
            if "weight" not in lobe and len(raw) > 1:
                raise self.error(f"{key}.weight", "missing: every lobe of several needs a weight")
            ws.append(self.number(lobe.get("weight", 1.0), f"{key}.weight", *value_domain("w")))
        total = math.fsum(ws)
        if abs(total - 1) > _TOL:
            raise self.error(f"lobes[{len(ws) - 1}].weight", f"weights sum to {total:.12g}, must sum to 1")
        order = sorted(range(len(ms)), key=ms.__getitem__)  # results list lobes in ascending m
        return [ms[j] for j in order], [ws[j] for j in order]

    def resolve(self, name: str) -> str | pathlib.Path:
        """A table's name, or the real path of an optical constants CSV in the material file's
        folder (below it, or the working directory's without one) or in a folder of
        :data:`~ctfit._io.optical_constants.TABLE_FOLDERS` (``docs/formats.md``)."""
        if is_table_name(name):
            return name
        if not name.lower().endswith(".csv"):
            raise self.error("optical_constants", f"{quote(name)} is neither the name of a table that ships with ctfit "
                             f"({', '.join(table_names())}) nor the path of an optical constants CSV (.csv)")
        folders = [pathlib.Path(self.base_dir if self.base_dir is not None else pathlib.Path.cwd()), *table_folders()]
        inside = False
        for folder in folders:
            real, top = pathlib.Path(os.path.realpath(folder / name)), pathlib.Path(os.path.realpath(folder))
            if real.is_relative_to(top):
                inside = True
                if real.is_file():
                    return real
        if not inside:
            raise self.error("optical_constants", f"{quote(name)} is outside the material file's folder; an optical constants "
                             f"CSV must be in that folder (or below it) or in a folder listed in ${TABLE_FOLDERS}")
        looked = " or ".join(str(f / name) for f in folders)
        raise self.error("optical_constants", f"no file {quote(name)} (looked for {shorten(looked, 400)}); ctfit ships {', '.join(table_names())}")

    def bands(self) -> tuple[np.ndarray | None, tuple[str, ...] | None, str | None, dict | None]:
        """(wavelength_nm, channels, band key, optical constants table or None)."""
        given = [k for k in ("wavelength_nm", "channels", "optical_constants") if k in self.data]
        if not given:
            raise self.error("wavelength_nm", "missing: give wavelength_nm, channels or optical_constants")
        if len(given) > 1:
            raise self.error(given[1], f"give only one of {given}")
        key, value = given[0], self.data[given[0]]
        if key == "optical_constants":
            if not isinstance(value, str):
                raise self.error(key, f"must be a path (string), got {quote(value)}")
            where = self.resolve(value)
            try:
                table = read_optical_constants(where)
            except MaterialError as err:
                raise self.error(key, str(err)) from None
            return table["wavelength_nm"], None, key, table
        if not isinstance(value, list) or not value:
            raise self.error(key, f"must be a non-empty list, got {quote(value)}")
        if key == "channels":
            for i, c in enumerate(value):
                if not isinstance(c, str) or not c:
                    raise self.error(f"{key}[{i}]", f"must be a channel name, got {quote(c)}")
            if len(set(value)) != len(value):
                raise self.error(key, f"channel names must be unique, got {value}")
            return None, tuple(value), key, None
        wl = self.numbers(value, key, 0, math.inf, lo_open=True)
        if np.any(np.diff(wl) <= 0):
            raise self.error(key, "must be strictly increasing")
        return wl, None, key, None

    def spectrum(
        self, key: str, nbands: int, band_key: str | None, lo: float, hi: float, lo_open: bool = False, allow_null: bool = False
    ) -> np.ndarray:
        """A per-band quantity: a list over the bands, or one number for every band."""
        value = self.data[key]
        if _is_number(value):
            return np.full(nbands, self.number(value, key, lo, hi, lo_open))
        if not isinstance(value, list):
            raise self.error(key, f"must be a number or a list over {band_key}, got {quote(value)}")
        if len(value) != nbands:
            raise self.error(key, f"has {len(value)} values, {band_key} has {nbands}")
        return self.numbers(value, key, lo, hi, lo_open, allow_null)


def material_from_dict(data: dict, *, source: str = "<material>", base_dir: str | os.PathLike[str] | None = None, default_name: str = "") -> Material:
    """Build a Material from the keys of a material document (already parsed TOML/JSON).

    ``source`` names the document in error messages; ``base_dir`` is where a relative
    ``optical_constants`` path is looked up first (default: the working directory).

    >>> glass = material_from_dict({"s": 1, "lobes": [{"m": 0.2}], "channels": ["R", "G", "B"], "n": 1.5})
    >>> glass.structure.fresnel, glass.params.n
    ('n', array([1.5, 1.5, 1.5]))
    >>> try:
    ...     material_from_dict({"s": 1, "lobes": [{"m": 0.2, "weigth": 1}], "F0": 0.5, "wavelength_nm": [550]})
    ... except ValueError as err:  # a MaterialError
    ...     print(err)
    <material>: key 'lobes[0].weigth': unknown key; a lobe has 'm' and 'weight'
    """
    if not isinstance(data, dict):
        raise MaterialError(f"{source}: a material is a table of keys, got {type(data).__name__}")
    p = _Parser(data, source, base_dir)
    meta = p.meta()
    name = data.get("name", default_name)
    if not isinstance(name, str):
        raise p.error("name", f"must be a string, got {quote(name)}")
    s, d = p.fractions()
    ms, ws = p.lobes(s)
    distribution = p.choice("distribution", DISTRIBUTIONS, "beckmann")
    geometry = p.choice("geometry", GEOMETRIES, "v-cavity")
    normalization = p.choice("normalization", NORMALIZATIONS, "normalized")
    wl, channels, band_key, table = p.bands()
    nbands = len(wl) if wl is not None else len(channels or ())
    band_unknown = data.get("band_unknown", False)
    if not isinstance(band_unknown, bool):
        raise p.error("band_unknown", f"must be true or false, got {quote(band_unknown)}")
    if band_unknown and (wl is None or nbands != 1):
        raise p.error("band_unknown", f"true needs exactly one wavelength_nm (a placeholder), got {nbands} {band_key}")

    diffuse, rd = None, None
    if d == 0:
        if data.get("Rd", "F0/pi") != "F0/pi":
            raise p.error("Rd", "not used: d = 0 (no diffuse part)")
    else:
        value = data.get("Rd", "F0/pi")
        if isinstance(value, str):
            if value != "F0/pi":
                raise p.error("Rd", f'must be "F0/pi", a number or a list over {band_key}, got {quote(value)}')
            diffuse = "F0/pi"
        elif _is_number(value):
            diffuse, rd = "constant", np.asarray(p.number(value, "Rd", *value_domain("rd")))
        else:
            diffuse, rd = "spectrum", p.spectrum("Rd", nbands, band_key, *value_domain("rd"))

    family, diffuse, rd = _family(p, diffuse, rd, nbands)
    needed = s > 0 or diffuse in ("F0/pi", "transmitted")  # a Fresnel term in the model
    fresnel, spectral = _fresnel(p, table, needed, nbands, band_key)
    if family == "plastic" and needed:  # (a plastic of s = 0 with a Lambertian R_d has no index to give)
        if fresnel != "n":
            raise p.error("n", f'a plastic has one real index: give n (a number), not fresnel = "{fresnel}"')
        if np.ptp(spectral["n"]) > _TOL * np.max(spectral["n"]):
            raise p.error("n", "a plastic has one real index for every band: give one number")
    structure = Structure(
        lobes=len(ms),
        distribution=distribution,
        geometry=geometry,
        fresnel=fresnel,
        diffuse=diffuse,
        normalization=normalization,
        family=family,
    )
    params = Params(
        s=np.asarray(s) if structure.has_s else None,
        m=np.asarray(ms) if ms else None,
        w=np.asarray(ws) if ms else None,
        rd=rd,
        **spectral,
    )
    return Material(structure, params, wavelength_nm=wl, channels=channels, name=name, meta=meta, band_unknown=band_unknown)


def _family(p: _Parser, diffuse: str | None, rd: Any, nbands: int) -> tuple[str, str | None, Any]:
    """(family, diffuse form, R_d) from the keys ``family`` and ``diffuse`` (a plastic's R_d
    seen through its interface is a spectrum: a single number is repeated over the bands)."""
    family = p.choice("family", ("metal", "plastic"), "metal")
    form = p.choice("diffuse", _DIFFUSE_FORMS, "lambertian")
    if family == "plastic" and diffuse == "F0/pi":
        raise p.error("Rd", 'a plastic\'s diffuse part is its own: give Rd (a number or a spectrum), not "F0/pi"')
    if form == "transmitted":
        if family != "plastic":
            raise p.error("diffuse", '"transmitted" (through a dielectric interface) needs family = "plastic"')
        if diffuse is None:
            raise p.error("diffuse", "not used: d = 0 (no diffuse part)")
        diffuse, rd = "transmitted", np.broadcast_to(rd, (nbands,)).astype(float)
    return family, diffuse, rd


def _fresnel(p: _Parser, table: dict | None, needed: bool, nbands: int, band_key: str | None) -> tuple[str, dict]:
    """The Fresnel form and its per-band parameters ({"f0" | "n" | "k": array})."""
    data = p.data
    keys = [k for k in ("F0", "n", "k") if k in data]
    if not needed:
        for key in keys + (["fresnel"] if "fresnel" in data else []):
            raise p.error(key, 'not used: no specular part (s = 0) and Rd is not "F0/pi"')
        return "f0", {}
    explicit = data.get("fresnel")
    if explicit is not None and explicit not in FRESNELS:
        raise p.error("fresnel", f"must be one of {list(FRESNELS)}, got {quote(explicit)}")
    if table is not None:
        if keys:
            raise p.error(keys[0], "give either optical_constants or F0/n/k, not both")
        mode = explicit or "conductor"
        values = {"F0": table["F0"], "n": table["n"], "k": table["k"]}
    else:
        mode = explicit or ("conductor" if "k" in data else "f0" if "F0" in data else "n" if "n" in data else None)
        if mode is None:
            raise p.error("F0", f"missing: give F0, n, or n and k over {band_key} (or optical_constants)")
        for key in _FRESNEL_KEYS[mode]:
            if key not in data:
                raise p.error(key, f'missing: fresnel = "{mode}" needs {" and ".join(_FRESNEL_KEYS[mode])}')
        if "k" in data and mode != "conductor":
            raise p.error("k", f'only with fresnel = "conductor", not "{mode}"')
        values = {}
        for key in keys:  # a conductor's n may be 0 (a fit on its bound, F0 = 1)
            lo, hi, lo_open = value_domain(key.lower(), mode)
            values[key] = p.spectrum(key, nbands, band_key, lo, hi, lo_open, allow_null=key not in _FRESNEL_KEYS[mode])
        derived = {
            "f0": ("n", lambda: n_from_f0(values["F0"])),
            "n": ("F0", lambda: f0_from_n(values["n"])),
            "conductor": ("F0", lambda: f0_from_nk(values["n"], values["k"])),
        }[mode]
        if derived[0] in values:
            given, expected = values[derived[0]], derived[1]()
            ok = np.isnan(given) | ~np.isfinite(expected) | np.isclose(given, expected, rtol=1e-6, atol=1e-9)
            if not np.all(ok):
                i = int(np.argmin(ok))
                raise p.error(
                    f"{derived[0]}[{i}]",
                    f'{float(given[i])!r} is inconsistent with fresnel = "{mode}" ({float(expected[i])!r} expected)',
                )
    return mode, {key.lower(): values[key] for key in _FRESNEL_KEYS[mode]}


# --- writing ------------------------------------------------------------------------------------


def float_list(a: ArrayLike) -> list[float]:
    return [float(x) for x in np.asarray(a, dtype=float).reshape(-1)]


def jsonable(x: Any) -> Any:
    """Plain Python values for JSON: arrays to lists, non-finite floats to None (null)."""
    if type(x) is float:  # the commonest leaf first (a fit's document holds hundreds)
        return x if math.isfinite(x) else None
    if isinstance(x, np.ndarray) and x.dtype.kind == "f":
        return _finite(x.tolist())
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):  # floats inline (a fit's spectra), the rest by recursion
        return [(v if math.isfinite(v) else None) if type(v) is float else jsonable(v) for v in x]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    if x is None or isinstance(x, str):
        return x
    if isinstance(x, (datetime.date, datetime.time)):
        return x.isoformat()
    if hasattr(x, "__array__"):
        return jsonable(np.asarray(x).tolist())
    raise TypeError(f"cannot write a {type(x).__name__} to a material file")


def _finite(x: Any) -> Any:
    """``ndarray.tolist()`` of a float array with its non-finite numbers None."""
    if isinstance(x, list):
        return [_finite(v) for v in x]
    return x if math.isfinite(x) else None


def material_to_dict(material: Material, extra: dict | None = None) -> dict:
    """The material as a fit-result document (plain JSON-ready values, ``docs/formats.md``).

    Always written: ``name``, ``s``, ``d``, ``distribution``, ``geometry``, ``normalization``,
    the bands, and, when the material has Fresnel parameters, ``fresnel``, ``F0`` and ``n``
    (``k`` for a conductor); lobes in ascending m. A part whose fraction is exactly 0 (s = 0 or
    d = 0, e.g. a fit at its bound) is left out, as the format requires; the BRDF is unchanged.
    ``material.meta`` and then ``extra`` (e.g. ``fit``, ``uncertainty``) follow; they may not
    reuse a model key. Non-finite numbers (fit statistics, the effective index of F0 = 1) become
    null. What is written always reads back (:func:`material_from_dict`): a material whose
    parameters are not finite (a failed fit), or that would not read back for another reason,
    raises :class:`MaterialError` instead.

    >>> glass = material_from_dict({"name": "glass", "s": 1, "lobes": [{"m": 0.2}], "channels": ["R", "G", "B"], "n": 1.5})
    >>> doc = material_to_dict(glass, {"fit": {"converged": True}})
    >>> doc["fresnel"], [round(f, 4) for f in doc["F0"]], doc["fit"]  # F0 = ((n - 1)/(n + 1))²
    ('n', [0.04, 0.04, 0.04], {'converged': True})
    """
    _check_finite(material)
    try:
        material.check_shapes()  # each parameter's length that of its structure and bands: saved, it would be read as another material
    except ValueError as err:
        raise MaterialError(str(err)) from None
    st, p = material.structure, material.params
    out: dict = {"name": material.name}
    s = float(p.s) if st.has_s else (1.0 if st.has_specular else 0.0)
    out["s"], out["d"] = s, 1.0 - s
    specular, diffuse = st.has_specular and s > 0, st.diffuse if s < 1 else None
    if specular:
        m, w = float_list(p.m), float_list(p.w)
        total = math.fsum(w)
        if abs(total - 1) > _WEIGHT_ROUNDING:  # renormalising would change the BRDF: the format asks Σw = 1
            raise MaterialError(f"material {material.name!r}: lobe weights {w} sum to {total:.9g}, not 1")
        if abs(total - 1) > _TOL:  # float32 weights sum to 1 only to ~1e-7; the format asks 1e-9
            w = [x / total for x in w]
        out["lobes"] = [{"m": m[j], "weight": w[j]} for j in sorted(range(len(m)), key=m.__getitem__)]
    out["distribution"], out["geometry"], out["normalization"] = st.distribution, st.geometry, st.normalization
    if st.family == "plastic":
        out["family"] = "plastic"
    if material.channels is not None:
        out["channels"] = list(material.channels)
    elif material.wavelength_nm is not None:
        out["wavelength_nm"] = float_list(material.wavelength_nm)
    else:
        raise MaterialError(f"material {material.name!r} has neither wavelength_nm nor channels")
    if material.band_unknown:
        out["band_unknown"] = True
    if specular or diffuse in ("F0/pi", "transmitted"):
        out["fresnel"] = st.fresnel
        if st.fresnel == "f0":
            f0 = np.asarray(p.f0, dtype=float)
            out["F0"], out["n"] = float_list(f0), float_list(n_from_f0(f0))
        else:
            n = np.asarray(p.n, dtype=float)
            k = np.asarray(p.k, dtype=float) if st.fresnel == "conductor" else None
            out["F0"] = float_list(f0_from_n(n) if k is None else f0_from_nk(n, k))
            out["n"] = float_list(n)
            if st.shared_index:  # a plastic's one index: one number
                out["F0"], out["n"] = out["F0"][0], out["n"][0]
            if k is not None:
                out["k"] = float_list(k)
    if diffuse == "F0/pi":
        out["Rd"] = "F0/pi"
    elif diffuse == "constant":
        out["Rd"] = float(p.rd)
    elif diffuse in ("spectrum", "transmitted"):
        out["Rd"] = float_list(p.rd)
        if diffuse == "transmitted":
            out["diffuse"] = "transmitted"
    for key, value in {**material.meta, **(extra or {})}.items():
        if key in _MODEL_KEYS:
            raise MaterialError(f"material {material.name!r}: extra key {key!r} would replace a model key")
        out[key] = value
    out = jsonable(out)
    try:
        material_from_dict(out, source=f"material {material.name!r}")
    except MaterialError as err:
        raise MaterialError(f"{err} (while saving: the document would not read back)") from None
    return out


def _check_finite(material: Material) -> None:
    """A parameter that is not finite (a fit that failed) has no material document."""
    st = material.structure
    fresnel = {"f0": ("f0",), "n": ("n",), "conductor": ("n", "k")}[st.fresnel] if st.needs_fresnel_params else ()
    for name, public in PUBLIC_NAMES.items():
        key = f"lobes[].{public}" if name in ("m", "w") else public
        value = getattr(material.params, name) if name in ("s", "m", "w", "rd") or name in fresnel else None
        if value is not None and not np.all(np.isfinite(np.asarray(value, dtype=float))):
            raise MaterialError(
                f"material {material.name!r}: parameter {key} is not finite ({float_list(value)}): the fit failed, "
                "there is no material to save"
            )


def save_material_json(material: Material, path: str | os.PathLike[str], extra: dict | None = None) -> pathlib.Path:
    """Write :func:`material_to_dict` as JSON atomically (:func:`~ctfit._io.files.atomic_write`).

    >>> glass = material_from_dict({"name": "glass", "s": 1, "lobes": [{"m": 0.2}], "channels": ["R", "G", "B"], "n": 1.5})
    >>> path = save_material_json(glass, "glass.json")  # relative to the working directory
    >>> load_material(path).params.n
    array([1.5, 1.5, 1.5])
    """
    path = pathlib.Path(path)
    atomic_write(path, [material_json(material_to_dict(material, extra))])
    return path


def material_json(doc: dict) -> str:
    """The text :func:`save_material_json` writes for ``doc`` (a :func:`material_to_dict`): JSON
    indented by 2, UTF-8 characters as they are, a number that is not finite as null (as
    ``material_to_dict`` makes them).

    msgspec encodes it: ``json.dumps`` with an indent runs Python's own encoder, 0.33 ms for a fit of
    31 bands against 0.02 ms. Each float has the fewest significant digits that read back to it, as
    ``json.dumps`` writes it, in msgspec's form (``0.00001``, ``1.5e-7``, ``1e16``; ``json.dumps``
    writes ``1e-05``, ``1.5e-07``, ``1e+16``).

    >>> print(material_json({"name": "glass", "s": 1.0, "F0": [0.04, 2.5e-05], "fit": {"warnings": []}}), end="")
    {
      "name": "glass",
      "s": 1.0,
      "F0": [
        0.04,
        0.000025
      ],
      "fit": {
        "warnings": []
      }
    }
    """
    try:
        raw = msgspec.json.encode(doc, enc_hook=_plain_scalar)
    except UnicodeEncodeError:  # a lone surrogate: the name of a file that is not UTF-8, as Python decodes it
        raw = msgspec.json.encode(valid_text(doc), enc_hook=_plain_scalar)
    return msgspec.json.format(raw, indent=2).decode() + "\n"


def _plain_scalar(value: Any) -> Any:
    """A NumPy scalar as the Python number msgspec encodes (else msgspec's own TypeError)."""
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot write a {type(value).__name__} to a material file")
