"""What every command reads first: JAX's set-up, material files, measurements, wavelength lists."""

from __future__ import annotations

from pathlib import Path
from typing import overload

from .messages import UserError

__all__ = ["PARAM_OUT_HELP", "WAVELENGTHS_HELP", "check_param_out", "data_bands_check", "load_coloured_material", "load_material_file",
           "material_inputs", "output_file", "parse_wavelengths", "read_data", "refuse_dash", "setup_jax"]


def setup_jax(float32: bool = False):
    import jax

    if not float32:
        jax.config.update("jax_enable_x64", True)
    from .._runtime import enable_compilation_cache

    enable_compilation_cache()


@overload
def output_file(value: str, option: str = "-o") -> Path: ...
@overload
def output_file(value: None, option: str = "-o") -> None: ...
@overload
def output_file(value: str | None, option: str = "-o") -> Path | None: ...


def output_file(value: str | None, option: str = "-o") -> Path | None:
    """An output option that names one file, as a path; one that ends with a slash (a folder) is refused."""
    import os

    if value is None:
        return None
    refuse_dash(value, option)
    if value.endswith(("/", os.sep)):
        raise UserError(f"{option} {value}: ends with '/', so it names a folder; give a file name")
    return Path(value)


def refuse_dash(value: str | None, option: str) -> None:
    """Refuse ``-`` as an output: ctfit does not read it as standard output (a file named ``-``
    was written); ``/dev/stdout`` writes there (``docs/formats.md``)."""
    if value is not None and value.strip() == "-":
        raise UserError(f"{option} -: '-' is not standard output to ctfit (a file named '-' would be written); "
                        f"give {option} /dev/stdout to write there, or a file name")


def material_inputs(*paths) -> list:
    """Every file the material files ``paths`` read (None skipped): each file and the optical
    constants CSV it names (:func:`~ctfit._io.material_file_inputs`): inputs no output may replace."""
    from .._io import material_file_inputs

    return [f for p in paths if p is not None for f in material_file_inputs(p)]


def load_material_file(path: Path):
    from .._io import load_material

    return load_material(path)


def load_coloured_material(path: Path):
    """Load a material that ``color``, ``render`` and ``export`` need a colour of: one whose channels
    are not R, G, B is refused naming the file (:meth:`~ctfit.Material.check_colour_channels`)."""
    mat = load_material_file(path)
    try:
        return mat.check_colour_channels()
    except ValueError as e:
        raise UserError(f"{path}: {e}") from None


def data_bands_check(mat, material: Path, meas, data: Path) -> None:
    """Refuse data whose bands the material has no values in — RGB data and a spectral material,
    spectral data and an RGB one, channels it lacks — naming the data file and what to give."""
    if meas.channels is not None:
        if mat.channels is None:
            raise UserError(f"{data}: its bands are the channels {list(meas.channels)} and the material {material} is spectral (wavelengths): "
                            "it has no values in them; give a material with those channels (a fit of RGB data), or data with wavelengths")
        missing = [c for c in meas.channels if c not in mat.channels]
        if missing:
            raise UserError(f"{data}: its channels {missing} are not the material's ({material}: {list(mat.channels)}); "
                            "give a material with every channel of the data")
    elif mat.channels is not None:
        raise UserError(f"{data}: its bands are not channels ({', '.join(meas.band_labels[:3])}{', …' if meas.n_bands > 3 else ''}) and the material "
                        f"{material} has the channels {list(mat.channels)}: it has no values there; give a spectral material, or data with those channels")


def read_data(path: Path, param_out: str | None = None, ahead=None):
    """Read a measurement (once); ``--param-out`` serves only an ALTA file without its own #PARAM_OUT
    line. ``ahead``: a :class:`~ctfit._io.read_ahead.ReadAhead` of ``path`` (its measurement)."""
    from .._fitting import read_input

    check_param_out(param_out)
    if ahead is not None and ahead.path == str(path):
        return ahead.measurement()
    return read_input(path, param_out)


def check_param_out(param_out: str | None) -> None:
    """Refuse a ``--param-out`` that names no unit (it is checked even where no ALTA file uses it)."""
    if param_out is not None and param_out not in PARAM_OUT_UNITS:
        raise UserError(f"--param-out must be one of {', '.join(PARAM_OUT_UNITS)}, got {param_out!r}")


PARAM_OUT_UNITS = ("INV_STERADIAN", "INV_STERADIAN_COSINE_FACTOR", "RGB_COLOR")  # the ALTA reader's (ctfit._io.alta.PARAM_OUT)


PARAM_OUT_HELP = ("ALTA files without a #PARAM_OUT line: the unit of their values (INV_STERADIAN or INV_STERADIAN_COSINE_FACTOR; "
                  "RGB_COLOR for three values a line, R, G, B in sr⁻¹).")


WAVELENGTHS_HELP = ("START:STOP:STEP (START, START+STEP, … up to STOP, never past it: 400:700:7 ends at 694) or a "
                    "comma-separated list, nm, every one > 0 (default: the material's within 400–700).")


_MOST_WAVELENGTHS = 100_000


def parse_wavelengths(text: str | None):
    """The wavelengths of ``--wavelengths``: a START:STOP:STEP range (STOP included where the steps
    land on it, never passed) or a list; each a positive finite number of nm.

    >>> parse_wavelengths("400:700:100").tolist(), float(parse_wavelengths("400:700:7")[-1]), parse_wavelengths("450, 650").tolist()
    ([400.0, 500.0, 600.0, 700.0], 694.0, [450.0, 650.0])
    """
    import numpy as np

    if text is None:
        return None
    try:
        if ":" in text:
            start, stop, step = (float(x) for x in text.split(":"))  # not three: ValueError
            if not (np.isfinite([start, stop, step]).all() and step > 0 and stop >= start):
                raise UserError(f"--wavelengths {text!r}: START:STOP:STEP needs STEP > 0 and STOP ≥ START (finite numbers of nm)")
            q = (stop - start) / step
            if q > _MOST_WAVELENGTHS:
                raise UserError(f"--wavelengths {text!r}: {q + 1:.3g} wavelengths; at most {_MOST_WAVELENGTHS:,} (a larger STEP)")
            values = start + step * np.arange(int(np.floor(q + 1e-9 * max(q, 1.0))) + 1)  # never past STOP (rounding aside)
        else:
            items = text.split(",")
            empty = [i for i, x in enumerate(items, 1) if not x.strip()]
            if empty and len(items) > 1:
                raise UserError(f"--wavelengths {text!r}: item {empty[0]} of {len(items)} is empty; give a wavelength between every two commas")
            values = np.array([float(x) for x in items if x.strip()])
    except ValueError:
        raise UserError(f"--wavelengths: expected START:STOP:STEP or a comma-separated list, got {text!r}") from None
    bad = values[~(np.isfinite(values) & (values > 0))]
    if values.size == 0 or bad.size:
        what = "no wavelength" if values.size == 0 else f"{bad[0]:g} is not a wavelength"
        raise UserError(f"--wavelengths {text!r}: {what}: every wavelength must be a positive number of nm")
    return values
