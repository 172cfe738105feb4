"""Small numerical guards shared by the model and the colour code."""

from __future__ import annotations

import jax.numpy as jnp

__all__ = ["safe_sqrt"]


def safe_sqrt(x):
    """√x for x > 0 and 0 elsewhere, with a finite derivative everywhere (double-``where``)."""
    pos = x > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1)), 0)
