"""Least-squares fits of the model to measurements: one, a batch, a database, texel maps.

The names the rest of the package uses, loaded on first use (``lazy_loader``).
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(
    __name__,
    submod_attrs={
        "batch": ['SAMPLE_BUDGET', 'fit_batch'],
        "chunked_fit": ['PARAMETER_STEP', 'shipped_solver_arguments'],
        "diagnostics": ['residual_structure'],
        "quality": ['fit_quality'],
        "fit_report": ['constrained_quantities', 'standard_errors', 'undetermined'],
        "least_squares": ['FitResult', 'fit', 'fit_core', 'prepare_fit', 'seed_params'],
        "many": ['fit_many', 'input_sha256', 'read_input'],
        "plots": ['plot_fit'],
        "quality_plots": ['draw_polar', 'draw_residual_map', 'plot_polar', 'plot_residual_map', 'residual_cells'],
        "problem": ['Problem', 'make_problem', 'model_values'],
        "coordinates": ['from_params', 'to_params'],
        "losses": ['LOSSES'],
        "jacobian": ['normal_equations', 'residual'],
        "results": ['fit_result_to_dict', 'format_fit_table'],
        "seeded_solve": ['SOLVERS'],
        "starts": ['start_from_material'],
        "status": ['FitStatus'],
        "fit_warnings": ['FitWarning', 'WARNING_KINDS'],
        "fit_stats": ['FitStats'],
        "structure_selection": ['choose_structure', 'select_structure', 'structure_label'],
        "texel_maps": ['MAP_PICTURES', 'fit_texel_maps', 'map_picture_files', 'read_texel_geometry', 'save_map_pngs'],
        "texels": ['TEXEL_STATUS', 'TexelFits', 'fit_texels', 'texel_status'],
    },
)
