"""ctfit: fit the Cook–Torrance reflectance model to measured or synthetic BRDF samples, in JAX.

Conventions (angles, directions, normalisation) are stated once in ``docs/conventions.md``.

Public names are loaded on first use (PEP 562), from the subpackage of their concern (each
subpackage's ``__init__`` lists what it exports), so ``import ctfit`` and ``ctfit --version`` do
not pay for importing JAX until a model function is used.
"""

from __future__ import annotations

import importlib
import importlib.metadata
from typing import TYPE_CHECKING

_EXPORTS = {  # public name -> the subpackage that exports it
    "ambient_reflectance": "._model",
    "beckmann": "._model",
    "brdf": "._model",
    "brdf_pairs": "._model",
    "diffuse_reflectance": "._model",
    "direction_from_angles_deg": "._model",
    "evaluate": "._model",
    "evaluate_at": "._model",
    "f0_from_n": "._model",
    "f0_from_nk": "._model",
    "fresnel": "._model",
    "fresnel_conductor": "._model",
    "fresnel_dielectric": "._model",
    "fresnel_dielectric_f0": "._model",
    "gaussian": "._model",
    "Geometry": "._model",
    "geometry": "._model",
    "geometry_from_angles_deg": "._model",
    "goniometer_directions": "._model",
    "Light": "._model",
    "Material": "._model",
    "Measurement": "._model",
    "n_from_f0": "._model",
    "normal_reflectance": "._model",
    "Params": "._model",
    "reflected_intensity": "._model",
    "simulate": "._model",
    "smith_g1_reduced": "._model",
    "specular_constant": "._model",
    "specular_geometric": "._model",
    "Structure": "._model",
    "v_cavity_reduced": "._model",
    "angles_deg_to_half_diff": "._io",
    "DataError": "._io",
    "DataWarning": "._io",
    "half_diff_to_angles_deg": "._io",
    "load_material": "._io",
    "material_from_dict": "._io",
    "material_to_dict": "._io",
    "MaterialError": "._io",
    "merl_table": "._io",
    "read_alta": "._io",
    "read_csv": "._io",
    "read_measurement": "._io",
    "read_merl": "._io",
    "read_optical_constants": "._io",
    "save_material_json": "._io",
    "write_csv": "._io",
    "write_merl": "._io",
    "fit": "._fitting",
    "fit_batch": "._fitting",
    "fit_many": "._fitting",
    "fit_result_to_dict": "._fitting",
    "fit_texel_maps": "._fitting",
    "fit_texels": "._fitting",
    "FitResult": "._fitting",
    "format_fit_table": "._fitting",
    "residual_structure": "._fitting",
    "select_structure": "._fitting",
    "TexelFits": "._fitting",
    "seed_params": "._fitting",
    "read_texel_geometry": "._fitting",
    "ChainTooShortWarning": "._sampling",
    "format_uncertainty_table": "._sampling",
    "plot_corner": "._sampling",
    "plot_spectra": "._sampling",
    "sample": "._sampling",
    "SampleResult": "._sampling",
    "average_normal_reflectance": "._colour",
    "colour_report": "._colour",
    "colour_shift_approximation": "._colour",
    "colour_shift_spectral": "._colour",
    "colour_shift_weight": "._colour",
    "DEFAULT_OBSERVER": "._colour",
    "delta_E_CIE2000": "._colour",
    "desaturate_to_gamut": "._colour",
    "dominant_wavelength": "._colour",
    "encode_RGB": "._colour",
    "eotf_inverse_sRGB": "._colour",
    "excitation_purity": "._colour",
    "fresnel_reflectance_spectrum": "._colour",
    "in_gamut": "._colour",
    "reflectance_spectrum": "._colour",
    "rgb_conversion": "._colour",
    "RGB_to_XYZ": "._colour",
    "RGBConversion": "._colour",
    "scale_to_display": "._colour",
    "spectral_weights": "._colour",
    "SpectralResamplingWarning": "._colour",
    "SpectralWeights": "._colour",
    "spectrum_to_RGB": "._colour",
    "spectrum_to_XYZ": "._colour",
    "srgb_luminance": "._colour",
    "XYZ_to_Lab": "._colour",
    "XYZ_to_RGB": "._colour",
    "XYZ_to_xy": "._colour",
    "render_compare": "._render",
    "render_linear": "._render",
    "render_material": "._render",
    "render_materials": "._render",
    "save_png": "._render",
    "Tile": "._render",
    "tone_map": "._render",
    "enable_compilation_cache": "._runtime",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'ctfit' has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_EXPORTS))


