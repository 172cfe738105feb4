"""Compiled programs kept in memory and on disk, so that a new process skips tracing, lowering
and compiling, and a process compiles a program once.

JAX's persistent compilation cache (``_runtime/compile_cache.py``) saves only the XLA compile: every new process
still traces the Python program and lowers it to HLO to compute the cache key, which for a fit
(optimistix's solver loop, the structured normal equations, the seeds) costs seconds, and it
leaves out programs that compile in under half a second, which a process then compiles again.
Here the *compiled executable itself* is stored (``jax.experimental.serialize_executable``:
loading one takes milliseconds, no tracing, lowering or compiling), keyed by everything that
determines it:

- the function's name and the source of the ctfit package (any edit invalidates every entry);
- the versions of jax, jaxlib, equinox, optimistix, lineax and numpy, the backend, its
  platform version, the device kind and the CPU's feature flags (executables are compiled for
  the host's instruction set), and the ``XLA_FLAGS`` the process started with (they change what
  XLA makes of a program: an optimisation level, a dump folder);
- the static part of the arguments (structure, spec, solver options: their ``repr``) and the
  shape and dtype of every array argument.

An entry is used only when its key matches exactly: its file is named by the key, and holds a
digest of the whole key, checked when it is loaded (a file copied over another's name is not
run). If it holds another key, or cannot be read, loaded or called (a truncated file, a jaxlib
that cannot deserialise it), it is discarded with a warning and the program is compiled as usual. Entries are written atomically. The store lives where
:func:`ctfit._runtime.compile_cache.program_store_folder` says (``ctfit-aot/`` inside the folder
of JAX's persistent cache), and only when that cache is enabled (the ``ctfit`` command
enables it; library users call :func:`ctfit.enable_compilation_cache`). Since
its programs are run, the folder is made with mode 0700 and is not used (one warning) when it,
or JAX's cache folder around it, belongs to another user or others can write to it
(:func:`ctfit._runtime.compile_cache.unsafe_folder`).

In memory, programs are kept under the same key: :func:`cached_call`'s executables, and
programs that :func:`kept_program` builds once and hands out, to be called directly (the
sampler's log-probability, called thousands of times per run, with the goniometer geometry
compiled in: its key holds the geometry's values; the last few used). At most
:data:`MEMORY_PROGRAMS` in all, the least recently used dropped beyond: a process that fits
many layouts (a notebook, a long analysis) must not run out of memory maps.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib.metadata
import math
import os
import pathlib
import pickle
import platform
import sys
import threading
import warnings
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import serialize_executable

from .._io import atomic_write
from .._model import array_leaves, is_array, split_arrays
from .compile_cache import program_store_folder, unsafe_folder, warn_once

_FORMAT = 4  # 1: jax.export programs (compiled again in every process); 2: executables; 3: with their key; 4: compile efforts

_CONFIG: Any = jax.config  # JAX's flags are attributes added at run time, unknown to type checkers

COMPILE_EFFORT: dict[str, dict[str, bool | int]] = {
    "run": {"xla_llvm_disable_expensive_passes": True},
    "step": {"xla_llvm_disable_expensive_passes": True, "xla_cpu_use_fusion_emitters": False},
    "once": {"xla_backend_optimization_level": 0, "xla_llvm_disable_expensive_passes": True, "xla_cpu_use_fusion_emitters": False},
}
"""XLA's options per compile effort (``Lowered.compile(compiler_options=...)``). LLVM's expensive
passes are left out of all three, which cuts their compile by 20–50 % here and leaves their run
time as it was. "run" (the default): the one-program solves (the other solvers, texels,
batches), compiled with XLA's fusion emitters. "step": programs called many times (the kernels
over a chunk: the normal equations, the seeds' sums): XLA's
older fusion code, which compiles them in 50–70 % of the time and runs the fit's chunk kernels
as fast where the fit calls them (``ctfit._fitting.chunked_fit._EFFORT``). "once": programs called once per fit (the cost of a zero model,
the report, the screen's held-out values) and the solver's step: the older fusion code and LLVM
not optimising at all, a quarter to a half of what "run" would compile; they run a few
milliseconds per fit (docs/fitting.md, "Compiled programs are kept"; ``scripts/compile_times.py``)."""
_memory: dict[str, Callable] = {}  # "name-key" → program, the least recently used first
_memory_guard = threading.Lock()  # held while _memory changes (threads make programs at once)

MEMORY_PROGRAMS = 192
"""Programs kept in a process's memory (:func:`_remember`); beyond, the least recently used is
dropped (loaded from the store, or compiled, when asked for again). A compiled program holds
its machine code in memory maps of its own, one per kernel and section: a fit's programs take
about 95 maps each, and a default fit (its structure chosen among several) keeps about 56
programs, 4,800 maps. Linux allows a process 65,530 maps (``vm.max_map_count``); past it XLA
aborts the process (``LLVM ERROR: Unable to allocate section memory``, or an abort inside
``executable.serialize()``). Kept without a bound, 14 default fits of different layouts (pairs
and grids, float32 and float64, several band counts) in one process would pass it; a test
worker did. 192 programs (about 18,000 maps) hold three default fits' programs at once."""
_jax_cache_hits = 0  # executables this process loaded from JAX's persistent cache
_thread_hits = threading.local()  # .count: the same, in this thread (JAX reports a hit in the thread that compiles)


def _count_jax_cache_hit(event: str, **_) -> None:
    global _jax_cache_hits
    if event == "/jax/compilation_cache/cache_hits":
        _jax_cache_hits += 1
        _thread_hits.count = getattr(_thread_hits, "count", 0) + 1


jax.monitoring.register_event_listener(_count_jax_cache_hit)
_stores: dict[pathlib.Path, pathlib.Path | None] = {}  # store folder → itself once checked, or None


@functools.cache
def _source_digest() -> str:
    """A digest of every Python source of the package, subpackages included (by relative path)."""
    root = pathlib.Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for p in sorted(root.rglob("*.py")):
        h.update(p.relative_to(root).as_posix().encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def _cpu_flags() -> str:
    try:
        for line in pathlib.Path("/proc/cpuinfo").read_text(errors="replace").splitlines():
            if line.startswith(("flags", "Features")):
                return line
    except OSError:
        pass
    return platform.processor() or platform.machine()


@functools.cache
def _environment_digest() -> str:
    versions = []
    for dist in ("jax", "jaxlib", "equinox", "optimistix", "lineax", "numpy"):
        try:
            versions.append(f"{dist}={importlib.metadata.version(dist)}")
        except importlib.metadata.PackageNotFoundError:
            versions.append(f"{dist}=?")
    device = jax.devices()[0]
    backend = device.client  # (jax.extend.backend.get_backend(): importing jax.extend costs 40 ms)
    xla_flags = f"XLA_FLAGS={os.environ.get('XLA_FLAGS', '')}"  # read by XLA when the backend starts: they change what it compiles
    parts = [f"format={_FORMAT}", *versions, backend.platform, backend.platform_version, device.device_kind, _cpu_flags(), xla_flags, _source_digest()]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()


def _store() -> pathlib.Path | None:
    """The store's folder (:func:`~ctfit._runtime.compile_cache.program_store_folder`), made (mode
    0700) on first use, JAX's LAPACK kernels registered (:func:`register_lapack`); None without
    a cache, or (with one :class:`~ctfit._runtime.compile_cache.CacheWarning`) when the folder
    cannot be trusted."""
    folder = program_store_folder()
    if folder is None:
        return None
    register_lapack()
    if folder not in _stores:
        _stores[folder] = _trusted(folder)
    return _stores[folder]


def _trusted(store: pathlib.Path) -> pathlib.Path | None:
    """``store`` if only this user can write there: programs loaded from it are run, so nobody else
    may plant one. Otherwise warn and go without it."""
    try:
        store.mkdir(mode=0o700, parents=True, exist_ok=True)
        problem = unsafe_folder(store, follow=False)
    except OSError as e:
        problem = f"cannot be created ({e.strerror or e})"
    if problem is None:
        return store
    warn_once(f"compiled-program store off: {store} {problem}; fits trace their programs again in every run")
    return None


def _abstract(x):
    if is_array(x):
        return jax.ShapeDtypeStruct(x.shape, x.dtype)
    return x


def _key(name: str, args: tuple, constants=None) -> str | None:
    """The entry's key, or None when the static part has no stable ``repr`` (e.g. a closure).

    ``args`` count by their static part and the shape and dtype of their arrays; ``constants``
    (a tree of arrays the program has compiled in) by its structure and its arrays' values.
    The static part is read from the tree's structure (its values' own ``repr``, every field
    shown), not from Equinox's ``repr``, which leaves out a field whose value *is* its default:
    ``family="metal"`` parsed from a command line is an equal string but not the same object,
    and the command and a library call would not share their programs."""
    leaves, treedef = jax.tree.flatten(args)
    text = f"{treedef}\n{[_abstract(x) for x in leaves]!r}"
    if " at 0x" in text:
        return None
    config = (_CONFIG.jax_enable_x64, _CONFIG.jax_default_matmul_precision, _CONFIG.jax_numpy_rank_promotion)
    h = hashlib.sha256("\n".join([_environment_digest(), name, repr(config), text]).encode())
    if constants is not None:
        leaves, treedef = jax.tree.flatten(constants)
        h.update(str(treedef).encode())
        for leaf in leaves:
            a = np.asarray(leaf)
            h.update(str((a.dtype, a.shape)).encode())
            h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _recall(key: str) -> Callable | None:
    """The program kept in memory under ``key`` (from now on the most recently used), or None."""
    with _memory_guard:
        run = _memory.pop(key, None)
        if run is not None:
            _memory[key] = run
    return run


def _remember(key: str, run: Callable, limit: int | None = None) -> Callable:
    """Keep ``run`` in memory under ``key``; with ``limit``, only that many programs of its name
    (the key up to "-"), and :data:`MEMORY_PROGRAMS` in all, the least recently used dropped."""
    with _memory_guard:
        _memory.pop(key, None)
        _memory[key] = run
        if limit is not None:
            prefix = key.partition("-")[0] + "-"
            same = [k for k in _memory if k.startswith(prefix)]
            for k in same[: max(len(same) - limit, 0)]:
                del _memory[k]
        while len(_memory) > MEMORY_PROGRAMS:
            del _memory[next(iter(_memory))]
    return run


def kept_program(name: str, build: Callable[[], Callable], static: tuple = (), constants=None, *, limit: int | None = None) -> Callable:
    """The program ``build()`` returns, built once per key and kept in this process's memory
    (beside :func:`cached_call`'s; with ``limit``, the ``limit`` programs of ``name`` used last).

    The key is :func:`cached_call`'s of ``name`` and ``static`` (their ``repr``; the environment),
    with the values of the arrays in ``constants``: what the program has compiled in. For
    programs that are called often, once built: the caller calls the program itself, with no
    lookup per call. Without a stable key (a closure in ``static``) the program is built anew.
    """
    digest = _key(name, static, constants)
    if digest is None:
        return build()
    key = f"{name}-{digest}"
    run = _recall(key)
    return run if run is not None else _remember(key, build(), limit)


_lapack_lock = threading.Lock()  # held while JAX's LAPACK kernels are registered
_lapack_registered = False


def register_lapack() -> None:
    """Register JAX's LAPACK kernels, which compiled fits call. JAX registers them when it lowers
    a linear-algebra operation, which a loaded executable skips (its call would crash): lowering
    one small ``jnp.linalg.eigh`` (never compiled) does it through JAX's public API (0.09–0.17 s;
    the command does it in a background thread, :func:`prepare_runtime`). JAX's own loader of
    serialised programs calls a private ``initialize_lapack`` instead, which ctfit may not use
    (issue 24: public API only). Threads asking at once wait for the first. The kernels take
    their routines from SciPy's ``cython_blas`` and ``cython_lapack``, loaded first on their own
    (:func:`_scipy_lapack`)."""
    global _lapack_registered
    with _lapack_lock:
        if not _lapack_registered:
            loaded = _scipy_lapack()
            try:
                jax.jit(jnp.linalg.eigh).lower(np.eye(2))
            finally:
                for name in loaded:  # JAX holds their routines now; ``import scipy.linalg`` makes its own
                    sys.modules.pop(name, None)
            _lapack_registered = True


def _scipy_lapack() -> list[str]:
    """Load SciPy's ``scipy.linalg.cython_blas`` and ``cython_lapack`` extension modules (where
    JAX's LAPACK kernels find their routines) without running ``scipy/linalg/__init__.py``.
    Importing them the usual way imports all of ``scipy.linalg`` first: 0.15–0.2 s of every
    command, on the way to its first fit; these two take milliseconds. Where ``scipy.linalg`` is
    imported already, or the files are not where SciPy keeps them, nothing is done (JAX then
    imports them itself). Returns the names entered in ``sys.modules``, for the caller to take out
    once JAX has their routines: a later ``import scipy.linalg`` then imports them as usual."""
    import importlib.machinery
    import importlib.util

    loaded: list[str] = []
    if "scipy.linalg" in sys.modules:
        return loaded
    try:
        spec = importlib.util.find_spec("scipy")
    except (ImportError, ValueError):
        return loaded
    if spec is None or not spec.submodule_search_locations:
        return loaded
    folder = pathlib.Path(next(iter(spec.submodule_search_locations))) / "linalg"
    for name in ("cython_blas", "cython_lapack"):
        full = f"scipy.linalg.{name}"
        file = next((folder / (name + ext) for ext in importlib.machinery.EXTENSION_SUFFIXES if (folder / (name + ext)).is_file()), None)
        if file is None or full in sys.modules:
            continue
        module_spec = importlib.util.spec_from_file_location(full, file)
        if module_spec is None or module_spec.loader is None:
            continue
        module = importlib.util.module_from_spec(module_spec)
        sys.modules[full] = module
        try:
            module_spec.loader.exec_module(module)
        except Exception:  # JAX's own import then loads it the usual way
            del sys.modules[full]
            continue
        loaded.append(full)
    return loaded


def prepare_runtime() -> None:
    """Start :func:`register_lapack`'s work (0.1 s, mostly a first lowering) and the environment's
    part of every key (:func:`_environment_digest`: package versions, the backend, ctfit's source;
    0.02–0.04 s) in a thread of its own, so that a command's first stored program need not wait
    for them (the command calls this when it sets JAX up, before it reads its files)."""
    def prepare() -> None:
        register_lapack()
        _environment_digest()

    threading.Thread(target=prepare, name="ctfit-runtime").start()


def _load(path: pathlib.Path, key: str):
    """The executable stored at ``path`` under ``key`` (the store is this user's alone, see
    :func:`_trusted`); ``ValueError`` when the entry was stored under another key (a file of
    another program, or of another ctfit, under this one's name). The entry's time is set to
    now: the store keeps the programs used last (:func:`_prune`)."""
    stored = pickle.loads(path.read_bytes())
    if not (isinstance(stored, tuple) and len(stored) == 4 and stored[0] == hashlib.sha256(key.encode()).hexdigest()):
        raise ValueError("it holds another program (its key is not this one's)")
    with contextlib.suppress(OSError):
        os.utime(path)
    return serialize_executable.deserialize_and_load(*stored[1:])


def _save(path: pathlib.Path, key: str, compiled) -> None:
    """Store ``compiled`` at ``path``, with a digest of its ``key`` that :func:`_load` checks;
    then keep the store under :data:`STORE_LIMIT` (:func:`_prune`)."""
    entry = (hashlib.sha256(key.encode()).hexdigest(), *serialize_executable.serialize(compiled))
    data = pickle.dumps(entry, protocol=pickle.HIGHEST_PROTOCOL)
    atomic_write(path, [data], quiet=True)  # a cache entry: a Ctrl-C removes it without a word
    _prune(path.parent, len(data))


STORE_LIMIT = 512 * 2**20
"""Bytes the program store may hold. Every ctfit (its source is in each key) and every data
layout has programs of its own, and nothing else ever deletes them: above this, the entries
used longest ago are deleted (:func:`_prune`) until a quarter of it is free. A default fit of one
layout stores about 11 MB."""
_store_bytes: dict[pathlib.Path, int] = {}  # folder → its size, as this process last knew it
_store_guard = threading.Lock()


def _prune(store: pathlib.Path, added: int) -> None:
    """Count ``added`` bytes into ``store``'s size (found once per process, by a listing) and,
    above :data:`STORE_LIMIT`, delete the entries used longest ago (their file times: a load
    sets it) until the store holds at most three quarters of it."""
    with _store_guard:
        known = _store_bytes.get(store)
        if known is not None and known + added <= STORE_LIMIT:
            _store_bytes[store] = known + added
            return
        paths, sizes, times = _entries(store)  # the first save of this process, or the estimate above the limit
        total = sum(sizes)
        for i in np.argsort(times, kind="stable") if total > STORE_LIMIT else ():
            if total <= 0.75 * STORE_LIMIT:
                break
            paths[i].unlink(missing_ok=True)
            total -= sizes[i]
        _store_bytes[store] = total


def _entries(store: pathlib.Path) -> tuple[list[pathlib.Path], list[int], list[float]]:
    """The store's entries: paths, sizes and file times (entries gone meanwhile left out)."""
    paths, sizes, times = [], [], []
    for path in store.glob("*.xla"):
        with contextlib.suppress(OSError):
            st = path.stat()
            paths.append(path)
            sizes.append(st.st_size)
            times.append(st.st_mtime)
    return paths, sizes, times


_outside = threading.Lock()
_outside_depth = 0
_outside_saved = None


@contextlib.contextmanager
def _outside_jax_cache():
    """Programs compiled meanwhile (in any thread) are not written to JAX's persistent cache.

    The store keeps the programs compiled in here; JAX's cache keeps the others. A program bound
    for the store must not come back from JAX's cache, which the store then could not keep (see
    :func:`_program`): a program JAX's cache held but the store lacked (an entry dropped as
    damaged) would be served by JAX, traced and lowered, in every later process. JAX's threshold
    of compile time is raised meanwhile, then restored.
    """
    global _outside_depth, _outside_saved
    with _outside:
        if _outside_depth == 0:
            _outside_saved = _CONFIG.jax_persistent_cache_min_compile_time_secs
            jax.config.update("jax_persistent_cache_min_compile_time_secs", math.inf)
        _outside_depth += 1
    try:
        yield
    finally:
        with _outside:
            _outside_depth -= 1
            if _outside_depth == 0:
                jax.config.update("jax_persistent_cache_min_compile_time_secs", _outside_saved)


def _plain(treedef) -> bool:
    """Whether a tree structure uses only containers that survive pickling (no custom nodes)."""
    probe = jax.tree.unflatten(treedef, [0] * treedef.num_leaves)

    def ok(x):
        if isinstance(x, dict):
            return all(isinstance(k, str) and ok(v) for k, v in x.items())
        if type(x) in (list, tuple):
            return all(ok(v) for v in x)
        return x is None or x == 0

    return ok(probe)


def cached_call(name: str, fn: Callable, *args, effort: str = "run"):
    """``fn(*args)`` through a compiled executable kept in memory and, when enabled, on disk.

    ``fn`` is traced with the arrays of ``args`` (JAX and NumPy arrays: :func:`~ctfit._model.is_array`) as
    inputs and everything else static, as :func:`equinox.filter_jit` would. The result is the
    same as ``eqx.filter_jit(fn)(*args)``. The output must be built of dicts, lists, tuples,
    ``None`` and arrays only (its structure is stored with the executable, and JAX cannot
    store the structure of an Equinox module). ``effort``: how hard XLA optimises it
    (:data:`COMPILE_EFFORT`).
    """
    leaves = array_leaves(args)
    run, out = _program(name, fn, args, leaves, effort)
    return run(*leaves) if out is None else out


def stored_program(name: str, fn: Callable, *args, effort: str = "run") -> Callable:
    """The program :func:`cached_call` runs for ``fn(*args)``, to be called many times: it takes
    the array leaves of arguments like ``args`` (:func:`~ctfit._model.array_leaves`, same
    shapes and dtypes) and returns ``fn``'s output. Kept in memory and on
    disk as :func:`cached_call`'s; ``args`` give the shapes (a stored program is tried on them)."""
    leaves = array_leaves(args)
    return _program(name, fn, args, leaves, effort)[0]


def program_made(name: str, *args, effort: str = "run") -> bool:
    """Whether the program :func:`stored_program` gives for ``name`` and ``args`` is made
    already: kept in this process's memory, or in the store on disk (not loaded here, nor
    checked). A caller can then choose another way where making it would cost more than it saves."""
    digest = _key(name, (effort, *args))
    if digest is None:
        return False
    if _recall(f"{name}-{digest}") is not None:
        return True
    store = _store()
    return store is not None and _entry(store, name, digest).is_file()


def _entry(store: pathlib.Path, name: str, digest: str) -> pathlib.Path:
    """The store's file of the program ``name`` keyed by ``digest``."""
    return store / f"{name}-{digest[:32]}.xla"


def _program(name: str, fn: Callable, args: tuple, leaves: list, effort: str):
    """(program, its output on ``leaves`` or None): the output when a stored program was tried."""
    options = COMPILE_EFFORT[effort]
    digest = _key(name, (effort, *args))
    if digest is None:  # (Equinox only here: not imported by a fit whose programs are stored)
        import equinox as eqx

        jitted, rebuild = eqx.filter_jit(fn), split_arrays(args)[1]
        return (lambda *ls: jitted(*rebuild(ls))), None
    key = f"{name}-{digest}"
    for asked in _askers:
        asked.setdefault(key, (name, digest))
    run = _recall(key)
    if run is not None:
        return run, None
    with _making_lock(key):  # threads asking for one program at once (a fit and the background's) make it once
        run = _recall(key)
        if run is not None:
            return run, None
        return _load_or_compile(name, fn, args, leaves, key, digest, options)


_making: dict[str, threading.Lock] = {}  # key → the lock of the thread making that program
_making_guard = threading.Lock()


def _making_lock(key: str) -> threading.Lock:
    """The lock a thread making (or loading ahead) the program ``key`` holds meanwhile."""
    with _making_guard:
        return _making.setdefault(key, threading.Lock())


def load_ahead(name: str, digest: str) -> bool:
    """Load the stored program ``name`` of key ``digest`` for a later :func:`_program` to take and
    try (``program_preload.py``), unless it is in memory or loaded ahead already; a thread asking
    for it meanwhile waits for this load. Whether it was loaded (not where it is missing or stale)."""
    store, key = _store(), f"{name}-{digest}"
    if store is None:
        return False
    with _making_lock(key):
        if _recall(key) is not None or key in _preloaded:
            return False
        try:
            _preloaded[key] = _load(_entry(store, name, digest), key)
        except Exception:  # missing or stale: the fit makes it as usual (and says why, where it is damaged)
            return False
    return True


_askers: list[dict[str, tuple[str, str]]] = []  # each told key → (name, digest) of every program asked for, in order (program_preload.py)
_preloaded: dict[str, Callable] = {}  # key → a stored program loaded ahead of its use, not yet tried (program_preload.py)
_missed: list[Callable[[str], None]] = []  # told the key of a program asked for that was not loaded ahead (program_preload.py)


def _load_or_compile(name: str, fn: Callable, args: tuple, leaves: list, key: str, digest: str, options: dict):
    """:func:`_program`'s work once the program is not in memory: load it from the store, or
    trace, compile and store it. (program, its output on ``leaves`` or None)."""
    store = _store()
    path = _entry(store, name, digest) if store is not None else None
    ahead = _preloaded.pop(key, None)  # loaded in the background (program_preload.py): tried here as any other
    if ahead is None:
        for told in list(_missed):
            told(key)
    if path is not None and (ahead is not None or path.is_file()):
        try:
            run = ahead if ahead is not None else _load(path, key)
            out = jax.block_until_ready(run(*leaves))  # a damaged program fails here, not later
        except FileNotFoundError:
            pass  # deleted meanwhile (another process kept its store under STORE_LIMIT): compiled below
        except Exception as err:  # a stale or damaged entry: trace instead
            warnings.warn(f"ignoring the compiled-program cache entry {path}: {err}", RuntimeWarning, stacklevel=3)
            path.unlink(missing_ok=True)
        else:
            return _remember(key, run), out

    # The program takes a flat list of arrays and returns plain containers, which is what
    # an executable can be stored with.
    rebuild = split_arrays(args)[1]

    def flat(*ls):
        out = fn(*rebuild(ls))
        if not _plain(jax.tree.structure(out)):
            raise TypeError(f"cached_call({name!r}): the output must be built of dicts, lists, tuples, None and arrays")
        return out

    # The program's name in JAX's logs, and in JAX's cache key: with the entry's digest in it when
    # stored, JAX's cache never hands the store a program compiled under another key (two programs
    # of one HLO: jit leaves out unused arguments, so e.g. the report of a 1-band and a 3-band fit
    # may agree), which would keep it out of the store (see below).
    flat.__name__ = flat.__qualname__ = f"ctfit_{name}_{digest[:16]}" if path is not None else f"ctfit_{name}"
    lowered = jax.jit(flat).lower(*(jax.ShapeDtypeStruct(x.shape, x.dtype) for x in leaves))
    hits = getattr(_thread_hits, "count", 0)
    with _outside_jax_cache() if path is not None else contextlib.nullcontext():
        run = _remember(key, lowered.compile(compiler_options=options))
    # A program JAX's cache served (a hit in this thread during its compile) is not stored: a
    # jaxlib 0.10 executable loaded from JAX's cache could serialise without some of its
    # functions. Hits of other programs, earlier or in other threads (JAX keeps even a dtype
    # conversion that once took 0.5 s to compile), do not stop the store: with that rule, the
    # store stayed empty in every process that met one, and a background compile lost its entry
    # to a small program the main thread loaded meanwhile.
    if path is not None and getattr(_thread_hits, "count", 0) == hits:
        try:
            _save(path, key, run)
        except Exception as err:  # the cache is an optimisation; never fail a fit over it
            warnings.warn(f"could not write the compiled-program cache entry {path}: {err}", RuntimeWarning, stacklevel=3)
    return run, None
