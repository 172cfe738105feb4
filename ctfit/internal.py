"""Pieces of ctfit's fit for benchmarks and research code, as ``optimistix.internal`` offers its
own: they may change between versions. Everything meant for users is in :mod:`ctfit`.

- :func:`prepare_fit`: a measurement made ready for the compiled fit (checked, started, laid
  out, padded to its size bucket): ``.problem``, ``.u0`` (the start in the fit's coordinates).
- :func:`normal_equations`: ``(½‖r‖², Jᵀr, JᵀJ)`` of a prepared problem at free values ``u``,
  the one evaluation a Levenberg–Marquardt step of the fit is built on.
"""

from ._fitting import normal_equations, prepare_fit

__all__ = ["normal_equations", "prepare_fit"]
