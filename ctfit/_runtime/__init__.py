"""What runs the work: compiled-program caches, the Dask cluster, memory, progress output.

The names the rest of the package uses, loaded on first use (``lazy_loader``).
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(
    __name__,
    submod_attrs={
        "cluster": ['LOCAL_WORKERS_PER_CORE', 'check_local_workers', 'dask_client', 'prepare_worker', 'worker_count'],
        "compile_cache": ['enable_compilation_cache', 'matplotlib_config_fallback'],
        "extras": ['EXTRAS', 'MissingExtraError', 'need'],
        "garbage": ['collect_seldom'],
        "jax_plugin_scan": ['narrow_jax_plugin_scan'],
        "memory": ['release_free_pages', 'return_large_blocks'],
        "program_preload": ['Preload', 'programs_asked', 'record_programs', 'start_preload'],
        "progress": ['ProgressLines', 'bar', 'closed_pipe', 'echo', 'progress_enabled', 'progress_mode'],
        "shipped_programs": ['export_program', 'ship_programs', 'shipped'],
        "stored_programs": ['COMPILE_EFFORT', 'cached_call', 'kept_program', 'prepare_runtime', 'program_made', 'register_lapack', 'stored_program'],
    },
)