if TYPE_CHECKING:  # for type checkers and IDEs: the same names, eagerly
    from ._model import (
        ambient_reflectance as ambient_reflectance,
        beckmann as beckmann,
        brdf as brdf,
        brdf_pairs as brdf_pairs,
        diffuse_reflectance as diffuse_reflectance,
        direction_from_angles_deg as direction_from_angles_deg,
        evaluate as evaluate,
        evaluate_at as evaluate_at,
        f0_from_n as f0_from_n,
        f0_from_nk as f0_from_nk,
        fresnel as fresnel,
        fresnel_conductor as fresnel_conductor,
        fresnel_dielectric as fresnel_dielectric,
        fresnel_dielectric_f0 as fresnel_dielectric_f0,
        gaussian as gaussian,
        Geometry as Geometry,
        geometry as geometry,
        geometry_from_angles_deg as geometry_from_angles_deg,
        goniometer_directions as goniometer_directions,
        Light as Light,
        Material as Material,
        Measurement as Measurement,
        n_from_f0 as n_from_f0,
        normal_reflectance as normal_reflectance,
        Params as Params,
        reflected_intensity as reflected_intensity,
        simulate as simulate,
        smith_g1_reduced as smith_g1_reduced,
        specular_constant as specular_constant,
        specular_geometric as specular_geometric,
        Structure as Structure,
        v_cavity_reduced as v_cavity_reduced,
    )
    from ._io import (
        angles_deg_to_half_diff as angles_deg_to_half_diff,
        DataError as DataError,
        DataWarning as DataWarning,
        half_diff_to_angles_deg as half_diff_to_angles_deg,
        load_material as load_material,
        material_from_dict as material_from_dict,
        material_to_dict as material_to_dict,
        MaterialError as MaterialError,
        merl_table as merl_table,
        read_alta as read_alta,
        read_csv as read_csv,
        read_measurement as read_measurement,
        read_merl as read_merl,
        read_optical_constants as read_optical_constants,
        save_material_json as save_material_json,
        write_csv as write_csv,
        write_merl as write_merl,
    )
    from ._fitting import (
        fit as fit,
        fit_batch as fit_batch,
        fit_many as fit_many,
        fit_result_to_dict as fit_result_to_dict,
        fit_texel_maps as fit_texel_maps,
        fit_texels as fit_texels,
        FitResult as FitResult,
        format_fit_table as format_fit_table,
        residual_structure as residual_structure,
        select_structure as select_structure,
        TexelFits as TexelFits,
        seed_params as seed_params,
        read_texel_geometry as read_texel_geometry,
    )
    from ._sampling import (
        ChainTooShortWarning as ChainTooShortWarning,
        format_uncertainty_table as format_uncertainty_table,
        plot_corner as plot_corner,
        plot_spectra as plot_spectra,
        sample as sample,
        SampleResult as SampleResult,
    )
    from ._colour import (
        average_normal_reflectance as average_normal_reflectance,
        colour_report as colour_report,
        colour_shift_approximation as colour_shift_approximation,
        colour_shift_spectral as colour_shift_spectral,
        colour_shift_weight as colour_shift_weight,
        DEFAULT_OBSERVER as DEFAULT_OBSERVER,
        delta_E_CIE2000 as delta_E_CIE2000,
        desaturate_to_gamut as desaturate_to_gamut,
        dominant_wavelength as dominant_wavelength,
        encode_RGB as encode_RGB,
        eotf_inverse_sRGB as eotf_inverse_sRGB,
        excitation_purity as excitation_purity,
        fresnel_reflectance_spectrum as fresnel_reflectance_spectrum,
        in_gamut as in_gamut,
        reflectance_spectrum as reflectance_spectrum,
        rgb_conversion as rgb_conversion,
        RGB_to_XYZ as RGB_to_XYZ,
        RGBConversion as RGBConversion,
        scale_to_display as scale_to_display,
        spectral_weights as spectral_weights,
        SpectralResamplingWarning as SpectralResamplingWarning,
        SpectralWeights as SpectralWeights,
        spectrum_to_RGB as spectrum_to_RGB,
        spectrum_to_XYZ as spectrum_to_XYZ,
        srgb_luminance as srgb_luminance,
        XYZ_to_Lab as XYZ_to_Lab,
        XYZ_to_RGB as XYZ_to_RGB,
        XYZ_to_xy as XYZ_to_xy,
    )
    from ._render import (
        render_compare as render_compare,
        render_linear as render_linear,
        render_material as render_material,
        render_materials as render_materials,
        save_png as save_png,
        Tile as Tile,
        tone_map as tone_map,
    )
    from ._runtime import (
        enable_compilation_cache as enable_compilation_cache,
    )

try:
    __version__ = importlib.metadata.version("ctfit")
except importlib.metadata.PackageNotFoundError:  # running from a source tree
    __version__ = "0.0.0"
