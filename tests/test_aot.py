"""ctfit/_runtime/stored_programs.py: compiled programs kept on disk (serialised executables), so a new process skips
tracing, lowering and compiling."""

from __future__ import annotations

import sys

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ctfit
from ctfit._fitting import chunked_fit
from ctfit._model import array_leaves
from ctfit._runtime import stored_programs as _aot

from conftest import memory_maps


class _Box(eqx.Module):
    a: jax.Array
    scale: float = eqx.field(static=True)


def _fn(box, x, power):
    return {"y": box.a * box.scale + x**power, "parts": [jnp.sum(x), None]}


def _args():
    return _Box(jnp.arange(3.0), 2.0), jnp.array([1.0, 2.0, 3.0]), 2


def _forbid_tracing(monkeypatch):
    """Make tracing a program for the store fail (the cached_call path traces through jax.jit
    and compiles it; a program loaded from disk does neither)."""

    def no_tracing(*a, **k):
        raise AssertionError("traced again although the program is on disk")

    monkeypatch.setattr(_aot.jax, "jit", no_tracing)
    monkeypatch.setattr(eqx, "filter_jit", no_tracing)  # (imported by the store only for a program it cannot key)


def test_same_result_as_filter_jit(store):
    got = _aot.cached_call("toy", _fn, *_args())
    want = eqx.filter_jit(_fn)(*_args())
    np.testing.assert_array_equal(got["y"], want["y"])
    np.testing.assert_array_equal(got["parts"][0], want["parts"][0])
    assert got["parts"][1] is None
    assert len(list(store.glob("toy-*.xla"))) == 1


def test_a_new_process_loads_the_program_without_tracing(store, monkeypatch):
    first = _aot.cached_call("toy", _fn, *_args())
    monkeypatch.setattr(_aot, "_memory", {})  # as in a new process

    _forbid_tracing(monkeypatch)
    again = _aot.cached_call("toy", _fn, *_args())
    np.testing.assert_array_equal(again["y"], first["y"])


def test_static_values_and_shapes_are_part_of_the_key(store):
    box, x, power = _args()
    _aot.cached_call("toy", _fn, box, x, power)
    y3 = _aot.cached_call("toy", _fn, box, x, 3)["y"]
    np.testing.assert_array_equal(y3, box.a * 2.0 + x**3)
    y_scale = _aot.cached_call("toy", _fn, _Box(box.a, 5.0), x, power)["y"]
    np.testing.assert_array_equal(y_scale, box.a * 5.0 + x**2)
    y_long = _aot.cached_call("toy", _fn, _Box(jnp.arange(4.0), 2.0), jnp.ones(4), power)["y"]
    np.testing.assert_array_equal(y_long, jnp.arange(4.0) * 2.0 + 1.0)
    assert len(list(store.glob("toy-*.xla"))) == 4


def test_equal_static_values_share_a_key_whatever_object_holds_them():
    """A structure whose ``family`` was parsed from a command line (an equal string, not the
    literal's object) keys as the library's ``Structure(family="metal")``: Equinox's ``repr``
    hides a field only when its value *is* the default, so keying by it split the programs of
    ``ctfit fit --family metal`` from those of a library call."""
    parsed = "".join(["me", "tal"])
    assert parsed == "metal" and parsed is not "metal"  # noqa: F632 (the identity is the point)
    a, b = (ctfit.Structure(lobes=2, diffuse="F0/pi", family=f) for f in ("metal", parsed))
    assert repr(_Static(a)) != repr(_Static(b))  # what the key was made of: it differed
    x = jnp.ones(3)
    assert _aot._key("toy", ("run", _Static(a), x)) == _aot._key("toy", ("run", _Static(b), x))
    assert _aot._key("toy", ("run", _Static(a), x)) != _aot._key("toy", ("run", _Static(ctfit.Structure(lobes=1)), x))


class _Static(eqx.Module):
    structure: ctfit.Structure = eqx.field(static=True)


def test_a_damaged_entry_is_replaced_with_a_warning(store, monkeypatch):
    _aot.cached_call("toy", _fn, *_args())
    (path,) = store.glob("toy-*.xla")
    path.write_bytes(b"not a program")
    monkeypatch.setattr(_aot, "_memory", {})
    with pytest.warns(RuntimeWarning, match="ignoring the compiled-program cache entry"):
        got = _aot.cached_call("toy", _fn, *_args())
    np.testing.assert_array_equal(got["y"], jnp.arange(3.0) * 2.0 + jnp.array([1.0, 4.0, 9.0]))
    assert path.read_bytes() != b"not a program"  # rewritten with the fresh program


