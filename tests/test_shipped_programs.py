"""The solver's programs ctfit ships (``ctfit/data/programs/``, ``ctfit/_runtime/shipped_programs.py``):
they are what exporting the current code gives (else ``scripts/ship_programs.py`` must be run
again), they compute what the traced programs compute, bit for bit, and a first fit on a
machine uses them: it imports neither optimistix, lineax nor Equinox, and fits as a fit that
traces the solver."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from ctfit._fitting.chunked_fit import PARAMETER_STEP, shipped_solver_arguments
from ctfit._runtime import shipped_programs
from ctfit._runtime.shipped_programs import SHIPPED, export_program, installed_versions, shipped, shipped_name

ROOT = Path(__file__).resolve().parent.parent
MANIFEST = json.loads((SHIPPED / "manifest.json").read_text())
SAME_VERSIONS = MANIFEST["versions"] == installed_versions()


def _module_text(blob: bytes) -> str:
    from jax import export

    return export.deserialize(bytearray(blob)).mlir_module()


VARIANTS = [(True, np.float64), (True, np.float32), (False, np.float32)]
"""(JAX's 64-bit types on, dtype) of the shipped programs: float32 ones twice, with the types off
their counters are int32 (float64 fits need them on)."""


def test_the_manifest_lists_every_shipped_program_and_the_versions_they_were_made_with():
    files = sorted(p.name for p in SHIPPED.glob("*.jaxexport"))
    assert files == MANIFEST["programs"] and len(files) == 3 * 2 * 9
    assert set(MANIFEST["versions"]) == set(shipped_programs.SHIPPED_VERSIONS)
    for x64, dtype in VARIANTS:
        with jax.enable_x64(x64):
            for p in range(PARAMETER_STEP, 72 + 1, PARAMETER_STEP):
                for name, _, args in shipped_solver_arguments(p, dtype):
                    assert f"{shipped_name(name, args)}.jaxexport" in files, (name, p, dtype, x64)


def test_a_program_made_with_64_bit_types_on_is_not_the_one_with_them_off():
    """The float32 ``lm_init`` takes the same arrays either way but returns int64 counters with the
    types on: with them off it is another file (a first float32 fit without x64 once took the
    other one and failed)."""
    with jax.enable_x64(True):
        on = [shipped_name(name, args) for name, _, args in shipped_solver_arguments(PARAMETER_STEP, np.float32)]
    with jax.enable_x64(False):
        off = [shipped_name(name, args) for name, _, args in shipped_solver_arguments(PARAMETER_STEP, np.float32)]
    assert not set(on) & set(off)


@pytest.mark.parametrize("x64, dtype", VARIANTS)
def test_the_shipped_programs_are_what_the_current_code_exports(x64, dtype):
    """Where the installed versions are the manifest's (else ctfit does not use them: the second
    branch), every shipped module equals a new export of the solver's code: a change to the
    solver fails here until the programs are shipped again."""
    with jax.enable_x64(x64):
        if not SAME_VERSIONS:
            assert all(shipped(name, args) is None for name, _, args in shipped_solver_arguments(PARAMETER_STEP, dtype))
            return
        for p in range(PARAMETER_STEP, 72 + 1, PARAMETER_STEP):
            for name, fn, args in shipped_solver_arguments(p, dtype):
                stored = (SHIPPED / f"{shipped_name(name, args)}.jaxexport").read_bytes()
                assert _module_text(export_program(fn, args)) == _module_text(stored), (name, p, dtype, x64)


@pytest.mark.skipif(not SAME_VERSIONS, reason="ctfit uses the shipped programs only with the manifest's versions (tested above)")
@pytest.mark.parametrize("x64, dtype", VARIANTS)
def test_a_shipped_program_computes_what_the_traced_one_computes_bit_for_bit(x64, dtype):
    with jax.enable_x64(x64):
        _shipped_and_traced_agree(dtype)


def _shipped_and_traced_agree(dtype):
    rng = np.random.default_rng(0)
    p = 16
    (init_name, init_fn, init_args), (step_name, step_fn, step_args) = shipped_solver_arguments(p, dtype)
    lower, upper = np.full(p, -1.0, dtype), np.full(p, 2.0, dtype)
    y = rng.uniform(0, 1, p).astype(dtype)
    tol = np.array([1e-8, 1e-8, 1e-3], dtype)  # stol, gtol, the cost of a zero model
    a = rng.normal(size=(3 * p, p))
    grad, hess = (a.T @ rng.normal(size=3 * p)).astype(dtype), (a.T @ a).astype(dtype)
    runs = {}
    for way in ("shipped", "traced"):
        init = shipped(init_name, init_args) if way == "shipped" else init_fn
        step = shipped(step_name, step_args) if way == "shipped" else step_fn
        assert init is not None and step is not None
        first = jax.jit(init)(y, lower, upper, tol)
        runs[way] = jax.device_get((first, jax.jit(step)(y, first["state"], dtype(1.5), grad, hess, lower, upper, tol)))
    for a, b in zip(jax.tree.leaves(runs["shipped"]), jax.tree.leaves(runs["traced"])):
        np.testing.assert_array_equal(a, b)


_FIRST_FIT = """
import json, sys
import jax
jax.config.update("jax_enable_x64", sys.argv[4] == "float64")
import numpy as np
import ctfit
from ctfit._runtime import shipped_programs
if sys.argv[2] == "traced":
    shipped_programs.SHIPPED = shipped_programs.SHIPPED / "nothing here"
