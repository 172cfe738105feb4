"""Test configuration: float64 enabled for the suite (ctfit itself never switches it on), and
XLA's cheapest compile for every program of the suite and of the processes it starts."""

import importlib.util
import os
import pathlib
import signal

CHEAP_XLA_FLAGS = "--xla_backend_optimization_level=0 --xla_cpu_use_fusion_emitters=false"
"""The suite's programs are compiled without XLA's backend optimisation and fusion emitters:
compiling is most of the suite's time (a fresh clone compiles every program), and these flags
halve it (tests/test_fit_chunks.py and tests/test_fit_programs.py: 47 s against 97 s, two
workers). They change how fast a program runs, not what it computes; the programs as ctfit
compiles them for users are checked against these in tests/test_shipped_compile.py, which
runs without them. ``CTFIT_TEST_COMPILE=shipped`` runs the whole suite as ctfit ships. Set in
the environment before JAX starts, so the processes the tests start inherit it; the program
store keys every program by ``XLA_FLAGS``, so none is shared with a run of other flags."""
if os.environ.get("CTFIT_TEST_COMPILE", "cheap") != "shipped" and CHEAP_XLA_FLAGS not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {CHEAP_XLA_FLAGS}".strip()

import jax  # noqa: E402  (after XLA_FLAGS: JAX reads them when its backend starts)
import jax.monitoring  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_platforms", "cpu")

if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    # A suite started in the background (``nohup``, ``&`` in a script) inherits Ctrl-C ignored, and
    # so would every process it starts: the tests that send one (status 130, "interrupted") saw the
    # command finish its work instead. A handled signal is reset to the default in a child.
    signal.signal(signal.SIGINT, signal.default_int_handler)

ROOT = pathlib.Path(__file__).resolve().parent.parent
MEASURED = ROOT / "measurements" / "brdf"  # real BRDF measurements (measurements/brdf/README.md)
TABLES = ROOT / "ctfit" / "data" / "optical_constants"  # optical constants tables (package data)
os.environ.setdefault("MPLBACKEND", "Agg")


def load_script(name: str):
    """``scripts/<name>.py`` imported as a module (the scripts are not a package)."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


BACKEND_COMPILE = "/jax/core/compile/backend_compile_duration"


@pytest.fixture
def store(tmp_path, monkeypatch):
    """ctfit's program store in ``tmp_path``, as in a fresh process without JAX's persistent cache:
    a process that loaded a program from that cache stores nothing, and the CLI's tests leave it
    enabled (in HOME) in the worker that ran them."""
    from jax.experimental.compilation_cache import compilation_cache

    from ctfit._runtime import stored_programs

    monkeypatch.setattr(stored_programs, "_store", lambda: tmp_path)
    monkeypatch.setattr(stored_programs, "_memory", {})
    monkeypatch.setattr(stored_programs, "_jax_cache_hits", 0)
    folder = jax.config.jax_compilation_cache_dir
    jax.config.update("jax_compilation_cache_dir", None)
    compilation_cache.reset_cache()  # JAX opens its cache once: make it look again (and find none)
    yield tmp_path
    jax.config.update("jax_compilation_cache_dir", folder)
    compilation_cache.reset_cache()


@pytest.fixture
def compilations():
    """A list that grows by one entry per XLA (backend) compilation while the test runs."""
    seen = []

    def listener(event, duration, **kw):
        if event == BACKEND_COMPILE:
            seen.append(duration)

    jax.monitoring.register_event_duration_secs_listener(listener)
    yield seen
    jax.monitoring.unregister_event_duration_listener(listener)


MAPS_CLEAR = 40_000


def memory_maps() -> int:
    """The memory maps this process holds (Linux; 0 elsewhere)."""
    try:
        with open("/proc/self/maps", "rb") as f:
            return f.read().count(b"\n")
    except OSError:
        return 0


@pytest.fixture(autouse=True)
def _few_enough_memory_maps():
    """A test worker lives for a thousand tests, and every compiled program holds memory maps of
    its own (about 95 for a fit's kernels). ctfit keeps at most ``MEMORY_PROGRAMS`` programs, but
    JAX keeps every executable of a jitted function the tests call with new shapes; past
    ``vm.max_map_count`` (65,530) XLA aborts the worker. Past ``MAPS_CLEAR`` maps after a test,
    the worker drops every compiled program, JAX's and ctfit's, as a fresh process would not
    have them."""
    yield
    if memory_maps() > MAPS_CLEAR:
        import gc

        from ctfit._runtime import stored_programs

        jax.clear_caches()
        stored_programs._memory.clear()  # the only owner: chunked_fit's lookup holds them weakly
        gc.collect()