def test_module_outputs_are_refused(store):
    with pytest.raises(TypeError, match="output must be built of"):
        _aot.cached_call("toy_module", lambda box: box, _Box(jnp.ones(2), 1.0))


def test_closures_are_not_cached(store):
    offset = jnp.ones(3)
    got = _aot.cached_call("toy_closure", lambda x, f: f(x), jnp.zeros(3), lambda x: x + offset)
    np.testing.assert_array_equal(got, np.ones(3))
    assert not list(store.glob("toy_closure-*"))


def test_no_store_without_a_cache_directory(monkeypatch):
    monkeypatch.setattr(_aot, "_memory", {})
    monkeypatch.setattr(_aot, "_store", lambda: None)
    got = _aot.cached_call("toy", _fn, *_args())
    np.testing.assert_array_equal(got["y"], jnp.arange(3.0) * 2.0 + jnp.array([1.0, 4.0, 9.0]))


def test_fit_through_the_store_matches_fit_in_memory(store, monkeypatch):
    """A fit whose program comes from disk gives the same result as the one that wrote it."""
    import ctfit
    from ctfit._model.evaluation import simulate

    st = ctfit.Structure(lobes=1)
    truth = ctfit.Material(st, ctfit.Params(m=np.array([0.25]), w=np.array([1.0]), f0=np.array([0.6, 0.8])), wavelength_nm=np.array([450.0, 650.0]))
    data = simulate(truth, 120, noise=0.01, seed=3)
    monkeypatch.setattr(chunked_fit, "_programs", {})
    first = ctfit.fit(data, st)
    assert list(store.glob("fit_ne-*.xla")) and list(store.glob("lm_step-*.xla"))
    monkeypatch.setattr(_aot, "_memory", {})
    monkeypatch.setattr(chunked_fit, "_programs", {})
    _forbid_tracing(monkeypatch)
    again = ctfit.fit(data, st)
    np.testing.assert_array_equal(again.material.params.m, first.material.params.m)
    np.testing.assert_array_equal(again.material.params.f0, first.material.params.f0)
    assert again.stats["cost"] == first.stats["cost"]


def test_a_stored_program_is_not_compiled_again(store, monkeypatch):
    """Loading a stored executable compiles nothing (JAX's own cache leaves out programs that
    compile in under half a second, and a jax.export program is compiled in every process)."""
    from jax._src import compiler

    _aot.cached_call("toy", _fn, *_args())
    monkeypatch.setattr(_aot, "_memory", {})

    def no_compiling(*a, **k):
        raise AssertionError("compiled again although the executable is on disk")

    monkeypatch.setattr(compiler, "backend_compile_and_load", no_compiling)
    monkeypatch.setattr(compiler, "compile_or_get_cached", no_compiling)
    again = _aot.cached_call("toy", _fn, *_args())
    np.testing.assert_array_equal(again["y"], np.arange(3.0) * 2.0 + np.array([1.0, 4.0, 9.0]))  # NumPy: JAX would compile it


_FIT_SCRIPT = """
import sys, jax
jax.config.update("jax_enable_x64", True)
import numpy as np, ctfit
from ctfit._runtime.compile_cache import enable_compilation_cache
from ctfit._model.evaluation import simulate
enable_compilation_cache(sys.argv[1])
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
st = ctfit.Structure(lobes=1)
truth = ctfit.Material(st, ctfit.Params(m=np.array([0.25]), w=np.array([1.0]), f0=np.array([0.6, 0.8])), wavelength_nm=np.array([450.0, 650.0]))
print(repr(float(ctfit.fit(simulate(truth, 120, noise=0.01, seed=3), st).stats["cost"])))
"""


