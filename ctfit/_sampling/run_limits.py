"""The ranges of a sampling run's lengths and seed, checked before any work: what :func:`ctfit.sample`
takes, and what the command's options take (imported at its start: this module loads no JAX)."""

from __future__ import annotations

from typing import Any

__all__ = ["MAX_SEED", "MAX_STEPS", "MAX_WALKERS", "check_lengths"]


MAX_STEPS = 10**9
"""The most ``steps`` (per walker) :func:`~ctfit.sample` takes: a billion steps of 32 walkers would run for
weeks (18,000 walker-steps/s), their chain (8 bytes a value) fit in no machine's memory; ``steps=10**20``
stopped in emcee with NumPy's "Maximum allowed dimension exceeded"."""
MAX_WALKERS = 10**6
"""The most ``walkers`` :func:`~ctfit.sample` takes (the default is max(2·ndim + 2, 32)); ``walkers=10**20``
stopped in emcee as ``steps`` did."""
MAX_SEED = 2**32 - 1
"""The largest ``seed`` :func:`~ctfit.sample` takes, NumPy's ``RandomState``'s (emcee's generator): ``seed=2**32``
stopped after the posterior was set up with its "Seed must be between 0 and 2**32 - 1"."""


def check_lengths(*, steps: int, burn: int | None, thin: int, seed: int, resume: bool, backend: Any, walkers: int | None = None) -> None:
    """Refuse (``ValueError``) a chain length, walker count, burn-in, thinning or seed that keeps
    no draw or cannot be, before the backend is touched or a step is run."""
    if not 1 <= steps <= MAX_STEPS:
        raise ValueError(f"steps must be in [1, {MAX_STEPS:,}], got steps={steps}")
    if walkers is not None and not 2 <= walkers <= MAX_WALKERS:
        raise ValueError(f"walkers must be in [2, {MAX_WALKERS:,}] (and even), got walkers={walkers}")
    if thin < 1:
        raise ValueError(f"thin must be ≥ 1, got thin={thin}")
    if thin > steps:
        raise ValueError(f"thin must be at most steps ({steps}) to keep a draw, got thin={thin}")
    if burn is not None and not 0 <= burn < steps:
        raise ValueError(f"burn must be in [0, steps), got {burn} with steps={steps}")
    if burn is not None and steps - burn < thin:
        raise ValueError(f"thin must be at most steps − burn = {steps - burn} to keep a draw, got thin={thin} (burn={burn})")
    if not 0 <= seed <= MAX_SEED:
        raise ValueError(f"seed must be in [0, 2**32 − 1 = {MAX_SEED}] (emcee's generator, NumPy's RandomState, takes no other), got seed={seed}")
    if resume and backend is None:
        raise ValueError("resume=True needs a backend (the HDF5 file of the run to continue)")
