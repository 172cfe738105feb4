"""The optional parts of ctfit, and the one line that names the extra a missing part needs.

``pip install ctfit`` installs the core: the model, the fit and the command line. Three extras
add the rest (``pyproject.toml``); :func:`need` is called where a feature starts, before any
work, so that a missing extra stops it with one line (:class:`MissingExtraError`, an
``ImportError``) instead of a traceback from deep inside:

>>> need("plots", "a plot")  # installed here: nothing happens
>>> sorted(EXTRAS)
['cluster', 'plots', 'posterior']
"""

from __future__ import annotations

import importlib.util

__all__ = ["EXTRAS", "MissingExtraError", "need"]

EXTRAS = {
    "plots": ("matplotlib", "corner", "PIL"),
    "posterior": ("arviz", "h5py", "h5netcdf"),
    "cluster": ("dask", "distributed", "xarray", "zarr"),
}
"""Extra → the modules it installs (``PIL`` is the ``pillow`` package)."""

_PACKAGE = {"PIL": "pillow"}


class MissingExtraError(ImportError):
    """A feature's optional packages are not installed; the message names the extra."""


def need(extra: str, feature: str) -> None:
    """Raise :class:`MissingExtraError` unless every module of ``extra`` can be imported:
    ``FEATURE needs matplotlib, corner (not installed): pip install 'ctfit[plots]'``."""
    missing = [m for m in EXTRAS[extra] if importlib.util.find_spec(m) is None]
    if missing:
        names = ", ".join(_PACKAGE.get(m, m) for m in missing)
        raise MissingExtraError(f"{feature} needs {names} (not installed): pip install 'ctfit[{extra}]'")