@pytest.mark.slow
def test_a_stored_program_runs_in_a_new_process_also_when_jax_cache_had_it(tmp_path):
    """Three processes with JAX's cache on for every program: the first compiles and stores the
    fit; the second, the stored executable deleted, loads other programs from JAX's cache and
    compiles the fit again; the third runs whatever the store then holds. Whatever JAX's cache
    served (with jaxlib 0.10 an executable loaded from there could serialise without some of
    its functions), what the store then holds runs, and gives the same fit."""
    import subprocess
    import sys

    cache = tmp_path / "cache"
    run = lambda: subprocess.run([sys.executable, "-c", _FIT_SCRIPT, str(cache)], capture_output=True, text=True, timeout=300)
    first = run()
    assert first.returncode == 0, first.stderr
    for pattern in ("fit_*.xla", "lm_*.xla"):  # the fit's programs
        for entry in (cache / "ctfit-aot").glob(pattern):
            entry.unlink()
    second = run()  # loads the simulation's programs from JAX's cache before it compiles the fit
    assert second.returncode == 0, second.stderr
    third = run()
    assert third.returncode == 0, third.stderr[-2000:]
    assert first.stdout == second.stdout == third.stdout


_LAPACK_SCRIPT = """
import sys, jax
jax.config.update("jax_enable_x64", True)
import json, numpy as np, jax.numpy as jnp
from ctfit._runtime import cached_call
from ctfit._runtime.compile_cache import enable_compilation_cache
enable_compilation_cache(sys.argv[1])

def solve(a, b):
    return jnp.linalg.solve(jnp.linalg.cholesky(a) @ jnp.linalg.cholesky(a).T, b), jnp.linalg.eigh(a)[0]

a = np.array([[4.0, 1.0], [1.0, 3.0]])
x, w = cached_call("lapack_probe", solve, a, np.array([1.0, 2.0]))
print("before", "scipy.linalg" in sys.modules, [m for m in sys.modules if m.startswith("scipy.linalg.")])
print(json.dumps([np.asarray(x).tolist(), np.asarray(w).tolist()]))
import scipy.linalg
print("after", scipy.linalg.cython_blas.__name__, scipy.linalg.cython_lapack.__name__, repr(scipy.linalg.eigh(a)[0].tolist()))
"""


@pytest.mark.slow
def test_a_stored_program_calling_lapack_runs_without_importing_scipy_linalg(tmp_path):
    """JAX's LAPACK kernels take their routines from SciPy's ``cython_blas`` and ``cython_lapack``:
    the store loads those two modules alone (``_scipy_lapack``), not all of ``scipy.linalg``. A
    new process runs a stored program that calls LAPACK (Cholesky, eigh) with ``scipy.linalg``
    never imported, gets the first process's results, and can import ``scipy.linalg`` after it
    as usual (its BLAS and LAPACK modules its own attributes)."""
    import json
    import subprocess
    import sys

    run = lambda: subprocess.run([sys.executable, "-c", _LAPACK_SCRIPT, str(tmp_path / "cache")], capture_output=True, text=True, timeout=300)
    first = run()  # compiles and stores the program
    assert first.returncode == 0, first.stderr
    assert list((tmp_path / "cache" / "ctfit-aot").glob("lapack_probe-*"))
    second = run()  # loads it
    assert second.returncode == 0, second.stderr
    before, values, after = second.stdout.splitlines()
    assert before == "before False []"  # nothing of scipy.linalg left in sys.modules
    assert values == first.stdout.splitlines()[1]
    x, w = (np.array(v) for v in json.loads(values))
    a = np.array([[4.0, 1.0], [1.0, 3.0]])
    np.testing.assert_allclose(a @ x, [1.0, 2.0], rtol=1e-12)
    np.testing.assert_allclose(w, np.linalg.eigvalsh(a), rtol=1e-12)
    assert after.startswith("after scipy.linalg.cython_blas scipy.linalg.cython_lapack [")


def test_scipy_lapack_leaves_an_imported_scipy_linalg_alone(monkeypatch):
    """Where ``scipy.linalg`` is imported already, nothing is loaded apart from it."""
    import sys

    import scipy.linalg  # noqa: F401

    assert _aot._scipy_lapack() == []
    assert "scipy.linalg" in sys.modules


def test_a_command_s_runtime_is_prepared_in_a_thread_before_its_first_program(monkeypatch):
    """``prepare_runtime`` (the ``ctfit`` command calls it before reading its files) registers the
    LAPACK kernels and computes the environment's part of every key in a thread of its own."""
    import threading

    monkeypatch.setattr(_aot, "_lapack_registered", False)
    _aot._environment_digest.cache_clear()
    _aot.prepare_runtime()
    for thread in threading.enumerate():
        if thread.name == "ctfit-runtime":
            thread.join(120)
    assert _aot._lapack_registered and _aot._environment_digest.cache_info().currsize == 1


def _ignores_its_second(x, unused):
    return {"y": x * 2.0}


