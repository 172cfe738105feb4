"""ctfit: fit the Cook–Torrance reflectance model to measured or synthetic BRDF samples, in JAX.

Conventions (angles, directions, normalisation) are stated once in ``docs/conventions.md``.

Public names are loaded on first use (PEP 562), so ``import ctfit`` and ``ctfit --version`` do
not pay for importing JAX until a model function is used.
"""

from __future__ import annotations

import importlib
import importlib.metadata
from typing import TYPE_CHECKING

_EXPORTS = {
    "ambient_reflectance": "._brdf",
    "brdf": "._brdf",
    "brdf_pairs": "._brdf",
    "diffuse_reflectance": "._brdf",
    "fresnel": "._brdf",
    "normal_reflectance": "._brdf",
    "specular_constant": "._brdf",
    "specular_geometric": "._brdf",
    "beckmann": "._distribution",
    "gaussian": "._distribution",
    "f0_from_n": "._fresnel",
    "f0_from_nk": "._fresnel",
    "fresnel_conductor": "._fresnel",
    "fresnel_dielectric": "._fresnel",
    "fresnel_dielectric_f0": "._fresnel",
    "n_from_f0": "._fresnel",
    "Geometry": "._geometry",
    "direction_from_angles_deg": "._geometry",
    "geometry": "._geometry",
    "geometry_from_angles_deg": "._geometry",
    "Material": "._material",
    "Params": "._material",
    "Structure": "._material",
    "Measurement": "._measurement",
    "smith_g1_reduced": "._shadowing",
    "v_cavity_reduced": "._shadowing",
    "MaterialError": "._material_io",
    "load_material": "._material_io",
    "material_from_dict": "._material_io",
    "material_to_dict": "._material_io",
    "read_optical_constants": "._material_io",
    "save_material_json": "._material_io",
    "evaluate": "._simulate",
    "evaluate_at": "._simulate",
    "goniometer_directions": "._simulate",
    "simulate": "._simulate",
    "FitResult": "._fit",
    "fit": "._fit",
    "select_structure": "._fit",
    "fit_batch": "._fit_batch",
    "fit_many": "._fit_many",
    "fit_texel_maps": "._texel_maps",
    "TexelFits": "._fit_texels",
    "fit_texels": "._fit_texels",
    "fit_result_to_dict": "._fit_io",
    "format_fit_table": "._fit_io",
    "DEFAULT_OBSERVER": "._colour",
    "RGBConversion": "._colour",
    "RGB_to_XYZ": "._colour",
    "SpectralResamplingWarning": "._colour",
    "SpectralWeights": "._colour",
    "XYZ_to_Lab": "._colour",
    "XYZ_to_RGB": "._colour",
    "XYZ_to_xy": "._colour",
    "delta_E_CIE2000": "._colour",
    "dominant_wavelength": "._colour",
    "encode_RGB": "._colour",
    "eotf_inverse_sRGB": "._colour",
    "excitation_purity": "._colour",
    "rgb_conversion": "._colour",
    "spectral_weights": "._colour",
    "spectrum_to_RGB": "._colour",
    "spectrum_to_XYZ": "._colour",
    "colour_report": "._colour_report",
    "reflectance_spectrum": "._colour_report",
    "average_normal_reflectance": "._colour_shift",
    "colour_shift_approximation": "._colour_shift",
    "colour_shift_spectral": "._colour_shift",
    "colour_shift_weight": "._colour_shift",
    "fresnel_reflectance_spectrum": "._colour_shift",
    "desaturate_to_gamut": "._gamut",
    "in_gamut": "._gamut",
    "scale_to_display": "._gamut",
    "srgb_luminance": "._gamut",
    "read_measurement": "._readers",
    "enable_compilation_cache": "._cache",
    "read_csv": "._csvio",
    "write_csv": "._csvio",
    "DataError": "._errors",
    "read_alta": "._alta",
    "read_merl": "._merl",
    "write_merl": "._merl",
    "merl_table": "._merl",
    "half_diff_to_angles_deg": "._merl",
    "angles_deg_to_half_diff": "._merl",
    "DataWarning": "._errors",
    "residual_structure": "._diagnostics",
    "ChainTooShortWarning": "._sample",
    "SampleResult": "._sample",
    "sample": "._sample",
    "format_uncertainty_table": "._sample_io",
    "plot_corner": "._sample_io",
    "plot_spectra": "._sample_io",
    "Light": "._intensity",
    "reflected_intensity": "._intensity",
    "Tile": "._render",
    "render_compare": "._render",
    "render_linear": "._render",
    "render_material": "._render",
    "render_materials": "._render",
    "save_png": "._render",
    "tone_map": "._render",
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
    from ._cache import enable_compilation_cache as enable_compilation_cache
    from ._brdf import (
        ambient_reflectance as ambient_reflectance,
        brdf as brdf,
        brdf_pairs as brdf_pairs,
        diffuse_reflectance as diffuse_reflectance,
        fresnel as fresnel,
        normal_reflectance as normal_reflectance,
        specular_constant as specular_constant,
        specular_geometric as specular_geometric,
    )
    from ._distribution import (
        beckmann as beckmann,
        gaussian as gaussian,
    )
    from ._fresnel import (
        f0_from_n as f0_from_n,
        f0_from_nk as f0_from_nk,
        fresnel_conductor as fresnel_conductor,
        fresnel_dielectric as fresnel_dielectric,
        fresnel_dielectric_f0 as fresnel_dielectric_f0,
        n_from_f0 as n_from_f0,
    )
    from ._geometry import (
        Geometry as Geometry,
        direction_from_angles_deg as direction_from_angles_deg,
        geometry as geometry,
        geometry_from_angles_deg as geometry_from_angles_deg,
    )
    from ._material import (
        Material as Material,
        Params as Params,
        Structure as Structure,
    )
    from ._measurement import (
        Measurement as Measurement,
    )
    from ._shadowing import (
        smith_g1_reduced as smith_g1_reduced,
        v_cavity_reduced as v_cavity_reduced,
    )
    from ._material_io import (
        MaterialError as MaterialError,
        load_material as load_material,
        material_from_dict as material_from_dict,
        material_to_dict as material_to_dict,
        read_optical_constants as read_optical_constants,
        save_material_json as save_material_json,
    )
    from ._simulate import (
        evaluate as evaluate,
        evaluate_at as evaluate_at,
        goniometer_directions as goniometer_directions,
        simulate as simulate,
    )
    from ._fit import (
        FitResult as FitResult,
        fit as fit,
        select_structure as select_structure,
    )
    from ._fit_batch import (
        fit_batch as fit_batch,
    )
    from ._fit_many import (
        fit_many as fit_many,
    )
    from ._texel_maps import (
        fit_texel_maps as fit_texel_maps,
    )
    from ._fit_texels import (
        TexelFits as TexelFits,
        fit_texels as fit_texels,
    )
    from ._fit_io import (
        fit_result_to_dict as fit_result_to_dict,
        format_fit_table as format_fit_table,
    )
    from ._colour import (
        DEFAULT_OBSERVER as DEFAULT_OBSERVER,
        RGBConversion as RGBConversion,
        RGB_to_XYZ as RGB_to_XYZ,
        SpectralResamplingWarning as SpectralResamplingWarning,
        SpectralWeights as SpectralWeights,
        XYZ_to_Lab as XYZ_to_Lab,
        XYZ_to_RGB as XYZ_to_RGB,
        XYZ_to_xy as XYZ_to_xy,
        delta_E_CIE2000 as delta_E_CIE2000,
        dominant_wavelength as dominant_wavelength,
        encode_RGB as encode_RGB,
        eotf_inverse_sRGB as eotf_inverse_sRGB,
        excitation_purity as excitation_purity,
        rgb_conversion as rgb_conversion,
        spectral_weights as spectral_weights,
        spectrum_to_RGB as spectrum_to_RGB,
        spectrum_to_XYZ as spectrum_to_XYZ,
    )
    from ._colour_report import (
        colour_report as colour_report,
        reflectance_spectrum as reflectance_spectrum,
    )
    from ._colour_shift import (
        average_normal_reflectance as average_normal_reflectance,
        colour_shift_approximation as colour_shift_approximation,
        colour_shift_spectral as colour_shift_spectral,
        colour_shift_weight as colour_shift_weight,
        fresnel_reflectance_spectrum as fresnel_reflectance_spectrum,
    )
    from ._gamut import (
        desaturate_to_gamut as desaturate_to_gamut,
        in_gamut as in_gamut,
        scale_to_display as scale_to_display,
        srgb_luminance as srgb_luminance,
    )
    from ._readers import (
        read_measurement as read_measurement,
    )
    from ._csvio import (
        read_csv as read_csv,
        write_csv as write_csv,
    )
    from ._errors import (
        DataError as DataError,
    )
    from ._alta import (
        read_alta as read_alta,
    )
    from ._merl import (
        read_merl as read_merl,
        write_merl as write_merl,
        merl_table as merl_table,
        half_diff_to_angles_deg as half_diff_to_angles_deg,
        angles_deg_to_half_diff as angles_deg_to_half_diff,
    )
    from ._errors import (
        DataWarning as DataWarning,
    )
    from ._diagnostics import (
        residual_structure as residual_structure,
    )
    from ._sample import (
        ChainTooShortWarning as ChainTooShortWarning,
        SampleResult as SampleResult,
        sample as sample,
    )
    from ._sample_io import (
        format_uncertainty_table as format_uncertainty_table,
        plot_corner as plot_corner,
        plot_spectra as plot_spectra,
    )
    from ._intensity import (
        Light as Light,
        reflected_intensity as reflected_intensity,
    )
    from ._render import (
        Tile as Tile,
        render_compare as render_compare,
        render_linear as render_linear,
        render_material as render_material,
        render_materials as render_materials,
        save_png as save_png,
        tone_map as tone_map,
    )

try:
    __version__ = importlib.metadata.version("ctfit")
except importlib.metadata.PackageNotFoundError:  # running from a source tree
    __version__ = "0.0.0"
