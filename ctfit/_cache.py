"""JAX's persistent compilation cache, and with it ctfit's store of exported fit programs.

The ``ctfit`` command calls :func:`enable_compilation_cache`; library users may too. A second
process then skips XLA's compilation (JAX's cache) and the tracing of the fit program
(``_aot.py`` keeps it in ``ctfit-aot/`` inside the same folder).
"""

from __future__ import annotations

import os
from pathlib import Path


def enable_compilation_cache(path: str | os.PathLike | None = None) -> Path:
    """Point JAX's persistent cache at ``path``, ``$JAX_COMPILATION_CACHE_DIR`` or ~/.cache/ctfit/jax."""
    import jax

    where = Path(path or os.environ.get("JAX_COMPILATION_CACHE_DIR") or Path.home() / ".cache" / "ctfit" / "jax")
    where.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(where))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return where
