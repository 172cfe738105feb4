"""Frozen dataclasses that are JAX pytrees: the arrays of :class:`~ctfit.Params`,
:class:`~ctfit.Geometry` and a fit's problem, with JAX's own ``jax.tree_util.register_dataclass``.

They were Equinox modules. A fit whose programs are stored runs without importing Equinox
(0.25–0.4 s of every ``ctfit`` process on two cores here: its ``nn`` and ``debug`` modules and
what they import), so the classes a fit's hot path holds are plain frozen dataclasses; Equinox
stays where its transformations are used (the solvers, the sampler, the colour programs).

Fields are leaves (arrays, or None) unless marked static (:data:`STATIC`: hashable values that
are part of the tree's structure, as ``eqx.field(static=True)``). ``==`` compares as Equinox's
modules did (``tree_equal``: the same structure and equal leaves).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from types import MappingProxyType
from typing import Any, TypeVar

import jax
import numpy as np

__all__ = ["array_leaves", "is_array", "pytree", "split_arrays", "STATIC"]

T = TypeVar("T", bound=type)


STATIC = MappingProxyType({"static": True})
"""The metadata of a field that is part of the pytree's structure, not a leaf
(``dataclasses.field(metadata=STATIC)``; Equinox's ``eqx.field(static=True)``)."""


def is_array(x: Any) -> bool:
    """Whether ``x`` is a JAX or NumPy array (or NumPy scalar): ``eqx.is_array``'s test."""
    return isinstance(x, (np.ndarray, np.generic, jax.Array))


def array_leaves(tree: Any) -> list:
    """The array leaves of ``tree`` in order (``jax.tree.leaves(eqx.filter(tree, eqx.is_array))``)."""
    return [x for x in jax.tree.leaves(tree) if is_array(x)]


def split_arrays(tree: Any) -> tuple[list, Callable[[Sequence], Any]]:
    """(:func:`array_leaves` of ``tree``, a function that makes ``tree`` again with other arrays in
    their places): ``eqx.partition(tree, eqx.is_array)`` and ``eqx.combine``. The function holds
    the tree's other leaves and its structure, not its arrays."""
    leaves, treedef = jax.tree.flatten(tree)
    where = [i for i, x in enumerate(leaves) if is_array(x)]
    arrays = [leaves[i] for i in where]
    for i in where:
        leaves[i] = None

    def rebuild(new: Sequence) -> Any:
        out = list(leaves)
        for i, a in zip(where, new, strict=True):
            out[i] = a
        return jax.tree.unflatten(treedef, out)

    return arrays, rebuild


def _tree_equal(a: Any, b: Any) -> bool:
    if type(a) is not type(b):
        return False
    la, ta = jax.tree.flatten(a)
    lb, tb = jax.tree.flatten(b)
    if ta != tb:  # type: ignore[operator]
        return False
    for x, y in zip(la, lb):
        if is_array(x) or is_array(y):
            if not (is_array(x) and is_array(y)) or np.shape(x) != np.shape(y) or np.result_type(x) != np.result_type(y):
                return False
            if not np.array_equal(np.asarray(x), np.asarray(y)):
                return False
        elif x != y:
            return False
    return True


def pytree(cls: T) -> T:
    """Register ``cls``, a frozen dataclass made with ``eq=False``, as a pytree
    (``jax.tree_util.register_dataclass``), with ``==`` as :func:`_tree_equal`::

        @pytree
        @dataclasses.dataclass(frozen=True, eq=False)
        class Pair:
            a: jax.Array
            name: str = dataclasses.field(default="", metadata=STATIC)
    """
    if not dataclasses.is_dataclass(cls) or not cls.__dataclass_params__.frozen or cls.__dataclass_params__.eq:  # type: ignore[attr-defined]
        raise TypeError(f"{cls.__name__}: make it with dataclasses.dataclass(frozen=True, eq=False) first")
    cls.__eq__ = _tree_equal  # type: ignore[method-assign]
    cls.__hash__ = None  # type: ignore[assignment,method-assign]  # (arrays: not hashable)
    return jax.tree_util.register_dataclass(cls)
