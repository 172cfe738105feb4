"""ctfit: fit the Cook–Torrance reflectance model to measured or synthetic BRDF samples, in JAX.

Conventions (angles, directions, normalisation) are stated once in ``docs/conventions.md``.
"""

import importlib.metadata

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
from ._distribution import beckmann as beckmann, gaussian as gaussian
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
from ._material import Material as Material, Params as Params, Structure as Structure
from ._measurement import Measurement as Measurement
from ._shadowing import smith_g1_reduced as smith_g1_reduced, v_cavity_reduced as v_cavity_reduced

from ._material_io import (
    MaterialError as MaterialError,
    load_material as load_material,
    material_from_dict as material_from_dict,
    material_to_dict as material_to_dict,
    read_optical_constants as read_optical_constants,
    save_material_json as save_material_json,
)
from ._simulate import evaluate as evaluate, goniometer_directions as goniometer_directions, simulate as simulate
from ._fit import FitResult as FitResult, fit as fit, select_structure as select_structure
from ._fit_io import fit_result_to_dict as fit_result_to_dict, format_fit_table as format_fit_table

try:
    __version__ = importlib.metadata.version("ctfit")
except importlib.metadata.PackageNotFoundError:  # running from a source tree
    __version__ = "0.0.0"
