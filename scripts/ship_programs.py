"""Export the programs ctfit ships (``ctfit/data/programs/``; ``ctfit/_runtime/shipped_programs.py``
says why): the solver's ``lm_init`` and ``lm_step`` for every padded parameter count up to
:data:`LARGEST` and both dtypes, as StableHLO for the CPU without source locations, and
``manifest.json`` with the versions they were made with (a fit uses them only with exactly
these). Run after any change to the solver's code, or to the versions of JAX, optimistix, lineax
or Equinox (``tests/test_shipped_programs.py`` fails until then):
``.venv/bin/python scripts/ship_programs.py``.
"""

from __future__ import annotations

import sys

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

from ctfit.internal import PARAMETER_STEP, ship_programs, shipped_solver_arguments  # noqa: E402

LARGEST = 72
"""The most (padded) parameters shipped: three lobes with 31 bands of n and k, or of F0 and R_d, fit below it."""


def programs(x64: bool) -> list:
    """The programs shipped with JAX's 64-bit types on (both dtypes) or off (float32 alone: float64
    fits need them on)."""
    dtypes = (np.float64, np.float32) if x64 else (np.float32,)
    return [one for dtype in dtypes for p in range(PARAMETER_STEP, LARGEST + 1, PARAMETER_STEP) for one in shipped_solver_arguments(p, dtype)]


def main() -> int:
    print(ship_programs(programs, "scripts/ship_programs.py (jax.export of ctfit/_fitting/chunked_fit.py's _lm_init and _lm_step)"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
