"""ctfit/_model/pytrees.py: the fit's pytrees without Equinox behave as Equinox's modules did."""

import dataclasses
import weakref

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ctfit import Params
from ctfit._model import STATIC, array_leaves, is_array, pytree, split_arrays


@pytree
@dataclasses.dataclass(frozen=True, eq=False)
class _Pair:
    a: object
    b: object = None
    name: str = dataclasses.field(default="x", metadata=STATIC)


def test_static_fields_are_structure_and_the_rest_leaves():
    p = _Pair(jnp.arange(3.0), np.ones(2))
    assert len(jax.tree.leaves(p)) == 2
    assert jax.tree.structure(p) != jax.tree.structure(_Pair(jnp.arange(3.0), np.ones(2), name="y"))
    doubled = jax.tree.map(lambda v: 2 * v, p)
    assert isinstance(doubled, _Pair) and doubled.name == "x" and np.array_equal(doubled.a, [0.0, 2.0, 4.0])
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.a = 1  # type: ignore[misc]


def test_equality_is_equinox_s_tree_equal():
    p = Params(m=np.array([0.2, 0.3]), w=np.array([0.5, 0.5]))
    assert p == Params(m=np.array([0.2, 0.3]), w=np.array([0.5, 0.5]))
    assert p != Params(m=np.array([0.2, 0.4]), w=np.array([0.5, 0.5]))
    assert p != Params(m=np.array([0.2, 0.3]))  # another structure
    assert p != Params(m=np.array([0.2, 0.3], np.float32), w=np.array([0.5, 0.5]))  # another dtype
    assert _Pair(1.0) == _Pair(1.0) and _Pair(1.0) != _Pair(2.0) and _Pair(1.0) != "not a pair"


def test_array_leaves_and_split_are_equinox_s_filter_partition_and_combine():
    tree = (_Pair(jnp.arange(3.0), 2.5), {"k": np.int32(4), "s": "text", "n": None}, [jnp.ones(2)])
    assert [type(x) for x in array_leaves(tree)] == [type(x) for x in jax.tree.leaves(eqx.filter(tree, eqx.is_array))]
    assert all(a is b for a, b in zip(array_leaves(tree), jax.tree.leaves(eqx.filter(tree, eqx.is_array))))
    arrays, rebuild = split_arrays(tree)
    again = rebuild([a + 1 for a in arrays])
    dynamic, static = eqx.partition(tree, eqx.is_array)
    want = eqx.combine(jax.tree.map(lambda a: a + 1, dynamic), static)
    assert jax.tree.structure(again) == jax.tree.structure(want)
    for x, y in zip(jax.tree.leaves(again), jax.tree.leaves(want)):
        assert np.array_equal(x, y) if is_array(x) else x == y


def test_the_rebuilding_function_holds_no_array():
    a = np.ones(3)
    ref = weakref.ref(a)
    arrays, rebuild = split_arrays({"a": a, "name": "kept"})
    del a, arrays
    assert ref() is None and rebuild([np.zeros(2)])["name"] == "kept"


def test_a_class_that_is_not_a_frozen_dataclass_without_eq_is_refused():
    with pytest.raises(TypeError, match="frozen=True, eq=False"):
        pytree(dataclasses.dataclass(frozen=True)(type("A", (), {"__annotations__": {"a": object}})))
    with pytest.raises(TypeError, match="frozen=True, eq=False"):
        pytree(type("B", (), {}))
