"""Where compiled programs live on disk: JAX's persistent compilation cache, and in its folder
ctfit's store of compiled executables (:func:`program_store_folder`; what is stored there, and
under which key, is :mod:`ctfit._runtime.stored_programs`'s).

The ``ctfit`` command calls :func:`enable_compilation_cache`; library users may too. A second
process then skips XLA's compilation (JAX's cache) and the tracing of the fit program (the
store). The cache is an optimisation: a folder that cannot be created or written (no HOME, a
read-only one) gives one :class:`CacheWarning`, and everything runs without it.
"""

from __future__ import annotations

import atexit
import os
import shutil
import stat
import sys
import tempfile
import warnings
from pathlib import Path
from typing import Any

__all__ = ["CacheWarning", "enable_compilation_cache", "program_store_folder", "matplotlib_config_fallback", "unsafe_folder", "warn_once"]

PROGRAM_STORE = "ctfit-aot"
"""The store's folder inside JAX's cache folder."""

_warned: set[str] = set()


class CacheWarning(UserWarning):
    """The compilation cache (or the program store) is not used; the message says why and what to do."""


def warn_once(message: str) -> None:
    """Issue ``message`` as a :class:`CacheWarning` once per process."""
    if message not in _warned:
        _warned.add(message)
        warnings.warn(message, CacheWarning, stacklevel=3)


def _home() -> Path | None:
    home = os.environ.get("HOME")
    if home is None:
        try:
            home = str(Path.home())  # the password database
        except (RuntimeError, KeyError):
            return None
    return Path(home) if os.path.isabs(home) else None


def _default() -> Path | None:
    home = _home()
    return None if home is None else home / ".cache" / "ctfit" / "jax"


def _usable(where: Path) -> str | None:
    """Why files cannot be kept in ``where`` (created if missing), or None when they can."""
    try:
        where.mkdir(parents=True, exist_ok=True, mode=0o700)
        with tempfile.TemporaryFile(dir=where):
            pass
    except OSError as e:
        return f"cannot write to {where} ({e.strerror or e})"
    return None


def unsafe_folder(folder: Path, *, follow: bool = True) -> str | None:
    """Why the programs kept in ``folder`` could have been put there by someone else (the folder
    belongs to another user, or group or others can write to it, sticky bit or not), or None when
    only this user can write there. ``follow=False``: a link is not a folder.

    >>> import os, pathlib
    >>> folder = pathlib.Path("programs")
    >>> folder.mkdir(mode=0o700)
    >>> unsafe_folder(folder) is None
    True
    >>> os.chmod(folder, 0o1777)
    >>> unsafe_folder(folder)
    'can be written by other users (mode drwxrwxrwt); run chmod go-w on it'
    """
    st = folder.stat() if follow else folder.lstat()
    if not stat.S_ISDIR(st.st_mode):
        return "is not a folder"
    if hasattr(os, "getuid") and st.st_uid != os.getuid():
        return "belongs to another user"
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return f"can be written by other users (mode {stat.filemode(st.st_mode)}); run chmod go-w on it"
    return None


def _shared(where: Path) -> str | None:
    """:func:`unsafe_folder` of JAX's cache folder, as a reason: JAX's entries are programs too."""
    problem = unsafe_folder(where)
    return None if problem is None else f"{where} {problem}"


def enable_compilation_cache(path: str | os.PathLike | None = None) -> Path | None:
    """Point JAX's persistent cache at ``path``, ``$JAX_COMPILATION_CACHE_DIR`` or ~/.cache/ctfit/jax.

    Returns the folder, or None (with one :class:`CacheWarning`) when it cannot be created or
    written, other users can write to it (:func:`unsafe_folder`: its compiled programs are run),
    or there is no home folder: JAX then runs without a persistent cache.

    >>> import jax, ctfit
    >>> before = jax.config.jax_compilation_cache_dir
    >>> where = ctfit.enable_compilation_cache("jax-cache")  # later runs load what this one compiles
    >>> jax.config.jax_compilation_cache_dir == str(where), oct(where.stat().st_mode & 0o777)
    (True, '0o700')
    >>> jax.config.update("jax_compilation_cache_dir", before)  # as it was, for what runs after the example
    """
    import jax

    given = path or os.environ.get("JAX_COMPILATION_CACHE_DIR")
    where = Path(given) if given else _default()
    problem = "no home folder (HOME is empty or relative)" if where is None else _usable(where) or _shared(where)
    if problem:
        warn_once(
            f"compilation cache off: {problem}; every run compiles again. "
            "Set JAX_COMPILATION_CACHE_DIR to a writable folder to keep compiled programs"
        )
        jax.config.update("jax_compilation_cache_dir", None)
        return None
    jax.config.update("jax_compilation_cache_dir", str(where))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return where


def program_store_folder() -> Path | None:
    """The folder of ctfit's compiled-program store: :data:`PROGRAM_STORE` inside JAX's cache
    folder; None while JAX's cache is off, or (with one :class:`CacheWarning`, JAX's cache then
    turned off) when JAX's folder was set without :func:`enable_compilation_cache` (say by
    ``$JAX_COMPILATION_CACHE_DIR``) to one that others can write to (:func:`unsafe_folder`)."""
    import jax

    config: Any = jax.config  # its flags are attributes added at run time, unknown to type checkers
    where = config.jax_compilation_cache_dir
    if not where:
        return None
    try:
        problem = _shared(Path(where))
    except OSError:  # not made yet: JAX makes it, with the umask's mode
        problem = None
    if problem:
        warn_once(f"compilation cache off: {problem}; every run compiles again")
        jax.config.update("jax_compilation_cache_dir", None)
        return None
    return Path(where) / PROGRAM_STORE


def matplotlib_config_fallback() -> str | None:
    """Give matplotlib a temporary configuration folder (removed at exit) when HOME cannot hold
    one, so that it runs without printing two lines about it; return the folder, or None when
    nothing was needed (``MPLCONFIGDIR`` set, matplotlib already imported, or a usable folder)."""
    if "MPLCONFIGDIR" in os.environ or "matplotlib" in sys.modules:
        return None
    home = _home()
    base = os.environ.get("XDG_CONFIG_HOME") or (None if home is None else str(home / ".config"))
    if base and os.path.isabs(base) and _usable(Path(base) / "matplotlib") is None:
        return None
    folder = tempfile.mkdtemp(prefix="ctfit-matplotlib-")
    atexit.register(shutil.rmtree, folder, True)
    os.environ["MPLCONFIGDIR"] = folder
    return folder
