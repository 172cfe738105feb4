"""What every command reads first: JAX's set-up, material files, measurements, wavelength lists."""

from __future__ import annotations

from pathlib import Path

from .messages import UserError

__all__ = ["PARAM_OUT_HELP", "load_material_file", "output_file", "parse_wavelengths", "read_data", "setup_jax"]


def setup_jax(float32: bool = False):
    import jax

    if not float32:
        jax.config.update("jax_enable_x64", True)
    from .._runtime import enable_compilation_cache

    enable_compilation_cache()


def output_file(value: str | None, option: str = "-o") -> Path | None:
    """An output option that names one file, as a path; one that ends with a slash (a folder) is refused."""
    import os

    if value is None:
        return None
    if value.endswith(("/", os.sep)):
        raise UserError(f"{option} {value}: ends with '/', so it names a folder; give a file name")
    return Path(value)


def load_material_file(path: Path):
    from .._io import load_material

    return load_material(path)


def read_data(path: Path, param_out: str | None = None):
    """Read a measurement (once); ``--param-out`` serves only an ALTA file without its own #PARAM_OUT line."""
    from .._fitting import read_input

    return read_input(path, param_out)


PARAM_OUT_HELP = "ALTA files without a #PARAM_OUT line: the unit of their values (INV_STERADIAN or INV_STERADIAN_COSINE_FACTOR)."


def parse_wavelengths(text: str | None):
    import numpy as np

    if text is None:
        return None
    try:
        if ":" in text:
            parts = [float(x) for x in text.split(":")]
            if len(parts) != 3 or parts[2] <= 0:
                raise ValueError
            return np.arange(parts[0], parts[1] + 0.5 * parts[2], parts[2])
        return np.array([float(x) for x in text.split(",") if x.strip()])
    except ValueError:
        raise UserError(f"--wavelengths: expected START:STOP:STEP or a comma-separated list, got {text!r}") from None