@pytest.fixture
def store_beside_jax_cache(tmp_path, monkeypatch):
    """A program store (the folder, yielded) and JAX's persistent cache on for every program
    (threshold 0), both in ``tmp_path``; JAX's cache as it was afterwards."""
    from jax.experimental.compilation_cache import compilation_cache

    store = tmp_path / "store"
    store.mkdir()
    monkeypatch.setattr(_aot, "_store", lambda: store)
    monkeypatch.setattr(_aot, "_memory", {})
    monkeypatch.setattr(_aot, "_jax_cache_hits", 0)
    before = (jax.config.jax_compilation_cache_dir, jax.config.jax_persistent_cache_min_compile_time_secs)
    jax.config.update("jax_compilation_cache_dir", str(tmp_path / "jax"))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
    compilation_cache.reset_cache()
    try:
        yield store
    finally:
        jax.config.update("jax_compilation_cache_dir", before[0])
        jax.config.update("jax_persistent_cache_min_compile_time_secs", before[1])
        compilation_cache.reset_cache()


def test_programs_of_one_hlo_under_two_keys_are_both_stored(store_beside_jax_cache):
    """jit leaves unused arguments out, so two stored programs (keys differing in the shape of an
    argument the program does not read) can lower to one HLO. JAX's cache must not hand the
    second the first's executable, which the store then could not keep (a 1-band file fitted
    after a 3-band one shared the fit report's HLO this way)."""
    x = jnp.arange(3.0)
    first = _aot.cached_call("twin", _ignores_its_second, x, jnp.ones(4))
    second = _aot.cached_call("twin", _ignores_its_second, x, jnp.ones(7))
    np.testing.assert_array_equal(first["y"], second["y"])
    assert _aot._jax_cache_hits == 0
    assert len(list(store_beside_jax_cache.glob("twin-*.xla"))) == 2


def test_a_program_lost_from_the_store_is_stored_again(store_beside_jax_cache):
    """A store entry removed (damaged, or deleted by hand) must be compiled and stored again, not
    served by JAX's persistent cache: until 2026-11-26 that hit kept this and every later process
    from storing anything more, and every "warm" fit traced and loaded from JAX's cache again."""
    x = jnp.arange(3.0)
    _aot.cached_call("lost", _ignores_its_second, x, jnp.ones(4))
    (entry,) = store_beside_jax_cache.glob("lost-*.xla")
    entry.unlink()
    _aot._memory.clear()  # as a new process
    again = _aot.cached_call("lost", _ignores_its_second, x, jnp.ones(4))
    np.testing.assert_array_equal(again["y"], np.arange(3.0) * 2.0)
    assert _aot._jax_cache_hits == 0
    assert entry.is_file()
    assert jax.config.jax_persistent_cache_min_compile_time_secs == 0  # JAX's threshold as the user set it


def test_a_jax_cache_hit_of_another_program_does_not_stop_the_store(store_beside_jax_cache):
    """JAX's cache keeps small programs too (a dtype conversion that once took 0.5 s to compile);
    a process that loads one from there still stores the programs it compiles afterwards."""
    small = jax.jit(lambda v: v.astype(jnp.float32) + 1)
    small(jnp.arange(5.0))
    jax.clear_caches()  # as a new process: the small program comes from JAX's cache
    small(jnp.arange(5.0))
    assert _aot._jax_cache_hits >= 1
    out = _aot.cached_call("after_a_hit", _ignores_its_second, jnp.arange(3.0), jnp.ones(2))
    np.testing.assert_array_equal(out["y"], np.arange(3.0) * 2.0)
    assert len(list(store_beside_jax_cache.glob("after_a_hit-*.xla"))) == 1


def test_the_source_digest_covers_subpackages(tmp_path, monkeypatch):
    """Every ``.py`` below the package counts, in subfolders too (a restructured package must
    not load programs compiled from its old sources)."""
    from ctfit._runtime import stored_programs as _aot

    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "_runtime").mkdir()
    (pkg / "_runtime/stored_programs.py").write_text("# stand-in\n")
    (pkg / "sub" / "model.py").write_text("x = 1\n")
    monkeypatch.setattr(_aot, "__file__", str(pkg / "_runtime/stored_programs.py"))
    digest = _aot._source_digest.__wrapped__  # the uncached function (the module keeps one digest per process)
    before = digest()
    (pkg / "sub" / "model.py").write_text("x = 2\n")
    assert digest() != before


