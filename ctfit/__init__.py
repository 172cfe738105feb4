"""ctfit: fit the Cook–Torrance reflectance model to measured or synthetic BRDF samples, in JAX.

Conventions (angles, directions, normalisation) are stated once in ``docs/conventions.md``.

Public names are listed once, in ``ctfit/__init__.pyi`` (what type checkers read), and loaded on
first use from the subpackage of their concern (``lazy_loader.attach_stub``; each subpackage's
``__init__`` lists what it exports), so ``import ctfit`` and ``ctfit --version`` do not pay for
importing JAX until a model function is used.
"""

from __future__ import annotations

import importlib.metadata

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach_stub(__name__, __file__)  # the names: __init__.pyi

try:
    __version__ = importlib.metadata.version("ctfit")
except importlib.metadata.PackageNotFoundError:  # running from a source tree
    __version__ = "0.0.0"
