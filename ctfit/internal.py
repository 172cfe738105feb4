"""Pieces of ctfit's fit for benchmarks and research code, as ``optimistix.internal`` offers its
own: they may change between versions. Everything meant for users is in :mod:`ctfit`.

- :func:`prepare_fit`: a measurement made ready for the compiled fit (checked, started, laid
  out, padded to its size bucket): ``.problem``, ``.u0`` (the start in the fit's coordinates).
- :func:`normal_equations`: ``(½‖r‖², Jᵀr, JᵀJ)`` of a prepared problem at free values ``u``,
  the one evaluation a Levenberg–Marquardt step of the fit is built on.
- ``LOSSES``: the names ``ctfit.fit(..., loss=...)`` accepts besides "auto" (a search over
  every fit, ``scripts/bench_real.py``).
"""

from ._fitting import LOSSES, normal_equations, prepare_fit

__all__ = ["LOSSES", "normal_equations", "prepare_fit"]
