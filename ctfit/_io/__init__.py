"""Data in and out: measurement files (CSV, ALTA, MERL, RGL), material files, optical constants, safe writes.

The names the rest of the package uses, loaded on first use (``lazy_loader``).
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(
    __name__,
    submod_attrs={
        "alta": ['read_alta'],
        "chain_lock": ['hold_chain', 'lock_path'],
        "csv_files": ['read_csv', 'write_csv'],
        "csv_table": ['CsvTable', 'read_table'],
        "errors": ['DataError', 'DataWarning', 'MaterialError'],
        "files": ['TEMPORARY', 'atomic_save', 'atomic_write', 'remove_stale_temporaries', 'remove_temporaries', 'replace_links_in', 'temporary_for',
                  'writes_in_place'],
        "interrupt": ['deferred', 'note_resumable', 'on_interrupt', 'resumable', 'run_cleanups', 'set_exit', 'sigint', 'wait_for_writes'],
        "material_files": ['float_list', 'jsonable', 'load_material', 'material_file_inputs', 'material_from_dict', 'material_json',
                           'material_to_dict', 'save_material_json'],
        "merl": ['angles_deg_to_half_diff', 'angles_deg_to_half_diff_deg', 'half_diff_deg_to_angles_deg', 'half_diff_to_angles_deg', 'merl_cell_centres',
                 'merl_phi_d_index', 'merl_theta_d_index', 'merl_theta_h_index', 'merl_table', 'read_merl', 'write_merl'],
        "optical_constants": ['read_optical_constants'],
        "output_paths": ['InputFiles', 'PLOT_SOFTWARE', 'broken_link', 'check_backend', 'check_distinct', 'check_output', 'check_output_folder',
                         'check_own_name', 'check_rerun_plot', 'check_rerun_target', 'groups_beside_chain', 'is_fit_result', 'is_posterior', 'plot_metadata',
                         'result_targets', 'same_file', 'unconverged_name', 'unconverged_target', 'write_own_result'],
        "read_ahead": ['ReadAhead', 'start_read_ahead', 'usable_cores'],
        "readers": ['read_measurement', 'reader_for'],
        "rgl": ['bilinear', 'marginal_sample', 'read_rgl', 'read_tensor_file'],
        "untrusted": ['check_input_file', 'input_sha256', 'parse_json', 'quote', 'read_json_or_none', 'shorten', 'valid_text'],
    },
)
