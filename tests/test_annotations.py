"""The public API is annotated (issue 24): every parameter and return of every public function and
method, with jaxtyping shapes on the arrays of the model and colour functions
(``docs/conventions.md``, "Array shapes in annotations"); and mypy holds the modules that define the
public names to that (``pyproject.toml``, ``[tool.mypy]``)."""

import functools
import inspect
import tomllib
import types
import typing

import jax
import jaxtyping
import numpy as np
import pytest

import ctfit

from conftest import ROOT

SHAPED_PACKAGES = ("ctfit._model.", "ctfit._colour.")
"""Where every array in a public signature must carry a jaxtyping shape."""

NO_ARRAYS = {"specular_constant", "Structure.__init__", "Structure.has_specular", "Structure.has_diffuse", "Structure.has_s", "Structure.needs_fresnel_params",
             "Structure.has_rd", "Structure.shared_index", "Material.is_rgb", "Material.band_labels", "Material.check_shapes", "Material.check_colour_channels",
             "Measurement.n_bands",
             "Measurement.band_labels", "Measurement.repeats", "Measurement.replace", "Measurement.with_lines", "Measurement.file_place",
             "colour_report", "rgb_conversion", "spectral_weights",
             "SpectralWeights.cmfs", "RGBConversion.white_xy"}
"""Public callables of those packages that take and return no array."""


def _unwrapped(obj):
    """The Python function behind a jitted or cached public function."""
    while True:
        inner = getattr(obj, "__wrapped__", None)
        if inner is None:
            return obj
        obj = inner


def _members(cls):
    """(name, function) of a class's own public methods, properties and constructor."""
    for key, value in vars(cls).items():
        if key.startswith("_") and key not in ("__init__", "__new__", "__call__"):
            continue
        if isinstance(value, (staticmethod, classmethod)):
            value = value.__func__
        elif isinstance(value, property):
            value = value.fget
        elif isinstance(value, functools.cached_property):
            value = value.func
        if inspect.isfunction(value) and value.__module__.startswith("ctfit"):
            yield f"{cls.__name__}.{key}", value


def _public_callables():
    for name in sorted(ctfit.__all__):
        obj = getattr(ctfit, name)
        if inspect.isclass(obj):
            yield from _members(obj)
        elif callable(obj):
            fn = _unwrapped(obj)
            if inspect.isfunction(fn):
                yield name, fn


PUBLIC = list(_public_callables())
# the search finds functions, jitted and cached ones, methods, properties and constructors
assert {"brdf", "fit", "evaluate_at", "Material.params_at", "Measurement.replace", "Measurement.n_bands", "log_probability",
        "srgb_luminance", "DataError.__init__"} <= {name for name, _ in PUBLIC} and len(PUBLIC) > 120, PUBLIC


@pytest.mark.parametrize("name, fn", PUBLIC, ids=[name for name, _ in PUBLIC])
def test_every_parameter_and_return_is_annotated(name, fn):
    sig = inspect.signature(fn)
    missing = [p.name for p in sig.parameters.values() if p.name not in ("self", "cls") and p.annotation is inspect.Parameter.empty]
    if sig.return_annotation is inspect.Signature.empty:
        missing.append("return")
    assert not missing, f"{name} ({fn.__module__}): not annotated: {missing}"


def _bare_arrays(annotation) -> list:
    """The array types in ``annotation`` that carry no jaxtyping shape."""
    if isinstance(annotation, type) and issubclass(annotation, jaxtyping.AbstractArray):
        return []
    origin = typing.get_origin(annotation)
    if origin in (typing.Union, types.UnionType, tuple, list, dict):
        return [bare for arg in typing.get_args(annotation) for bare in _bare_arrays(arg)]
    if annotation in (jax.Array, np.ndarray) or origin is np.ndarray:
        return [annotation]
    return []


def _shapes(annotation) -> bool:
    """Whether ``annotation`` holds a jaxtyping shape."""
    if isinstance(annotation, type) and issubclass(annotation, jaxtyping.AbstractArray):
        return True
    return any(_shapes(arg) for arg in typing.get_args(annotation))


SHAPED = [(name, fn) for name, fn in PUBLIC if fn.__module__.startswith(SHAPED_PACKAGES)]


@pytest.mark.parametrize("name, fn", SHAPED, ids=[name for name, _ in SHAPED])
def test_model_and_colour_arrays_carry_shapes(name, fn):
    """No bare ``Array``/``ArrayLike``/``np.ndarray`` in the signature; every function that takes or
    returns an array says its shape (``*batch``, ``3``, ``bands``, …)."""
    hints = typing.get_type_hints(fn, include_extras=True)
    bare = {key: ann for key, ann in hints.items() if _bare_arrays(ann)}
    assert not bare, f"{name}: arrays without a shape: {bare}"
    if name not in NO_ARRAYS:
        assert any(_shapes(ann) for ann in hints.values()), f"{name}: no array shape in {hints}"


@pytest.mark.parametrize("cls", [ctfit.Geometry, ctfit.Params, ctfit.Light])
def test_the_model_containers_say_their_shapes(cls):
    hints = typing.get_type_hints(cls, include_extras=True)
    fields = [f for f in hints if not f.startswith("_")]
    assert fields and all(_shapes(hints[f]) and not _bare_arrays(hints[f]) for f in fields), hints


def test_the_shapes_are_checked_by_jaxtyping():
    """The annotations are jaxtyping's: a value of the wrong shape does not match them."""
    returns = typing.get_type_hints(ctfit.direction_from_angles_deg, include_extras=True)["return"]
    assert isinstance(jax.numpy.zeros((4, 3)), returns) and isinstance(jax.numpy.zeros((2, 5, 3)), returns)
    assert not isinstance(jax.numpy.zeros((4, 2)), returns) and not isinstance(jax.numpy.zeros((4, 3), int), returns)


def test_mypy_holds_the_public_modules_to_full_annotations():
    """Every module that defines a public name is under ``disallow_untyped_defs`` (and only those:
    the list is the public API's, ``ctfit/__init__.pyi``)."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["mypy"]
    strict = {m for o in config["overrides"] if o.get("disallow_untyped_defs") and o.get("disallow_incomplete_defs") for m in o["module"]}
    defining = {fn.__module__ for _, fn in PUBLIC}
    defining |= {obj.__module__ for obj in map(lambda n: getattr(ctfit, n), ctfit.__all__) if inspect.isclass(obj)}
    assert defining == strict, (sorted(defining - strict), sorted(strict - defining))
