"""ctfit: fit the Cook–Torrance reflectance model to measured or synthetic BRDF samples, in JAX.

Conventions (angles, directions, normalisation) are stated once in ``docs/conventions.md``.

Public names are listed once, in ``ctfit/__init__.pyi`` (what type checkers read), and loaded on
first use from the subpackage of their concern (``lazy_loader.attach_stub``; each subpackage's
``__init__`` lists what it exports), so ``import ctfit`` and ``ctfit --version`` do not pay for
importing JAX until a model function is used.
"""

from __future__ import annotations

import lazy_loader

from ._runtime import narrow_jax_plugin_scan

narrow_jax_plugin_scan()  # JAX's import reads three packages' metadata, not every one's (_runtime/jax_plugin_scan.py)
_public, __dir__, __all__ = lazy_loader.attach_stub(__name__, __file__)  # the names: __init__.pyi


def __getattr__(name: str):
    """A public name, loaded on first use; ``__version__`` looked up on first use too: importing
    ``importlib.metadata`` costs 0.03–0.04 s, which a process that never asks (the read-ahead
    helper, :mod:`ctfit._io.read_ahead`, whose start a large file's fit waits for) need not pay."""
    if name == "__version__":
        import importlib.metadata

        try:
            version = importlib.metadata.version("ctfit")
        except importlib.metadata.PackageNotFoundError:  # running from a source tree
            version = "0.0.0"
        globals()["__version__"] = version
        return version
    return _public(name)
