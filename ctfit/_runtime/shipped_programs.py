"""Programs shipped with ctfit as StableHLO (``jax.export``), for a machine's first fit.

The solver's programs (``lm_init``, ``lm_step``: optimistix's Levenberg–Marquardt, one step) depend
only on the number of parameters and the dtype, but tracing them means importing optimistix,
lineax and Equinox (0.45 s here) and tracing and lowering optimistix's step (0.4 s): about a
second of a first fit's CPU, all of it holding the GIL that the fit's other programs need for
their own tracing. ``scripts/ship_programs.py`` exports them once, for each padded size and dtype
a fit uses, into ``ctfit/data/programs/`` (StableHLO without source locations, and a manifest of
the versions it was made with); a first fit then compiles the shipped module instead
(:func:`shipped`), and the program store keeps the executable as for any other program.

The shipped modules are used only where they are what tracing would give: on the CPU backend,
with exactly the manifest's versions of JAX, jaxlib, optimistix, lineax and Equinox. Elsewhere
the program is traced as before. ``tests/test_shipped_programs.py`` exports them again and
compares them with the shipped ones (any change to the solver's code must be shipped again).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib.metadata
import json
import pathlib
import warnings
from collections.abc import Callable
from typing import Any

import jax

from .._model import array_leaves, split_arrays, x64_enabled
from .stored_programs import register_lapack

__all__ = ["SHIPPED", "SHIPPED_VERSIONS", "export_program", "installed_versions", "ship_programs", "shipped", "shipped_name"]

SHIPPED = pathlib.Path(__file__).resolve().parent.parent / "data" / "programs"
"""The folder of the shipped programs and their ``manifest.json``."""

SHIPPED_VERSIONS = ("jax", "jaxlib", "optimistix", "lineax", "equinox")
"""The distributions whose versions a shipped program was made with, and must be run with."""


def shipped_name(name: str, args: tuple) -> str:
    """The file name (without suffix) of program ``name`` for arguments like ``args``: the name and
    a digest of the array leaves' shapes and dtypes, and of whether JAX's 64-bit types are off
    (``jax_enable_x64``): a float32 program made with them on takes the same arrays but returns
    int64 counters, which JAX with them off cannot pass back in (a first float32 fit without
    x64 failed so: "Dtype mismatch ... expected int64 and called with int32")."""
    shapes = ";".join(f"{leaf.shape}{leaf.dtype.str}" for leaf in array_leaves(args))
    if not x64_enabled():
        shapes += ";x32"
    return f"{name}-{hashlib.sha256(shapes.encode()).hexdigest()[:16]}"


def installed_versions() -> dict[str, str]:
    """The installed versions of :data:`SHIPPED_VERSIONS`."""
    out = {}
    for dist in SHIPPED_VERSIONS:
        try:
            out[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            out[dist] = "?"
    return out


@functools.cache
def _manifest() -> dict | None:
    try:
        return json.loads((SHIPPED / "manifest.json").read_text())
    except (OSError, ValueError):
        return None


@functools.cache
def _usable() -> bool:
    """Whether shipped programs are what tracing would give here: the CPU backend, the manifest's versions."""
    manifest = _manifest()
    return manifest is not None and manifest.get("versions") == installed_versions() and jax.default_backend() == "cpu"


def shipped(name: str, args: tuple) -> Callable | None:
    """A function to trace in place of program ``name``'s own for arguments like ``args`` (the same
    tree of arrays): it calls the shipped module (:func:`jax.export.deserialize`), so its tracing
    imports and traces nothing of the program's code. None where no module is shipped for these
    shapes, or where shipped modules are not used (see the module docstring)."""
    if not _usable():
        return None
    path = SHIPPED / f"{shipped_name(name, args)}.jaxexport"
    try:
        blob = path.read_bytes()
    except OSError:
        return None
    from jax import export

    try:
        exported = export.deserialize(bytearray(blob))
    except Exception as err:  # a damaged file of the installation: traced instead, and said once
        warnings.warn(f"ignoring the shipped program {path}: {err}", RuntimeWarning, stacklevel=2)
        return None
    if [(a.shape, a.dtype) for a in exported.in_avals] != [(leaf.shape, leaf.dtype) for leaf in array_leaves(args)]:
        return None
    register_lapack()  # the module calls JAX's LAPACK kernels, which lowering it does not register
    return lambda *a: exported.call(*array_leaves(a))


def export_program(fn: Callable, args: tuple) -> bytes:
    """``fn`` for arguments like ``args`` (its array leaves the module's inputs, as a stored
    program takes them), exported for the CPU without source locations: what
    ``scripts/ship_programs.py`` ships."""
    from jax import export

    leaves, rebuild = array_leaves(args), split_arrays(args)[1]

    def flat(*ls):
        return fn(*rebuild(ls))

    flat.__name__ = flat.__qualname__ = "ctfit_shipped"
    with _no_locations():
        out = export.export(jax.jit(flat), platforms=("cpu",))(*(jax.ShapeDtypeStruct(x.shape, x.dtype) for x in leaves))
    return bytes(out.serialize())


def ship_programs(programs: Callable[[bool], list[tuple[str, Callable, tuple]]], made_by: str) -> str:
    """Export each (name, function, arguments like its own) of ``programs(x64)`` (:func:`export_program`),
    with JAX's 64-bit types on (``x64`` True) and then off (False: the programs of float32 fits
    without ``jax_enable_x64``, whose counters are int32), into :data:`SHIPPED`, in place of what
    was shipped, with ``manifest.json``: the files, the installed versions (:func:`installed_versions`)
    and ``made_by``. Returns a line saying what it wrote."""
    SHIPPED.mkdir(parents=True, exist_ok=True)
    for old in SHIPPED.glob("*.jaxexport"):
        old.unlink()
    names = []
    for x64 in (True, False):
        with jax.enable_x64(x64):
            for name, fn, args in programs(x64):
                file = SHIPPED / f"{shipped_name(name, args)}.jaxexport"
                file.write_bytes(export_program(fn, args))
                names.append(file.name)
    manifest = dict(versions=installed_versions(), programs=sorted(names), made_by=made_by)
    (SHIPPED / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    return f"{len(names)} programs in {SHIPPED}, {sum((SHIPPED / n).stat().st_size for n in names) / 1e6:.2f} MB"


@contextlib.contextmanager
def _no_locations():
    """Source locations left out of a lowering (they name files of this machine)."""
    config: Any = jax.config  # its flags are attributes added at run time, unknown to type checkers
    saved = config.jax_traceback_in_locations_limit
    jax.config.update("jax_traceback_in_locations_limit", 0)
    try:
        yield
    finally:
        jax.config.update("jax_traceback_in_locations_limit", saved)
