"""``export_material``: a fitted material in a renderer's own terms, with how far it is from the fit."""

from __future__ import annotations

import dataclasses
import json
import os

import numpy as np

from .._io import atomic_write, write_merl
from .._model import Material, evaluate_at
from .error_grid import ERROR_GRID, error_grid_angles, relative_difference
from .gltf import gltf_brdf, gltf_material
from .merl_export import merl_lookup, merl_model_table
from .mitsuba import mitsuba_bsdf, mitsuba_target, mitsuba_values, mitsuba_xml, roughplastic_bsdf
from .rgb_bands import GAMUT_NOTE, band_to_rgb, in_rgb_order, rgb_material

__all__ = ["EXPORT_FORMATS", "MITSUBA_COLOURS", "ExportResult", "export_material"]

EXPORT_FORMATS = ("mitsuba", "mitsuba-dict", "merl", "gltf")
"""What :func:`export_material` writes: Mitsuba 3 XML, the same as JSON for ``mi.load_dict``, a MERL ``.binary`` table, a glTF 2.0 material."""

MITSUBA_COLOURS = ("spectrum", "rgb")
"""How :func:`export_material` writes a spectral material for Mitsuba: spectra (its ``*_spectral`` variants) or linear-sRGB colours (its RGB variants)."""


@dataclasses.dataclass(frozen=True, eq=False)
class ExportResult:
    """An exported material: ``content`` (XML or JSON text, or the (3, 90, 90, 180) MERL table),
    and its ``error`` — ``median`` and ``max`` relative difference of the BRDF over the grid of
    :data:`ERROR_GRID`, ``exact`` and ``approximations`` (what the target cannot express); ``note``:
    where the figures hold, if not everywhere (a Mitsuba export of spectra: its spectral variants).

    Examples
    --------
    >>> import numpy as np, ctfit
    >>> matte = ctfit.Material(ctfit.Structure(lobes=0, diffuse="constant"), ctfit.Params(rd=np.array(0.1)), wavelength_nm=np.array([550.0]))
    >>> result = ctfit.export_material(matte, to="mitsuba")
    >>> result.error["exact"], result.line().split(":")[0]
    (True, 'mitsuba')
    """

    format: str
    content: object
    error: dict
    note: str = ""

    def line(self) -> str:
        """The approximation error in one line, as ``ctfit export`` prints it (and ``note``, where there is one)."""
        e = self.error
        kind = "exact" if e["exact"] else "approximate (" + "; ".join(e["approximations"]) + ")"
        counted = f", {e['compared']:,} of its {e['values']:,} values above that floor" if e.get("compared", 0) < e.get("values", 0) else ""
        return (f"{self.format}: {kind}: median {100 * e['median']:.3g} %, max {100 * e['max']:.3g} % relative "
                f"difference of the BRDF over {e['grid']}{counted}" + (f"; {self.note}" if self.note else ""))

    def write(self, path: str | os.PathLike[str]) -> None:
        """Write the export to ``path`` atomically."""
        if self.format == "merl":
            write_merl(path, self.content)
        else:
            atomic_write(path, [self.content])


def _grid_values(material: Material) -> np.ndarray:
    ti, pi, to, po = error_grid_angles()
    return np.asarray(evaluate_at(material, theta_i=ti, phi_i=pi, theta_o=to, phi_o=po), float)


def _mitsuba_approximations(material: Material) -> list[str]:
    st, notes = material.structure, []
    if st.has_specular and st.geometry != "smith-rational":
        notes.append(f"Mitsuba's G is Smith's rational G1, not the {st.geometry} G")
    if st.has_specular and st.distribution != "beckmann":
        notes.append("Mitsuba has no Gaussian D: Beckmann with alpha = m")
    target = mitsuba_target(material)
    for name in ("f0", "rd"):
        ours, theirs = getattr(material.params, name), getattr(target.params, name)
        if ours is not None and not np.array_equal(np.asarray(ours), np.asarray(theirs)):
            notes.append(f"{'F0 ≤ 1 − 1e-6' if name == 'f0' else 'RGB reflectance ≤ 1 (R_d ≤ 1/π)'}")
    return notes


def _error(fit: np.ndarray, target: np.ndarray, approximations: list[str], material: Material) -> dict:
    return {**relative_difference(target, fit, _diffuse_peak(material)), "exact": not approximations, "approximations": approximations, "grid": ERROR_GRID}


def _diffuse_peak(material: Material) -> float:
    """The largest value on the grid of the material's diffuse part, d·R_d (0 without one, or
    where all of it is diffuse: the fit's own largest value then counts)."""
    st, params = material.structure, material.params
    if st.diffuse is None or not st.has_specular or params.s is None:
        return 0.0
    matte = dataclasses.replace(material, params=dataclasses.replace(params, s=np.zeros_like(np.asarray(params.s, float))))  # R_d alone
    return (1 - float(params.s)) * float(np.max(_grid_values(matte)))


