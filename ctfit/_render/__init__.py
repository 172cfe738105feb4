"""Pictures of materials as in Cook & Torrance (1982), Figures 6 and 7: shaded objects under two lights.

``surfaces`` (the camera, the sphere and the vase), ``scene`` (lights, bands, shading to linear
sRGB), ``tone`` (the paper's scaling and sRGB encoding), ``sheet`` (labelled grids),
``measured`` (a fit beside its measurement), ``png`` (saving). ``docs/rendering.md`` states the
scene with the reasons for each choice.

The names the rest of the package uses, loaded on first use (``lazy_loader``).
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(
    __name__,
    submod_attrs={  # in the order of the pipeline
        "surfaces": ['SHAPES', 'Surface', 'VIEW_DIRECTION', 'surface_normals'],
        "scene": ['AMBIENT_FRACTION', 'LIGHT_DIRECTIONS', 'SOLID_ANGLES', 'Scene', 'Tile', 'WAVELENGTH_STEP_NM', 'check_wavelength_step', 'render_linear',
                  'render_scene', 'shade_linear'],
        "tone": ['EXPOSURES', 'tone_map'],
        "sheet": ['render_material', 'render_materials'],
        "measured": ['render_compare'],
        "comparison": ['MeasuredBRDF', 'coverage_text', 'render_comparison'],
        "png": ['save_png'],
    },
)
