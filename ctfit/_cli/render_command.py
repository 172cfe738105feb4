"""The body of ``ctfit render``: materials → a labelled PNG grid, or a fit beside its measurement.

The typer command ``ctfit render`` (``ctfit/_cli``) parses the options and calls :func:`render_command_body`;
this module holds no CLI framework code, and imports nothing heavy at import time.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["render_command_body", "MAX_AMBIENT"]

_MAX_SIZE = 4096
MAX_AMBIENT = 1e6
"""The largest ``--ambient``: a million times the lights' irradiance hides them; 10³⁰⁰ overflowed the
image's float32 into a black sphere."""


def render_command_body(
    materials: list[Path],
    output: Path,
    size: int = 256,
    shape: str = "sphere",
    compare: Path | None = None,
    labels: bool = True,
    *,
    columns: int | None = None,
    wavelength_step: float = 5.0,
    supersample: int = 2,
    ambient: float = 0.01,
    exposure: str = "reference",
    delta_e: bool = False,
) -> dict:
    """Render ``materials`` (TOML or fit-result JSON) to the PNG ``output``; return a summary.

    Without ``compare``: one tile per material (:func:`ctfit.render_materials`). With
    ``compare`` (a measurement file): exactly one material, shown beside the nearest-measured
    rendering of the data (:func:`ctfit.render_compare`); with ``delta_e`` as well, the figure
    measured (interpolated) | fitted | ΔE2000 instead (:func:`ctfit.render_comparison`; no ambient
    light, ``size`` pixels per sphere). ``output`` is checked before the
    rendering (:func:`ctfit._io.output_paths.check_output`). Bad input raises ``ValueError``
    (or :class:`ctfit.MaterialError`, :class:`ctfit.DataError`, both ``ValueError``s) with a
    message naming the file or option.

    The summary: ``{"output", "materials", "shape", "size", "image_shape", "compare", "delta_e"}``;
    ``delta_e`` is None, or ``{"median", "p95", "coverage"}`` (ΔE2000 over the sphere, the
    fraction of the lit sphere inside the measured domain).
    """
    from .._io import check_output
    from .._render import EXPOSURES, SHAPES, check_wavelength_step, render_compare, render_materials, save_png
    from .inputs import load_coloured_material, material_inputs

    if not materials:
        raise ValueError("give at least one material file")
    if shape not in SHAPES:
        raise ValueError(f"--shape must be one of {list(SHAPES)}, got {shape!r}")
    if exposure not in EXPOSURES:
        raise ValueError(f"--exposure must be one of {list(EXPOSURES)}, got {exposure!r}")
    if not 8 <= size <= _MAX_SIZE:
        raise ValueError(f"--size must be in 8..{_MAX_SIZE} pixels, got {size}")
    if not 1 <= supersample <= 8:
        raise ValueError(f"--supersample must be in 1..8, got {supersample}")
    if not 0 <= ambient <= MAX_AMBIENT:
        raise ValueError(f"--ambient must be a finite fraction in [0, {MAX_AMBIENT:g}] (of the lights' irradiance), got {ambient}")
    check_wavelength_step(wavelength_step)  # its message names --step (messages.cli_message)
    if columns is not None and columns < 1:
        raise ValueError(f"--columns must be ≥ 1, got {columns}")
    if delta_e and compare is None:
        raise ValueError("--delta-e shows a material beside its measurement: give the measurement with --compare DATA")
    if Path(output).suffix.lower() != ".png":
        raise ValueError(f"{output}: the output is a PNG file; give a name ending in .png")
    check_output(output, [*material_inputs(*materials), compare])
    mats = [load_coloured_material(p) for p in materials]
    options = {"supersample": supersample, "ambient": ambient}
    if compare is not None:
        if len(mats) != 1:
            raise ValueError(f"--compare shows one material beside its data; got {len(mats)} materials")
        from .._io import read_measurement

        data = read_measurement(compare)
        if delta_e:
            return _delta_e_figure(mats[0], data, output, size, shape, supersample, exposure, [materials, compare])
        image = render_compare(mats[0], data, size, shape, None if labels else False, exposure=exposure, **options)
    else:
        image = render_materials(
            mats, size, shape, None if labels else False, columns=columns, exposure=exposure,
            wavelength_step=wavelength_step, **options,
        )  # fmt: skip
    save_png(image, output)
    return {
        "output": str(output),
        "materials": [str(p) for p in materials],
        "shape": shape,
        "size": size,
        "image_shape": list(image.shape),
        "compare": None if compare is None else str(compare),
        "delta_e": None,
    }


def _delta_e_figure(material, data, output, size, shape, supersample, exposure, inputs) -> dict:
    """``--compare DATA --delta-e``: the measured | fitted | ΔE2000 figure, and its summary."""
    from .._render import render_comparison

    result = render_comparison(material, data, output, size=size, shape=shape, supersample=supersample, exposure=exposure)
    width, height = (int(round(v * 110)) for v in result.figure.get_size_inches())
    materials, compare = inputs
    return {
        "output": str(output),
        "materials": [str(p) for p in materials],
        "shape": shape,
        "size": size,
        "image_shape": [height, width, 4],
        "compare": str(compare),
        "delta_e": {"median": result.median, "p95": result.p95, "coverage": result.coverage},
    }
