"""The Cook–Torrance model: directions, the terms D, G and F, the BRDF, materials and measurements.

The names the rest of the package uses, loaded on first use (``lazy_loader``).

Array annotations (jaxtyping) name their dimensions as ``docs/conventions.md`` ("Array shapes in
annotations") defines them: ``*batch`` any leading shape shared by one call's arguments (``*#batch``:
broadcast), ``3`` a direction's (x, y, z) or a colour's components, ``bands`` the material's bands
(last axis; ``*bands``: or a scalar), ``samples`` a measurement's rows, ``pairs`` distinct direction
pairs. Inputs are ``ArrayLike``, results ``Array`` (or ``np.ndarray`` where NumPy stays NumPy).
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(
    __name__,
    submod_attrs={
        "cook_torrance": ['ambient_reflectance', 'brdf', 'brdf_pairs', 'combine_parts', 'diffuse_reflectance', 'fresnel', 'normal_reflectance',
                          'specular_constant', 'specular_geometric', 'transmitted_diffuse_factor'],
        "direction_pairs": ['unique_direction_pairs'],
        "directions": ['Geometry', 'direction_from_angles_deg', 'geometry', 'geometry_from_angles_deg'],
        "distribution": ['beckmann', 'gaussian'],
        "evaluation": ['by_blocks', 'evaluate', 'evaluate_at', 'goniometer_directions', 'simulate'],
        "fresnel_equations": ['f0_from_n', 'f0_from_nk', 'fresnel_conductor', 'fresnel_dielectric', 'fresnel_dielectric_f0', 'fresnel_diffuse_reflectance',
                              'n_from_f0'],
        "intensity": ['Light', 'reflected_intensity'],
        "material": ['DISTRIBUTIONS', 'FAMILIES', 'FRESNELS', 'GEOMETRIES', 'MAX_LOBES', 'Material', 'NORMALIZATIONS', 'Params', 'Structure', 'used',
                     'wrong_size'],
        "measurement": ['Measurement', 'band_labels', 'check_samples', 'format_value', 'invalid_value', 'not_finite_why', 'value_rules'],
        "names": ['valid_name'],
        "numerics": ['array_module', 'float_dtype', 'safe_div', 'safe_sqrt', 'x64_enabled'],
        "parameters": ['PARAMETERS', 'PARAMETER_AXES', 'PLASTIC_INDEX_RANGE', 'PUBLIC_NAMES', 'box_bounds', 'clip_box', 'n_lower', 'parameter',
                       'value_domain', 'value_range'],
        "pytrees": ['array_leaves', 'is_array', 'pytree', 'split_arrays', 'STATIC'],
        "shadowing": ['smith_g1_reduced', 'v_cavity_reduced'],
    },
)
