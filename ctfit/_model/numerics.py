"""Small numerical guards shared by the model and the colour code."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["array_module", "safe_sqrt", "safe_div", "float_dtype", "x64_enabled"]


def array_module(*values) -> Any:
    """NumPy for NumPy input (float64 stays float64 whatever JAX's x64 setting), else jax.numpy.

    NumPy when at least one value is a NumPy array or scalar and none is a JAX array (or a
    tracer); Python numbers alone go to JAX."""
    numpy_in = any(isinstance(v, (np.ndarray, np.generic)) for v in values)
    return np if numpy_in and not any(isinstance(v, jax.Array) for v in values) else jnp


def safe_sqrt(x):
    """√x for x > 0 and 0 elsewhere, with a finite derivative everywhere (double-``where``);
    NumPy in, NumPy out (:func:`array_module`)."""
    xp = array_module(x)
    pos = x > 0
    return xp.where(pos, xp.sqrt(xp.where(pos, x, 1)), 0)


def safe_div(a, b):
    """(a / b where b ≠ 0, else 0; where b ≠ 0), with a finite derivative everywhere (double-``where``);
    NumPy in, NumPy out (:func:`array_module`)."""
    xp = array_module(a, b)
    ok = b != 0
    return xp.where(ok, a / xp.where(ok, b, 1), 0), ok


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
