"""Small numerical guards shared by the model and the colour code."""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["safe_sqrt", "safe_div", "float_dtype", "x64_enabled"]


def safe_sqrt(x):
    """√x for x > 0 and 0 elsewhere, with a finite derivative everywhere (double-``where``)."""
    pos = x > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1)), 0)


def safe_div(a, b):
    """(a / b where b ≠ 0, else 0; where b ≠ 0), with a finite derivative everywhere (double-``where``)."""
    ok = b != 0
    return jnp.where(ok, a / jnp.where(ok, b, 1), 0), ok


def float_dtype(x):
    """``x``'s dtype if it is a floating one, else the default float (the dtype colour results take)."""
    return x.dtype if jnp.issubdtype(x.dtype, jnp.floating) else jnp.result_type(float)


def x64_enabled() -> bool:
    """Whether JAX's 64-bit types are on (``jax_enable_x64``): float64 arrays stay float64.

    >>> import jax
    >>> x64_enabled() == (jax.numpy.zeros(1, dtype=float).dtype == jax.numpy.float64)
    True
    """
    return bool(jax.dtypes.canonicalize_dtype(jnp.float64) == jnp.float64)
