"""A fitted material in the formats renderers read: Mitsuba 3, MERL, glTF 2.0 (``docs/export.md``).

The names the rest of the package uses, loaded on first use (``lazy_loader``).
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(
    __name__,
    submod_attrs={
        "error_grid": ['ERROR_GRID', 'error_grid_angles', 'relative_difference', 'unit_directions'],
        "export": ['EXPORT_FORMATS', 'MITSUBA_COLOURS', 'ExportResult', 'export_material'],
        "gltf": ['fit_ggx_roughness', 'gltf_brdf', 'gltf_material'],
        "merl_export": ['merl_lookup', 'merl_model_table'],
        "mitsuba": ['mitsuba_bsdf', 'mitsuba_target', 'mitsuba_values', 'mitsuba_xml', 'roughplastic_bsdf'],
        "rgb_bands": ['band_to_rgb'],
    },
)