def test_the_xla_flags_are_part_of_every_key(monkeypatch):
    """A program compiled under other ``XLA_FLAGS`` (another optimisation level: the suite's own,
    tests/conftest.py) is another program: it is never served under this process's flags."""
    from ctfit._runtime import stored_programs as _aot

    digest = _aot._environment_digest.__wrapped__
    monkeypatch.setenv("XLA_FLAGS", "--xla_backend_optimization_level=0")
    cheap = digest()
    monkeypatch.delenv("XLA_FLAGS")
    assert digest() != cheap
    monkeypatch.setenv("XLA_FLAGS", "--xla_backend_optimization_level=0")
    assert digest() == cheap


def test_kept_programs_are_built_once_per_key_and_the_least_recently_used_dropped(store):
    """kept_program: one program per name, static values and constants' values; with a limit, the
    programs of that name used last (the other names' untouched)."""
    _aot.cached_call("toy", _fn, *_args())
    built = []

    def kept(tag, static, constants):
        return _aot.kept_program("toy_kept", lambda: built.append(tag) or (lambda: tag), static, constants, limit=2)

    a = kept("a", (1,), jnp.arange(3.0))
    assert kept("a again", (1,), jnp.arange(3.0)) is a and built == ["a"]
    kept("b", (1,), jnp.arange(3.0) + 1)  # other constant values
    kept("c", (2,), jnp.arange(3.0))  # other static values; "a" is dropped (limit 2)
    kept("b again", (1,), jnp.arange(3.0) + 1)  # kept, and now the most recently used
    kept("a", (1,), jnp.arange(3.0))  # built again; "c" is dropped
    assert built == ["a", "b", "c", "a"]
    assert sorted(k.partition("-")[0] for k in _aot._memory) == ["toy", "toy_kept", "toy_kept"]


def test_memory_keeps_at_most_its_bound_and_frees_what_it_drops(store, monkeypatch):
    """At most MEMORY_PROGRAMS programs in memory, the least recently used dropped: a dropped
    executable is freed, its memory maps with it (each compiled program holds maps of its own;
    a process that kept every program ran out of them, and XLA aborted it), also when a fit's
    fast lookup (chunked_fit._program) had handed it out; asked for again, it is loaded from the
    store, not traced."""
    import gc
    import weakref

    monkeypatch.setattr(_aot, "MEMORY_PROGRAMS", 3)
    monkeypatch.setattr(chunked_fit, "_programs", {})
    box, x, _ = _args()
    made = [weakref.ref(chunked_fit._program("toy", _fn, box, x, power)) for power in range(2, 8)]
    assert len(_aot._memory) == 3
    gc.collect()
    assert [r() is not None for r in made] == [False, False, False, True, True, True]
    if sys.platform.startswith("linux"):
        before = memory_maps()
        monkeypatch.setattr(_aot, "MEMORY_PROGRAMS", 0)
        _aot._remember("toy-none", lambda: None)  # drops every program (the bound is 0 now)
        gc.collect()
        assert memory_maps() < before  # the executables' maps are unmapped
        monkeypatch.setattr(_aot, "MEMORY_PROGRAMS", 3)
    _forbid_tracing(monkeypatch)
    again = chunked_fit._program("toy", _fn, box, x, 2)  # dropped: loaded from the store
    np.testing.assert_array_equal(again(*array_leaves((box, x, 2)))["y"], _fn(box, x, 2)["y"])


def test_an_entry_copied_over_another_programs_name_is_not_run(store, monkeypatch):
    """An entry holds a digest of its key: the file of one program under another's name (or one
    built by another ctfit) is discarded with a warning, and the right program compiled."""
    box, x, _ = _args()
    _aot.cached_call("toy", _fn, box, x, 2)
    _aot.cached_call("toy", _fn, box, x, 3)
    name = lambda power: store / f"toy-{_aot._key('toy', ('run', box, x, power))[:32]}.xla"  # the key: effort, then arguments
    name(3).write_bytes(name(2).read_bytes())  # the square's program where the cube's belongs
    monkeypatch.setattr(_aot, "_memory", {})
    with pytest.warns(RuntimeWarning, match="holds another program"):
        got = _aot.cached_call("toy", _fn, box, x, 3)
    np.testing.assert_array_equal(got["y"], box.a * 2.0 + x**3)
    assert name(3).read_bytes() != name(2).read_bytes()  # rewritten with the cube's program


