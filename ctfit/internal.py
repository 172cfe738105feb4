"""Pieces of ctfit's fit for benchmarks and research code, as ``optimistix.internal`` offers its
own: they may change between versions. Everything meant for users is in :mod:`ctfit`.

- :func:`prepare_fit`: a measurement made ready for the compiled fit (checked, started, laid
  out, padded to its size bucket): ``.problem``, ``.u0`` (the start in the fit's coordinates).
- :func:`fit_core`: the compiled fit's whole computation for one prepared measurement (seeds,
  solve, the report's numbers), to jit and time alone (the solves of ``scripts/bench_fit.py``'s
  many files).
- :func:`normal_equations`: ``(½‖r‖², Jᵀr, JᵀJ)`` of a prepared problem at free values ``u``,
  the one evaluation a Levenberg–Marquardt step of the fit is built on.
- :func:`start_read_ahead`: a large CSV parsed in a helper process (its ``.measurement()``), as
  ``ctfit fit`` reads its file while it imports JAX (the floor of ``scripts/bench_fit.py``).
- ``LOSSES``: the names ``ctfit.fit(..., loss=...)`` accepts besides "auto" (a search over
  every fit, ``scripts/bench_real.py``).
- :func:`shipped_solver_arguments`, ``PARAMETER_STEP``, :func:`ship_programs`: the solver's programs
  ctfit ships, the step of their parameter counts, and the export that ships them
  (``scripts/ship_programs.py``).
- ``COMPILE_EFFORT``: XLA's options of each compile effort of the fit's programs (a dict,
  changed in place by ``scripts/_cheapest_compile.py`` to compile every program the cheapest way).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ._fitting import LOSSES, PARAMETER_STEP, fit_core, normal_equations, prepare_fit, shipped_solver_arguments
    from ._io import start_read_ahead
    from ._runtime import COMPILE_EFFORT, ship_programs

__all__ = ["COMPILE_EFFORT", "LOSSES", "PARAMETER_STEP", "fit_core", "normal_equations", "prepare_fit", "ship_programs", "shipped_solver_arguments",
           "start_read_ahead"]

_HOME = {"COMPILE_EFFORT": "_runtime", "LOSSES": "_fitting", "PARAMETER_STEP": "_fitting", "fit_core": "_fitting", "normal_equations": "_fitting",
         "prepare_fit": "_fitting", "ship_programs": "_runtime", "shipped_solver_arguments": "_fitting", "start_read_ahead": "_io"}


def __getattr__(name: str) -> Any:
    """Each name loaded on first use, from its subpackage (``start_read_ahead`` without JAX)."""
    if name not in _HOME:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__package__}.{_HOME[name]}"), name)
