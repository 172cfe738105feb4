"""Pictures of materials: the paper's spheres and vases, lit and tone-mapped.

The names the rest of the package uses, loaded on first use (``lazy_loader``).
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(
    __name__,
    submod_attrs={
        "rendering": ['EXPOSURES', 'SHAPES', 'Tile', 'render_compare', 'render_linear', 'render_material', 'render_materials', 'save_png', 'tone_map'],
    },
)