@pytest.fixture
def jax_cache_config(monkeypatch):
    """JAX's cache folder as it was after the test; CacheWarnings as if none had been issued."""
    from ctfit._runtime import compile_cache

    monkeypatch.setattr(compile_cache, "_warned", set())
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    saved = jax.config.jax_compilation_cache_dir
    yield compile_cache
    jax.config.update("jax_compilation_cache_dir", saved)


@pytest.mark.parametrize("mode", [0o777, 0o1777, 0o770])
def test_a_jax_cache_folder_others_can_write_to_is_not_used(tmp_path, jax_cache_config, mode):
    """JAX's entries are compiled programs too: its folder must be this user's alone, as the
    program store's is (``enable_compilation_cache``, or a folder JAX was given directly)."""
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(mode)
    with pytest.warns(jax_cache_config.CacheWarning, match=r"compilation cache off: .*shared can be written by other users"):
        assert jax_cache_config.enable_compilation_cache(shared) is None
    assert jax.config.jax_compilation_cache_dir is None

    jax_cache_config._warned.clear()
    jax.config.update("jax_compilation_cache_dir", str(shared))  # as $JAX_COMPILATION_CACHE_DIR does
    with pytest.warns(jax_cache_config.CacheWarning, match="can be written by other users"):
        assert jax_cache_config.program_store_folder() is None
    assert jax.config.jax_compilation_cache_dir is None
    assert not list(shared.iterdir())


def test_threads_asking_for_one_program_at_once_make_it_once(store, monkeypatch):
    """A fit and the background threads that make the next candidates' programs may ask for one
    program together (the screening sample's geometry): it is compiled once, the others wait for
    it. Before, three threads compiled the geometry at once in a first run."""
    import threading

    compiled = []
    lower = _aot.jax.jit

    def counting_jit(fn, *a, **k):
        jitted = lower(fn, *a, **k)

        class Lowering:
            def lower(self, *args):
                lowered = jitted.lower(*args)
                compiled.append(fn.__name__)
                return lowered

        return Lowering()

    monkeypatch.setattr(_aot.jax, "jit", counting_jit)
    start, outs = threading.Barrier(3), []

    def ask():
        start.wait()
        outs.append(_aot.cached_call("together", _fn, *_args())["y"])

    threads = [threading.Thread(target=ask) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(compiled) == 1 and len(outs) == 3
    for y in outs:
        np.testing.assert_array_equal(y, outs[0])
    assert len(list(store.glob("together-*.xla"))) == 1


def test_the_store_keeps_the_programs_used_last_under_its_limit(store, monkeypatch):
    """Every ctfit and every layout stores programs of its own, which nothing else deletes (this
    machine's store had grown to 4,313 entries, about 1 GB): above STORE_LIMIT the entries used
    longest ago go, until a quarter of it is free. Loading an entry counts as a use."""
    import os
    import time

    monkeypatch.setattr(_aot, "_store_bytes", {})
    first = _aot.cached_call("kept", _fn, *_args())
    size = next(store.glob("kept-*.xla")).stat().st_size
    monkeypatch.setattr(_aot, "STORE_LIMIT", int(3.5 * size))
    box, x, _ = _args()
    _aot.cached_call("kept", _fn, box, x, 3)
    monkeypatch.setattr(_aot, "_store_bytes", {})  # a new process: its first save lists the store
    _aot.cached_call("kept", _fn, box, x, 4)
    assert len(list(store.glob("kept-*.xla"))) == 3  # under the limit (above 3/4 of it): nothing deleted
    old = time.time() - 1000
    for i, path in enumerate(sorted(store.glob("kept-*.xla"), key=lambda p: p.stat().st_mtime)):
        os.utime(path, (old + i, old + i))  # stored in this order, long ago
    oldest = min(store.glob("kept-*.xla"), key=lambda p: p.stat().st_mtime)
    monkeypatch.setattr(_aot, "_memory", {})  # a new process: the first program is loaded, which counts as a use
    np.testing.assert_array_equal(_aot.cached_call("kept", _fn, *_args())["y"], first["y"])
    assert oldest.exists() and oldest.stat().st_mtime > old + 100
    _aot.cached_call("kept", _fn, box, x, 5)  # a fourth: above the limit
    left = list(store.glob("kept-*.xla"))
    assert oldest in left and len(left) == 2  # the two used longest ago are gone: at most 3/4 of the limit left
    assert sum(p.stat().st_size for p in left) <= 0.75 * _aot.STORE_LIMIT