def _export_mitsuba(material: Material, to: str, plastic: str, colour: str) -> ExportResult:
    source, notes = rgb_material(material) if colour == "rgb" else (material, [])
    fit = _grid_values(material) @ band_to_rgb(material) if source is not material else _grid_values(material)  # colours: the fit's colour
    if plastic == "roughplastic":
        tree = roughplastic_bsdf(source)
        notes = notes + ["Mitsuba's roughplastic: rough transmittance tables in its diffuse term"]
        if source.structure.diffuse in ("spectrum", "constant"):
            notes.append("the Lambertian R_d as roughplastic's transmitted diffuse term of the same albedo")
        notes += [n for n in _mitsuba_approximations(source) if "G1" in n or "Gaussian" in n]
        error = _error(fit, mitsuba_values(tree, source, *error_grid_angles()), notes, material)
    else:
        tree = mitsuba_bsdf(source)
        error = _error(fit, _grid_values(mitsuba_target(source)), notes + _mitsuba_approximations(source), material)
    spectral = "" if source.is_rgb or len(source.wavelength_nm) == 1 else (
        "spectra: figures of Mitsuba's *_spectral variants; its RGB variants take the spectra as colours (for those, export the Mitsuba colours as rgb)")
    if to == "mitsuba-dict":
        return ExportResult(to, json.dumps({"bsdf": tree, "ctfit_export": error}, indent=2, ensure_ascii=False) + "\n", error, spectral)
    result = ExportResult(to, "", error, spectral)
    comments = [f"ctfit export of {material.name or 'a material'} ({material.structure})", result.line()]
    return dataclasses.replace(result, content=mitsuba_xml(tree, comments))


def _export_rgb(material: Material, to: str) -> ExportResult:
    fit = _grid_values(material) @ band_to_rgb(material)
    if to == "merl":
        table, out_of_gamut = merl_model_table(material)
        notes = ["tabulated in 90 × 90 × 180 cells of linear sRGB"] + ([GAMUT_NOTE] if out_of_gamut else [])
        return ExportResult(to, table, _error(fit, merl_lookup(table, *error_grid_angles()), notes, material))
    entry, notes = gltf_material(material)
    notes = ["glTF's GGX D, height-correlated Smith G, Schlick F and linear-sRGB colours"] + notes
    error = _error(fit, gltf_brdf(entry, *error_grid_angles()), notes, material)
    entry["extras"] = {"ctfit_export": error}
    doc = {"asset": {"version": "2.0", "generator": "ctfit export"},
           "extensionsUsed": sorted(entry["extensions"]), "materials": [entry]}
    return ExportResult(to, json.dumps(doc, indent=2, ensure_ascii=False) + "\n", error)


def export_material(
    material: Material, to: str = "mitsuba", path: str | os.PathLike[str] | None = None, *, mitsuba_plastic: str = "exact",
    mitsuba_colour: str = "spectrum",
) -> ExportResult:
    """The material in a renderer's format (:data:`EXPORT_FORMATS`), written to ``path`` if given.

    ``mitsuba_plastic="roughplastic"`` writes a plastic as Mitsuba's ``roughplastic`` (one per
    lobe) instead of the exact ``blendbsdf`` of ``roughconductor`` and ``plastic``; its error is
    measured with Mitsuba 3 itself (needs the ``mitsuba`` package).

    ``mitsuba_colour``: how a spectral material's spectra are written for Mitsuba. "spectrum":
    as ``spectrum`` λ:value lists, exact in Mitsuba's ``*_spectral`` variants (its RGB variants
    convert them as colours, which an effective index near F0 = 1 does not survive). "rgb": as
    linear-sRGB colours for its RGB variants (:func:`~ctfit._export.rgb_bands.rgb_material`), the
    error measured against the fit's colour.

    ``docs/export.md`` has the mapping of each structure to its target, and the grid of the
    approximation error (:data:`~ctfit._export.error_grid.ERROR_GRID`) that the result carries
    (``ExportResult.error``, ``ExportResult.line()``), and writes into the output (an XML
    comment, a JSON field).

    Examples
    --------
    A metal with the paper's V-cavity G becomes a Mitsuba ``roughconductor``, with Smith's G:

    >>> import numpy as np, ctfit
    >>> gold = ctfit.Material(ctfit.Structure(), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.9, 0.7, 0.3])),
    ...                       channels=("R", "G", "B"), name="gold")
    >>> result = ctfit.export_material(gold, to="mitsuba", path="gold.xml")
    >>> result.error["exact"], result.error["approximations"]
    (False, ["Mitsuba's G is Smith's rational G1, not the v-cavity G"])
    >>> import pathlib
    >>> '<bsdf type="roughconductor" version="3.0.0">' in pathlib.Path("gold.xml").read_text()
    True
    """
    if to not in EXPORT_FORMATS:
        raise ValueError(f"unknown export format {to!r}: one of {', '.join(EXPORT_FORMATS)}")
    if mitsuba_plastic not in ("exact", "roughplastic"):
        raise ValueError(f"mitsuba_plastic must be 'exact' or 'roughplastic', got {mitsuba_plastic!r}")
    if mitsuba_colour not in MITSUBA_COLOURS:
        raise ValueError(f"mitsuba_colour must be one of {', '.join(MITSUBA_COLOURS)}, got {mitsuba_colour!r}")
    material = in_rgb_order(material.check_shapes().check_colour_channels())  # channels B, G, R are written as R, G, B
    result = _export_mitsuba(material, to, mitsuba_plastic, mitsuba_colour) if to.startswith("mitsuba") else _export_rgb(material, to)
    if path is not None:
        result.write(path)
    return result