ctfit.enable_compilation_cache(sys.argv[3])
data = ctfit.read_measurement(sys.argv[1])
res = ctfit.fit(data, ctfit.Structure(lobes=2, diffuse="F0/pi"), dtype=getattr(jax.numpy, sys.argv[4]))
print(json.dumps(dict(cost=float(res.stats["cost"]), m=np.asarray(res.material.params.m).tolist(), steps=int(res.stats["steps"]),
                      imported=sorted(m for m in ("equinox", "optimistix", "lineax") if m in sys.modules))))
"""


@pytest.mark.slow
@pytest.mark.skipif(not SAME_VERSIONS, reason="ctfit uses the shipped programs only with the manifest's versions (tested above)")
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_a_first_fit_uses_the_shipped_solver_and_fits_as_one_that_traces_it(tmp_path, dtype):
    """float64 with JAX's 64-bit types on; float32 with them off (JAX's default, a library user's)."""
    path = ROOT / "measurements" / "testbed" / "blend-conductors.csv"
    env = {k: v for k, v in os.environ.items() if k not in ("JAX_COMPILATION_CACHE_DIR", "JAX_ENABLE_X64")}
    docs = {}
    for way in ("shipped", "traced"):
        done = subprocess.run([sys.executable, "-c", _FIRST_FIT, str(path), way, str(tmp_path / way), dtype], capture_output=True, text=True, env=env,
                              timeout=600)
        assert done.returncode == 0, done.stderr[-3000:]
        docs[way] = json.loads(done.stdout.splitlines()[-1])
    assert docs["shipped"]["imported"] == [] and docs["traced"]["imported"] == ["equinox", "lineax", "optimistix"]
    assert docs["shipped"]["cost"] == docs["traced"]["cost"] and docs["shipped"]["m"] == docs["traced"]["m"]
    assert docs["shipped"]["steps"] == docs["traced"]["steps"] > 0


def test_shipped_programs_are_not_used_with_other_versions_or_another_backend(monkeypatch):
    """A module made with other versions of JAX or optimistix may differ from what tracing gives
    here, and one made for the CPU runs nowhere else: then the solver is traced."""
    name, _, args = shipped_solver_arguments(PARAMETER_STEP, np.float64)[1]
    other = dict(MANIFEST, versions=dict(MANIFEST["versions"], optimistix="0.0.1"))
    monkeypatch.setattr(shipped_programs, "_manifest", lambda: other)
    shipped_programs._usable.cache_clear()
    try:
        assert shipped(name, args) is None
        monkeypatch.setattr(shipped_programs, "_manifest", lambda: MANIFEST)
        shipped_programs._usable.cache_clear()
        monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
        assert shipped(name, args) is None
    finally:
        shipped_programs._usable.cache_clear()


def test_a_damaged_shipped_program_is_traced_instead_with_a_warning(tmp_path, monkeypatch):
    name, _, args = shipped_solver_arguments(PARAMETER_STEP, np.float64)[1]
    (tmp_path / "manifest.json").write_text(json.dumps(dict(MANIFEST, versions=installed_versions())))
    (tmp_path / f"{shipped_name(name, args)}.jaxexport").write_bytes(b"not a module")
    monkeypatch.setattr(shipped_programs, "SHIPPED", tmp_path)
    shipped_programs._manifest.cache_clear()
    shipped_programs._usable.cache_clear()
    try:
        with pytest.warns(RuntimeWarning, match="ignoring the shipped program"):
            assert shipped(name, args) is None
        assert shipped(*shipped_solver_arguments(2 * PARAMETER_STEP, np.float64)[1][::2]) is None  # none shipped there
    finally:
        monkeypatch.undo()
        shipped_programs._manifest.cache_clear()
        shipped_programs._usable.cache_clear()
