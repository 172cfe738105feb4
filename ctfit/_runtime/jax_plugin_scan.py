"""JAX's import without its scan of every installed package's metadata.

Importing ``jax.numpy`` (JAX 0.10) looks for a ROCm plugin by reading the metadata of *every*
installed distribution (``jax/_src/numpy/array_constructors.py``: ``importlib.metadata.distributions()``,
then ``dist.metadata.get("Name")`` of each, parsed by the ``email`` package). With ctfit's extras
installed that is 157 files here and about 0.1 s of every process that imports JAX (0.10–0.13 s
here), more than a warm fit of 20,000 samples spends solving. Only a distribution named
``jax-rocm…-plugin`` can match, so :func:`narrow_jax_plugin_scan` narrows that one call to the
distributions whose name, read from their folder's name without opening their metadata, starts
with "jax": JAX finds the same plugins (or none), and reads three files instead of 157.

:func:`narrow_jax_plugin_scan` (``import ctfit`` calls it) adds a finder to ``sys.meta_path``
that finds no module: when JAX is about to import that module, it wraps ``importlib.metadata.distributions``
for the module's one call and takes itself out. Every other caller gets the function unchanged,
and nothing happens in a process that never imports JAX (``importlib.metadata`` is not even imported).
"""

from __future__ import annotations

import sys

SCANNING_MODULE = "jax._src.numpy.array_constructors"
"""The module of JAX whose import reads every distribution's metadata."""


class _BeforeTheScan:
    """A ``sys.meta_path`` finder that finds nothing; it narrows the scan as its module is imported."""

    def find_spec(self, name, path=None, target=None):
        if name == SCANNING_MODULE:
            _remove()
            _narrow_next_scan()
        return None


def narrow_jax_plugin_scan() -> None:
    """Narrow JAX's scan in this process (once; nothing where JAX's numpy is imported already)."""
    if SCANNING_MODULE not in sys.modules and not any(isinstance(f, _BeforeTheScan) for f in sys.meta_path):
        sys.meta_path.insert(0, _BeforeTheScan())


def _remove() -> None:
    sys.meta_path[:] = [f for f in sys.meta_path if not isinstance(f, _BeforeTheScan)]


def jax_named(dist) -> bool:
    """Whether an installed distribution's name starts with "jax" (jax, jaxlib, jax-rocm7-plugin, …),
    read from its folder's name where the distribution has one (its metadata file is not opened)."""
    name = getattr(dist, "_normalized_name", None)  # the name of its .dist-info folder, normalised (Python ≥ 3.10)
    if not isinstance(name, str):
        name = dist.metadata.get("Name", "") or ""
    return name.lower().replace("-", "_").startswith("jax")


def _narrow_next_scan() -> None:
    import importlib.metadata as metadata

    everything = metadata.distributions

    def distributions(**kwargs):
        """``importlib.metadata.distributions``; for the scanning module's call without arguments,
        only the distributions :func:`jax_named` keeps (and the function is put back)."""
        if kwargs or sys._getframe(1).f_globals.get("__name__") != SCANNING_MODULE:
            return everything(**kwargs)
        metadata.distributions = everything
        return [d for d in everything() if jax_named(d)]

    distributions.__wrapped__ = everything  # type: ignore[attr-defined]
    metadata.distributions = distributions
