"""Benchmark of the fit as users run it: ``ctfit fit`` against its peers, whole processes on both
sides, in one run; writes the section "## Fitting" of ``docs/benchmarks.md`` with ``--docs DIR``.

Every figure is a whole process (interpreter start to exit) timed from outside with the
kernel's accounting of the finished child (``_whole_process.py``: wall time, peak resident
memory); each is the median of ``--repeat`` runs, the columns of a case run in interleaved
rounds so that a drifting machine load touches them alike. Data files are written once into a
scratch folder (``_bench_fit_data.py`` describes them).

- **Floor**: the interpreter alone, a bare JAX process (import JAX, start its CPU backend,
  leave at once) and ``ctfit --version``.
- **Scattered samples** (20,000 and 200,000; ``--small``: 2,000): SciPy
  (``_scipy_fit.py``: NumPy reads the CSV, ``least_squares(method="lm")`` on the NumPy model
  ``_numpy_model.py``, from ctfit's default start) against ``ctfit fit FILE --lobes 2 --json``
  with an empty cache folder per run (cold), with a cache an earlier run filled (warm), and on a
  file of another sample count (19,000) with the cache as the first run left it (new size; the
  folder is put back in place after each such run). A further process calls ``ctfit.fit`` twice
  with the warm cache: the first call loads the stored program, the second only solves.
- **Warm from another size**: each scattered file fitted with a cache that one fit of a 50,000-sample
  file (``--small``: 5,000) filled, put back before every run (issue 21).
- **Batch**: 256 files × 2,000 samples of one geometry (``--small``: 8), one ``ctfit fit DIR -o
  OUT`` process against one SciPy process looping over the files, and ``--starts 1`` (one start, as
  SciPy's); its floor, a bare JAX process that reads the files one after another with ctfit's reader;
  and that process solving them too with ``ctfit.fit_batch``, nothing printed or written (what the
  command costs around its solves).
- **MERL-sized**: a MERL ``.binary`` file (every cell above the horizon: 1,096,216 pairs × RGB;
  ``--small``: 100,000 pairs), ``ctfit fit FILE --no-diffuse`` warm: time and peak memory.
- **Per texel**: ``ctfit.fit_batch(geometry, values=...)`` on 100,000 texels × 201 samples (67
  direction pairs × RGB, one lobe; ``--small``: 64), float32 and float64, in this
  process: texels per second of a call after the compiling one.
- **Mitsuba**: Mitsuba 3's ``roughconductor`` (Dr.Jit ``llvm_ad_rgb``, Adam, log loss, lr 0.05,
  1,000 iterations; ``_mitsuba_fit.py``) on 20,000 RGB direction pairs Mitsuba rendered (Cu,
  α = 0.15) against ``ctfit fit FILE --fresnel conductor --geometry G --no-diffuse`` (warm) with
  G = ``smith-rational`` (Mitsuba's own G1) and ``smith`` (the exact G1): time and accuracy.
  Skipped with the reason printed where Dr.Jit cannot run, and in ``--small``.

Run: ``.venv/bin/python scripts/bench_fit.py [--small] [--repeat N] [--docs DIR] [--no-merl]
[--no-mitsuba] [--no-texels] [--no-batch]``.
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import json
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = ROOT / "scripts"
sys.path.insert(0, str(SCRIPTS))

import _bench_fit_data as data  # noqa: E402
from _whole_process import byte_compile, median, run  # noqa: E402

SECTION = "## Fitting"
PY = sys.executable
CTFIT = str(Path(sys.executable).with_name("ctfit"))
JAX_FLOOR = "import os, jax; jax.numpy.zeros(()).block_until_ready()"
"""What every JAX process that computes pays: importing JAX and starting its CPU backend (an array
put on the device). Not a compile (a warm ctfit loads its compiled programs), and not Python's own
exit with JAX loaded (about 0.2 s here): the floors end with ``LEAVE``, as the ``ctfit`` command
does once its output is written (``ctfit/_cli/leave.py``). Until 2026-12-02 the floor compiled a
tiny program and left the usual way, 0.15–0.25 s more than this: a warm 20,000-sample fit ran
below it."""
LEAVE = "; os._exit(0)"
READ_FLOOR = ("import sys; from ctfit.internal import start_read_ahead; ahead = start_read_ahead(sys.argv[1]); " + JAX_FLOOR
              + "; import ctfit; ahead.measurement() if ahead else ctfit.read_measurement(sys.argv[1])" + LEAVE)
"""The floor of a fit of one file: the bare JAX process, and reading the file as ``ctfit fit`` does
(a CSV of 8 MiB or more parsed by a helper process while JAX is imported: ``ctfit/_io/read_ahead.py``)."""
READ_DIR_FLOOR = (JAX_FLOOR + "; import pathlib, sys, ctfit; "
                  "[ctfit.read_measurement(p) for p in sorted(pathlib.Path(sys.argv[1]).glob('*.csv'))]" + LEAVE)
"""The floor of a fit of a folder: the bare JAX process, and reading its files one after another
with ctfit's reader (``ctfit fit DIR`` reads them in a thread while it fits)."""
READ_SOLVE_DIR = ("import os, jax; jax.config.update('jax_enable_x64', True); jax.numpy.zeros(()).block_until_ready(); import pathlib, sys, ctfit; "
                  "ms = [ctfit.read_measurement(p) for p in sorted(pathlib.Path(sys.argv[1]).glob('*.csv'))]; "
                  "st = ctfit.Structure(lobes=2, diffuse='F0/pi', family='metal'); "
                  "[ctfit.fit_batch(ms[a: a + 64], st, loss='relative') for a in range(0, len(ms), 64)]" + LEAVE)
"""What ``ctfit fit DIR`` does but for its outputs, written the plain way with the library: a bare
JAX process reads the files one after another and fits them with ``ctfit.fit_batch``, 64 at a
call (the command's window), from the same warm cache; it prints and writes nothing. Not a floor
(the solves are ctfit's own), but the measure of what the command adds around its solves."""
SOLVES_ALONE = r"""
import json, pathlib, sys, time
import jax
jax.config.update("jax_enable_x64", True)
import ctfit
from ctfit.internal import fit_core, prepare_fit
paths = sorted(pathlib.Path(sys.argv[1]).glob("*.csv"))
t = time.process_time()
ms = [ctfit.read_measurement(p) for p in paths]
out = {"read_cpu_s": time.process_time() - t}
st = ctfit.Structure(lobes=2, diffuse="F0/pi", family="metal")
core = jax.jit(fit_core, static_argnums=(3, 4, 5, 6))
for k in (3, 1):
    preps = [prepare_fit(m, st, start=None, fixed=(), loss="relative", dtype=jax.numpy.float64, starts=k) for m in ms[:int(sys.argv[2])]]
    args = lambda p: (p.problem, p.u0, p.grid, *p.options("lm", 256))
    jax.block_until_ready(core(*args(preps[0])))  # compiled here (the command loads it from its store)
    best = []
    for p in preps:
        times = []
        for _ in range(3):
            t = time.process_time()
            jax.block_until_ready(core(*args(p)))
            times.append(time.process_time() - t)
        best.append(min(times))
    out[f"solve_cpu_s_{k}"] = sum(best) / len(best) * len(ms)
print(json.dumps(out))
"""
"""The CPU time (every thread of the process) of what no run of the many files can do without:
reading the files with ctfit's reader, and solving each (``fit_core`` jitted: seeds, solve and
the report's numbers, one file a call, best of 3), with 3 seeds and with 1, measured on the first
``argv[2]`` files and scaled to all of them. Two cores can at best share it out: the floor
of ``ctfit fit DIR`` is then the bare JAX process (it runs on one core before anything else can)
plus this CPU time over the cores."""
IN_PROCESS = r"""
import json, sys, time
import jax
jax.config.update("jax_enable_x64", True)
import ctfit
ctfit.enable_compilation_cache()
d = ctfit.read_measurement(sys.argv[1])
st = ctfit.Structure(lobes=2, diffuse="F0/pi")
t = time.perf_counter(); ctfit.fit(d, st); first = time.perf_counter() - t
t = time.perf_counter(); r = ctfit.fit(d, st); second = time.perf_counter() - t
# Step cost: a one-start fit's time per step against one evaluation of the residual, Jᵀr and
# JᵀJ alone (the structured normal equations, jitted; best of 7). The fit's time includes its
# set-up and report, so the ratio is an upper bound.
from ctfit.internal import normal_equations, prepare_fit
prep = prepare_fit(d, st, start=None, fixed=(), loss="relative", dtype=jax.numpy.float64, starts=1)
ne = jax.jit(normal_equations)
jax.block_until_ready(ne(prep.problem, prep.u0))
best = []
for _ in range(7):
    t = time.perf_counter(); jax.block_until_ready(ne(prep.problem, prep.u0)); best.append(time.perf_counter() - t)
ctfit.fit(d, st, starts=1)
t = time.perf_counter(); one = ctfit.fit(d, st, starts=1); one_s = time.perf_counter() - t
print(json.dumps(dict(first_s=first, second_s=second, cost=r.stats["cost"], normal_s=min(best), one_start_s=one_s, one_start_steps=one.stats["steps"])))
"""
TIMEOUT = 300.0
LLVM_CANDIDATES = ("/usr/lib/x86_64-linux-gnu/libLLVM-19.so", "/usr/lib/x86_64-linux-gnu/libLLVM-18.so", "/usr/lib/x86_64-linux-gnu/libLLVM-17.so")


class Bench:
    """The scratch folder, the environment of the children and the repetition count."""

    def __init__(self, tmp: Path, repeat: int):
        self.tmp, self.repeat = tmp, repeat
        self.env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
        self.count = 0

    def folder(self, name: str) -> Path:
        self.count += 1
        path = self.tmp / f"{name}-{self.count}"
        path.mkdir(parents=True)
        return path

    def ctfit(self, args: list[str], cache: Path, what: str, command: list[str] | None = None):
        """``ctfit ARGS`` (``command`` in place of ``ctfit``) with ``cache`` as its cache folder;
        (Run, parsed --json output or None). Exit status 1 (a fit did not converge) is a result,
        not a failure; a run is killed after ``TIMEOUT`` seconds (a hung process fails its case,
        not the benchmark)."""
        r = run([*(command or [CTFIT]), *args], env=dict(self.env, JAX_COMPILATION_CACHE_DIR=str(cache)), cwd=self.tmp, timeout=TIMEOUT)
        if r.returncode not in (0, 1):
            r.check(what)
        return r, (json.loads(r.stdout) if "--json" in args else None)

    def cold(self, args: list[str], what: str, command: list[str] | None = None):
        """A run with a fresh, empty cache folder (removed after); ``command`` in place of ``ctfit``."""
        cache = self.folder("cold-cache")
        try:
            return self.ctfit(args, cache, what, command)
        finally:
            shutil.rmtree(cache, ignore_errors=True)

    def backup(self, cache: Path) -> Path:
        """A copy of ``cache`` to put back later with :meth:`restore`. Only in place: JAX's
        cache keys include the folder's path, so a cache copied to another folder compiles again."""
        dest = self.folder("backup")
        shutil.copytree(cache, dest, dirs_exist_ok=True)
        return dest

    def restore(self, backup: Path, cache: Path) -> None:
        shutil.rmtree(cache)
        shutil.copytree(backup, cache)


# --------------------------------------------------------------------------- cases


def floor(b: Bench) -> dict:
    cmds = {"python": [PY, "-c", "pass"], "jax": [PY, "-c", JAX_FLOOR + LEAVE], "version": [CTFIT, "--version"]}
    times = {k: [] for k in cmds}
    for _ in range(b.repeat):
        for k, cmd in cmds.items():
            times[k].append(run(cmd, env=b.env).check(" ".join(cmd[:2])).wall_s)
    out = {k: median(v) for k, v in times.items()}
    print(f"floor: python {out['python']:.2f} s, bare JAX process {out['jax']:.2f} s, ctfit --version {out['version']:.2f} s", flush=True)
    return out


def scipy_start(path: Path, lobes: int, n_bands: int, diffuse: bool) -> Path:
    path.write_text(json.dumps({"x0": data.default_start_x0(lobes, n_bands, diffuse)}))
    return path


def scipy_run(b: Bench, start: Path, files: list[Path], grid: bool = False):
    cmd = [PY, str(SCRIPTS / "_scipy_fit.py"), str(start), *map(str, files), "--lobes", "2", "--diffuse", "--loss", "relative"]
    r = run(cmd + (["--grid"] if grid else []), env=b.env).check("the SciPy process")
    return r, [json.loads(line) for line in r.stdout.splitlines() if line.startswith("{")]


def _ctfit_params(doc: dict) -> dict:
    return dict(m=[lobe["m"] for lobe in doc["lobes"]], w=[lobe["weight"] for lobe in doc["lobes"]], s=doc["s"], f0=doc["F0"])


def recovery(p: dict) -> dict:
    """Errors against the scattered truth: max relative error of m, max |Δw|, |Δs|, max |ΔF0|."""
    m, w, f0 = (np.asarray(p[k], dtype=float) for k in ("m", "w", "f0"))
    order = np.argsort(m)
    m, w = m[order], w[order]
    return dict(m=float(np.max(np.abs(m / data.M_TRUE - 1))), w=float(np.max(np.abs(w - data.W_TRUE))), s=abs(p["s"] - data.S_TRUE),
                f0=float(np.max(np.abs(f0 - data.F0_TRUE))))


def primed_by(b: Bench, n: int, seed: int) -> Path:
    """A cache folder that one ``ctfit fit`` of an ``n``-sample scattered file filled (the same
    structure as the cases'): the cache of "warm from another size"."""
    folder = b.folder(f"prime-{n}")
    path = data.write_scattered(folder / f"scattered-{n}.csv", n, seed)
    cache = b.folder("primed-cache")
    b.ctfit(["fit", str(path), "--lobes", "2", "--family", "metal", "--diffuse", "F0/pi", "--loss", "relative", "--json", "-q"], cache,
            f"ctfit (priming with {n:,} samples)")
    return cache


CHEAPEST = [PY, str(SCRIPTS / "_cheapest_compile.py")]
"""``ctfit`` with every program at the cheapest compile effort (``_cheapest_compile.py``): a cold
run so bounds what compile options alone could gain."""


def scattered(b: Bench, n: int, new_n: int | None, seed: int, grid_peer: bool, primed_other: Path | None = None, cheapest: bool = False) -> dict:
    """SciPy against ctfit cold, warm, (``new_n``) on a file of another size, (``primed_other``)
    warm from a cache that a fit of another size filled, and (``cheapest``) cold with every
    program at the cheapest compile effort, one size."""
    folder = b.folder(f"scattered-{n}")
    path = data.write_scattered(folder / f"scattered-{n}.csv", n, seed)
    other = data.write_scattered(folder / f"scattered-{new_n}.csv", new_n, seed + 1) if new_n else None
    start = scipy_start(folder / "start.json", 2, len(data.WL31), True)
    args = ["fit", str(path), "--lobes", "2", "--family", "metal", "--diffuse", "F0/pi", "--loss", "relative", "--json", "-q"]
    warm_cache = b.folder("warm-cache")
    cold, first = b.ctfit(args, warm_cache, "ctfit (cold, priming)")  # the first cold run fills the warm cache
    primed = b.backup(warm_cache) if other else None
    from_other = b.folder("from-other-cache") if primed_other else None
    runs = {k: [] for k in ("scipy", "scipy_fit_s", "scipy_grid", "cold", "warm", "new", "other", "cold_fit_s", "warm_fit_s", "new_fit_s", "other_fit_s",
                            "read_floor", "cold_cheapest")}
    runs["cold"].append(cold.wall_s)
    runs["cold_fit_s"].append(first["fit"]["time_s"])
    res = {}
    for i in range(b.repeat):
        r, (sp,) = scipy_run(b, start, [path])
        runs["scipy"].append(r.wall_s)
        runs["scipy_fit_s"].append(sp["fit_s"])
        res["scipy"] = sp
        if grid_peer:
            r, (res["scipy_grid"],) = scipy_run(b, start, [path], grid=True)
            runs["scipy_grid"].append(r.wall_s)
        runs["read_floor"].append(run([PY, "-c", READ_FLOOR, str(path)], env=b.env).check("a bare JAX process reading the file").wall_s)
        r, res["warm"] = b.ctfit(args, warm_cache, "ctfit (warm)")
        runs["warm"].append(r.wall_s)
        runs["warm_fit_s"].append(res["warm"]["fit"]["time_s"])
        res["warm_peak_mb"] = r.peak_mb
        if i > 0:
            r, doc = b.cold(args, "ctfit (cold)")
            runs["cold"].append(r.wall_s)
            runs["cold_fit_s"].append(doc["fit"]["time_s"])
        if cheapest:
            runs["cold_cheapest"].append(b.cold(args, "ctfit (cold, cheapest compile)", CHEAPEST)[0].wall_s)
        if other:
            r, res["new"] = b.ctfit(["fit", str(other), "--lobes", "2", "--family", "metal", "--diffuse", "F0/pi", "--loss", "relative", "--json", "-q"],
                                    warm_cache, "ctfit (new size)")
            runs["new"].append(r.wall_s)
            runs["new_fit_s"].append(res["new"]["fit"]["time_s"])
            b.restore(primed, warm_cache)  # what the new size added is gone for the next round
        if primed_other:
            b.restore(primed_other, from_other)  # as the other size's fit left it, every round
            r, doc = b.ctfit(args, from_other, "ctfit (warm from another size)")
            runs["other"].append(r.wall_s)
            runs["other_fit_s"].append(doc["fit"]["time_s"])
    for _ in range(2):  # the first may store its own program (the library's key can differ from the command's)
        inproc = run([PY, "-c", IN_PROCESS, str(path)], env=dict(b.env, JAX_COMPILATION_CACHE_DIR=str(warm_cache))).check("ctfit.fit in process")
    out = {k: median(v) for k, v in runs.items() if v}
    out.update(n=n, new_n=new_n, in_process=json.loads(inproc.stdout.strip().splitlines()[-1]), scipy_cost=res["scipy"]["cost"],
               scipy_nfev=res["scipy"]["nfev"],
               ctfit_cost=res["warm"]["fit"]["cost"], ctfit_steps=res["warm"]["fit"]["steps"], converged=res["warm"]["fit"]["converged"],
               scipy_rec=recovery(res["scipy"]), ctfit_rec=recovery(_ctfit_params(res["warm"])), peak_mb=res["warm_peak_mb"],
               runs=len(runs["warm"]))
    if "scipy_grid" in res:
        out["scipy_grid_cost"] = res["scipy_grid"]["cost"]
    print(f"scattered {n:,}: SciPy {out['scipy']:.2f} s (cost {out['scipy_cost']:.10g}, {out['scipy_nfev']} evaluations)"
          + (f", SciPy on the grid {out['scipy_grid']:.2f} s" if "scipy_grid" in out else "")
          + f"; ctfit cold {out['cold']:.2f} s, warm {out['warm']:.2f} s (cost {out['ctfit_cost']:.10g}, {out['ctfit_steps']} steps, converged "
          f"{out['converged']})" + (f", new size ({new_n:,}) {out['new']:.2f} s" if other else "")
          + (f", warm from another size {out['other']:.2f} s (fit() {out['other_fit_s']:.2f} s)" if primed_other else "")
          + f"; in process: fit() {out['in_process']['first_s']:.2f} s then {out['in_process']['second_s']:.2f} s"
          + (f"; cold at the cheapest compile {out['cold_cheapest']:.2f} s" if cheapest else "")
          + f"; floor (bare JAX process reading the file) {out['read_floor']:.2f} s", flush=True)
    return out


def batch(b: Bench, n_files: int, n_samples: int, seed: int) -> dict:
    folder = b.folder("batch")
    files = data.write_batch(folder / "files", n_files, n_samples, seed)
    start = scipy_start(folder / "start.json", 2, len(data.WL31), True)
    cache = b.folder("batch-cache")
    args = ["fit", str(folder / "files"), "--lobes", "2", "--family", "metal", "--diffuse", "F0/pi", "--loss", "relative", "-q"]
    one = lambda: [*args, "--starts", "1", "-o", str(b.folder("batch-out-one"))]  # one start, as the SciPy loop; a new output folder each run
    b.ctfit([*args, "-o", str(b.folder("batch-out"))], cache, "ctfit fit DIR (priming)")
    b.ctfit(one(), cache, "ctfit fit DIR --starts 1 (priming)")
    alone = json.loads(run([PY, "-c", SOLVES_ALONE, str(folder / "files"), "32"], env=b.env).check("the solves alone").stdout.strip().splitlines()[-1])
    t_scipy, t_ctfit, t_floor, t_one, t_solve = [], [], [], [], []
    for _ in range(b.repeat):
        r, sp = scipy_run(b, start, files)
        t_scipy.append(r.wall_s)
        t_floor.append(run([PY, "-c", READ_DIR_FLOOR, str(folder / "files")], env=b.env).check("a bare JAX process reading the files").wall_s)
        t_solve.append(run([PY, "-c", READ_SOLVE_DIR, str(folder / "files")], env=dict(b.env, JAX_COMPILATION_CACHE_DIR=str(cache)))
                       .check("a process reading the files and solving them with fit_batch").wall_s)
        out = b.folder("batch-out")
        r, _ = b.ctfit([*args, "-o", str(out)], cache, "ctfit fit DIR")
        t_ctfit.append(r.wall_s)
        peak = r.peak_mb
        # What the default's two further seeds cost (they guard against a wrong basin on data the
        # model cannot represent; here they end where the first does).
        t_one.append(b.ctfit(one(), cache, "ctfit fit DIR --starts 1")[0].wall_s)
    docs = {p.stem: json.loads(p.read_text()) for p in sorted(out.glob("*.fit.json"))}
    sp_cost = {Path(x["file"]).stem: x["cost"] for x in sp}
    ct_cost = {k.split(".")[0]: d["fit"]["cost"] for k, d in docs.items()}
    rel = np.array([(ct_cost[k] - sp_cost[k]) / sp_cost[k] for k in sp_cost if k in ct_cost])
    conv = sum(bool(d["fit"]["converged"]) for d in docs.values())
    res = dict(files=n_files, samples=n_samples, scipy=median(t_scipy), ctfit=median(t_ctfit), one_start=median(t_one), read_floor=median(t_floor),
               read_and_solve=median(t_solve), solves_alone=alone,
               peak_mb=peak, results=len(docs), converged=conv,
               fit_s=sum(d["fit"]["time_s"] for d in docs.values()),
               same=int(np.sum(np.abs(rel) <= 1e-6)), ctfit_lower=int(np.sum(rel < -1e-6)), scipy_lower=int(np.sum(rel > 1e-6)),
               worst=float(np.max(np.abs(rel))) if rel.size else float("nan"))
    print(f"batch {n_files} × {n_samples:,}: SciPy loop {res['scipy']:.2f} s, ctfit fit DIR {res['ctfit']:.2f} s ({res['scipy'] / res['ctfit']:.1f}×), "
          f"with one start (--starts 1) {res['one_start']:.2f} s ({res['scipy'] / res['one_start']:.1f}×); "
          f"floor (bare JAX process reading the files) {res['read_floor']:.2f} s; reading and solving them with fit_batch, nothing written, "
          f"{res['read_and_solve']:.2f} s; "
          f"{res['results']} results, {conv} converged; cost equal (1e-6) in {res['same']}, lower for ctfit in {res['ctfit_lower']}, "
          f"for SciPy in {res['scipy_lower']}", flush=True)
    return res


def merl(b: Bench, pairs: int | None, seed: int) -> dict:
    folder = b.folder("merl")
    path = folder / "metal.binary"
    samples = data.write_merl_file(path, pairs, seed)
    args = ["fit", str(path), "--lobes", "1", "--no-diffuse", "--json", "-q"]
    cache = b.folder("merl-cache")
    cold, _ = b.ctfit(args, cache, "ctfit on the MERL file (priming)")
    walls, peaks = [], []
    for _ in range(b.repeat):
        r, doc = b.ctfit(args, cache, "ctfit on the MERL file")
        walls.append(r.wall_s)
        peaks.append(r.peak_mb)
    res = dict(samples=samples, pairs=samples // 3, cold=cold.wall_s, cold_peak_mb=cold.peak_mb, warm=median(walls), peak_mb=max(peaks),
               fit_s=doc["fit"]["time_s"], m=doc["lobes"][0]["m"], f0=doc["F0"], converged=doc["fit"]["converged"], steps=doc["fit"]["steps"])
    print(f"MERL-sized ({samples:,} samples): warm {res['warm']:.2f} s (fit() {res['fit_s']:.2f} s), peak {res['peak_mb']:.0f} MB; "
          f"cold {res['cold']:.2f} s, peak {res['cold_peak_mb']:.0f} MB; m = {res['m']:.5f}, F0 = {np.round(res['f0'], 4).tolist()}", flush=True)
    return res


def texels(n_texels: int, seed: int) -> dict:
    """Texels per second of ``ctfit.fit_batch(geometry, values=...)``, in this process."""
    import jax
    import jax.numpy as jnp

    import ctfit

    if not hasattr(ctfit, "fit_batch"):
        print("per-texel: skipped: ctfit.fit_batch not available", flush=True)
        return dict(skipped="ctfit.fit_batch not available")
    jax.config.update("jax_enable_x64", True)
    geometry, values, m, f0 = data.texel_case(n_texels, 67, seed)
    rows = []
    for dt in ("float32", "float64"):
        warmup = min(n_texels, 1024)
        t = time.perf_counter()
        ctfit.fit_batch(geometry, data.METAL, values=values[:warmup], dtype=getattr(jnp, dt))
        first = time.perf_counter() - t
        t = time.perf_counter()
        res = ctfit.fit_batch(geometry, data.METAL, values=values, dtype=getattr(jnp, dt))
        el = time.perf_counter() - t
        fm = np.asarray(res.params.m)[:, 0]
        ff = np.asarray(res.params.f0)
        rows.append(dict(dtype=dt, texels=n_texels, samples=values.shape[1], first_s=first, warmup=warmup, time_s=el, per_s=n_texels / el,
                         converged=float(np.mean(np.asarray(res.stats["converged"]))), m_err=float(np.median(np.abs(fm / m - 1))),
                         f0_err=float(np.median(np.max(np.abs(ff - f0), axis=1)))))
        r = rows[-1]
        print(f"per-texel {dt}: {n_texels:,} texels in {el:.2f} s = {r['per_s']:,.0f} texels/s (first call, {warmup} texels, compiling: {first:.2f} s); "
              f"converged {r['converged']:.1%}, median |Δm|/m {r['m_err']:.1e}, median max |ΔF0| {r['f0_err']:.1e}", flush=True)
    return dict(rows=rows)


def llvm_path() -> str | None:
    """Dr.Jit's libLLVM (≥ 17): DRJIT_LIBLLVM_PATH, else the first of LLVM_CANDIDATES present, else
    the one the ``bench`` extra installs into this environment's ``lib/`` (``make install-bench``;
    it finds its C++ runtime by its own run path), else None."""
    given = os.environ.get("DRJIT_LIBLLVM_PATH")
    if given:
        return given
    return next((p for p in (*LLVM_CANDIDATES, *_environment_llvm()) if os.path.exists(p)), None)


def _environment_llvm() -> list[str]:
    """``libLLVM.so.MAJOR.MINOR`` files of major ≥ 17 in ``sys.prefix/lib``, newest first."""
    found = []
    for path in Path(sys.prefix, "lib").glob("libLLVM.so.*"):
        major = path.name.removeprefix("libLLVM.so.").split(".")[0]
        if major.isdigit() and int(major) >= 17:
            found.append((int(major), str(path)))
    return [p for _, p in sorted(found, reverse=True)]


def mitsuba(b: Bench, n_pairs: int, seed: int) -> dict:
    """The Mitsuba peer against ctfit (warm), or ``skipped`` with the reason."""
    try:
        import mitsuba  # noqa: F401
    except ImportError as e:
        return _skip(f"mitsuba is not installed ({e})")
    llvm = llvm_path()
    if llvm is None:
        return _skip("Dr.Jit's LLVM backend needs libLLVM ≥ 17 (`make install-bench` installs one into the environment; or "
                     "`apt-get install libllvm19`, then DRJIT_LIBLLVM_PATH=/usr/lib/x86_64-linux-gnu/libLLVM-19.so); LLVM 14/15 abort "
                     "with \"Cannot select fmaximum\"")
    env = dict(b.env, DRJIT_LIBLLVM_PATH=llvm)
    folder = b.folder("mitsuba")
    try:
        case = data.mitsuba_case(folder, n_pairs, seed, env)
    except RuntimeError as e:
        return _skip(str(e))
    truth = case["truth"]
    import ctfit

    f0_true = np.asarray(truth["f0"])
    # ctfit twice: with Mitsuba's own (rational) G1 — the model that made the data — and with the exact one.
    runs = {g: (["fit", str(case["csv"]), "--fresnel", "conductor", "--geometry", g, "--no-diffuse", "--json", "-q"], b.folder(f"mitsuba-cache-{g}"))
            for g in ("smith-rational", "smith")}
    for g, (args, cache) in runs.items():
        b.ctfit(args, cache, f"ctfit --geometry {g} on Mitsuba's data (priming)")
    t_peer, t_ctfit, docs = [], {g: [] for g in runs}, {}
    for _ in range(b.repeat):
        r = run([PY, str(SCRIPTS / "_mitsuba_fit.py"), "fit", str(case["npz"])], env=env).check("the Mitsuba peer")
        t_peer.append(r.wall_s)
        peer = json.loads(r.stdout.strip().splitlines()[-1])
        for g, (args, cache) in runs.items():
            r, docs[g] = b.ctfit(args, cache, f"ctfit --geometry {g} on Mitsuba's data")
            t_ctfit[g].append(r.wall_s)

    def ours(g: str) -> dict:
        doc = docs[g]
        return dict(ctfit=median(t_ctfit[g]), ctfit_fit_s=doc["fit"]["time_s"], ctfit_df0=float(np.max(np.abs(np.asarray(doc["F0"]) - f0_true))),
                    ctfit_da=abs(doc["lobes"][0]["m"] / truth["alpha"] - 1), converged=doc["fit"]["converged"], steps=doc["fit"]["steps"])

    peer_f0 = np.asarray(ctfit.f0_from_nk(np.asarray(peer["eta"]), np.asarray(peer["k"])), dtype=float)
    res = dict(pairs=n_pairs, truth=truth, peer=median(t_peer), peer_fit_s=peer["fit_s"], peer_df0=float(np.max(np.abs(peer_f0 - f0_true))),
               peer_da=abs(peer["alpha"] / truth["alpha"] - 1), llvm=Path(llvm).name, **ours("smith-rational"), exact=ours("smith"))
    for label, r in (("smith-rational", res), ("smith (exact G1)", res["exact"])):
        print(f"Mitsuba ({n_pairs:,} pairs × RGB): peer {res['peer']:.2f} s (max |ΔF0| {res['peer_df0']:.1e}, |Δα|/α {res['peer_da']:.1e}); "
              f"ctfit --geometry {label} {r['ctfit']:.2f} s (max |ΔF0| {r['ctfit_df0']:.1e}, |Δα|/α {r['ctfit_da']:.1e}, {r['steps']} steps)", flush=True)
    return res


def _skip(reason: str) -> dict:
    print(f"Mitsuba peer: skipped: {reason}", flush=True)
    return dict(skipped=reason)


# --------------------------------------------------------------------------- report


def _s(x: float) -> str:
    return f"{x:.2f} s"


def _ratio(x: float) -> str:
    return f"{x:.1f}×" if x >= 1 else f"{x:.2f}×"


def _step_s(c: dict) -> float:
    """Seconds per step of the one-start fit measured in process."""
    ip = c["in_process"]
    return ip["one_start_s"] / max(ip["one_start_steps"], 1)


def _step_ratio(c: dict) -> float:
    return _step_s(c) / c["in_process"]["normal_s"]


def targets(fl: dict, cases: list[dict], bat: dict | None, mer: dict | None, mit: dict | None) -> list[tuple[str, str, str, str]]:
    """(target, measured, met, what dominates) rows for the targets of issue 11 this run measured."""
    rows = []

    def split(c):
        """The warm process's wall time in four parts (they add up to it): the bare JAX process,
        the rest of start-up and output, fit()'s set-up and loading of the stored program, the solve
        (a second ``fit`` call in one process); the largest named first."""
        solve = min(c["in_process"]["second_s"], c["warm_fit_s"])
        parts = {"the bare JAX process": min(fl["jax"], c["warm"] - c["warm_fit_s"]), "the rest of start-up (imports, reading, output)":
                 max(c["warm"] - c["warm_fit_s"] - fl["jax"], 0.0), "fit()'s set-up and loading the stored program": c["warm_fit_s"] - solve,
                 "the solve": solve}
        name = max(parts, key=parts.get)
        return (f"{name}: {parts[name]:.2f} s of {c['warm']:.2f} s "
                "(") + ", ".join(f"{k.removeprefix('the ')} {v:.2f} s" for k, v in parts.items() if k != name) + ")"

    def failed(target, case):
        if case is not None and "failed" in case:
            rows.append((target, "—", f"not measured: {case['failed']}", ""))
            return True
        return case is None

    big, small = max(c["n"] for c in cases), min(c["n"] for c in cases)
    for c in cases:
        goal = 10.0 if c["n"] >= 100_000 else 2.0
        if c["n"] not in (big, small) or (goal == 10.0 and c["n"] != big):
            continue
        target = f"{c['n']:,} scattered samples, warm: ≥ {goal:g}× SciPy"
        if failed(target, c):
            continue
        sp, need = c["scipy"] / c["warm"], c["scipy"] / goal
        rows.append((target, f"{_ratio(sp)} ({_s(c['warm'])} vs {_s(c['scipy'])})",
                     "yes" if sp >= goal else f"no: needs ≤ {_s(need)}, {c['warm'] - need:.2f} s over", "" if sp >= goal else split(c)))
    c = next(c for c in cases if c["n"] == small)
    if not failed(f"{small:,}, cold: ≤ 1.5× SciPy's time", c):
        r = c["cold"] / c["scipy"]
        rows.append((f"{small:,}, cold: ≤ 1.5× SciPy's time", f"{_ratio(r)} ({_s(c['cold'])} vs {_s(c['scipy'])})",
                     "yes" if r <= 1.5 else f"no: {c['cold'] - 1.5 * c['scipy']:.2f} s over",
                     "" if r <= 1.5 else f"tracing and compiling: fit() takes {c['cold_fit_s'] - c['warm_fit_s']:.2f} s longer than warm"))
        if "new" in c:
            d = c["new"] - c["warm"]
            rows.append((f"new sample count ({c['new_n']:,}): within 0.3 s of warm", f"{d:+.2f} s ({_s(c['new'])} vs {_s(c['warm'])})",
                         "yes" if d <= 0.3 else f"no: {d - 0.3:.2f} s over", "" if d <= 0.3 else
                         f"fit(): {c['new_fit_s']:.2f} s against {c['warm_fit_s']:.2f} s warm"))
    c = next(c for c in cases if c["n"] == big)
    if "failed" not in c:
        r = _step_ratio(c)
        rows.append((f"one LM step ≤ 3× one residual + JᵀJ evaluation ({big:,} samples)", f"{r:.2f}×", "yes" if r <= 3 else "no", ""))
    target = f"{(bat or {}).get('files')} files × 2,000 samples, one process: ≥ 20× a SciPy loop"
    if not failed(target, bat):
        r = bat["scipy"] / bat["ctfit"]
        rows.append((target, f"{_ratio(r)} ({_s(bat['ctfit'])} vs {_s(bat['scipy'])})", "yes" if r >= 20 else f"no: needs ≤ {_s(bat['scipy'] / 20)}",
                     "" if r >= 20 else f"the batched fits: {bat['fit_s']:.2f} s of `fit_batch` calls, two windows of files at once, "
                     f"in a process of {bat['ctfit']:.2f} s (the files' reading and writing overlap them)"))
    target = "MERL-sized: ≤ 5 s warm, ≤ 600 MB peak"
    if not failed(target, mer):
        mb = mer["peak_mb"]
        ok_t, ok_m = mer["warm"] <= 5.0, mb <= 600
        over = [x for x, ok in ((f"{mer['warm'] - 5:.2f} s over", ok_t), (f"{mb - 600:.0f} MB over", ok_m)) if not ok]
        rows.append((f"MERL-sized ({mer['samples']:,} samples): ≤ 5 s warm, ≤ 600 MB peak", f"{_s(mer['warm'])}, {mb:.0f} MB",
                     "yes" if not over else "no: " + ", ".join(over), "" if ok_t else f"fit(): {mer['fit_s']:.2f} s of {mer['warm']:.2f} s"))
    target = "Mitsuba peer: faster as a whole process, at ≥ 10× its accuracy (ctfit with Mitsuba's G1)"
    if mit is not None and "skipped" not in mit and not failed(target, mit):
        fast = mit["ctfit"] < mit["peer"]
        acc_f0, acc_a = mit["peer_df0"] / max(mit["ctfit_df0"], 1e-300), mit["peer_da"] / max(mit["ctfit_da"], 1e-300)
        bad = [x for x, good in (("slower", fast), (f"α only {acc_a:.1f}× as accurate", acc_a >= 10),
                                 (f"F0 only {acc_f0:.1f}× as accurate", acc_f0 >= 10)) if not good]
        rows.append((target, f"peer / ctfit time {_ratio(mit['peer'] / mit['ctfit'])} ({_s(mit['ctfit'])} vs {_s(mit['peer'])}); errors of the peer / "
                     f"ctfit: F0 {acc_f0:.0f}×, α {acc_a:.0f}×", "yes" if not bad else "no: " + ", ".join(bad), ""))
    return rows


def targets_21(fl: dict, cases: list[dict], bat: dict | None) -> list[tuple[str, str, str, str]]:
    """(target, measured, met, floor) rows of issue 21's targets this run measured. The floor is
    what no run of the case can go below here, from this run's figures: the bare JAX process
    and reading the file (a process that does only that); first on a machine, the row says how
    much of ctfit's time above it is compiling (cold fit() − warm fit()), which is ctfit's own and
    no floor; where the floor caps a target, the row says so."""
    rows = []

    def ratio_row(target, ours, peer, goal, floor: float, floor_text: str, above: str = ""):
        r = peer / ours
        cap = f"; the floor ({_s(floor)}) allows at most {peer / floor:.2f}×" if peer / floor < goal else ""
        rows.append((target, f"{_ratio(r)} ({_s(ours)} vs {_s(peer)})", "yes" if r >= goal else f"no: needs ≤ {_s(peer / goal)}{cap}",  # (a met target
                     # has no cap: a floor measured in a noisy moment above the run itself said both)
                     f"{floor_text}: {_s(floor)}; ctfit {ours - floor:.2f} s above it{above}"))

    def read_floor(c) -> tuple[float, str]:
        if "read_floor" in c:
            return c["read_floor"], "bare JAX process reading the file"
        return fl["jax"], "bare JAX process"

    for c in cases:
        if "failed" in c or "other" not in c:
            continue
        goal = 10.0 if c["n"] >= 100_000 else 1.5
        ratio_row(f"{c['n']:,} samples, warm from another size: ≥ {goal:g}× the SciPy script", c["other"], c["scipy"], goal, *read_floor(c))
    small = [c for c in cases if "failed" not in c]
    if small:
        c = min(small, key=lambda c: c["n"])
        compiling = max(c["cold_fit_s"] - c["warm_fit_s"], 0.0)
        cheapest = (f"; with every program at the cheapest compile effort (slower programs) a cold run still takes {_s(c['cold_cheapest'])}, "
                    f"{c['scipy'] / c['cold_cheapest']:.2f}× the SciPy script") if "cold_cheapest" in c else ""
        ratio_row(f"{c['n']:,} samples, first run on a machine (cold): ≥ 0.67× the SciPy script", c["cold"], c["scipy"], 0.67, *read_floor(c),
                  f", {compiling:.2f} s of it compiling ctfit's programs (cold fit() − warm fit()){cheapest}")
    if bat and "failed" not in bat:
        calls = f" (its `fit_batch` calls, two windows of files at once, take {_s(bat['fit_s'])} in all: the solves and each file's report)"
        if "read_floor" in bat:
            floor_at, what = bat["read_floor"], f"bare JAX process reading the {bat['files']} files one after another{calls}"
        else:
            floor_at, what = fl["jax"], f"bare JAX process{calls}"
        solves = (f"; a process that only reads the files and solves them (`fit_batch`, 64 a call, nothing printed or written) takes "
                  f"{_s(bat['read_and_solve'])}: ctfit fit DIR is {bat['ctfit'] - bat['read_and_solve']:+.2f} s from it, and the SciPy loop / that "
                  f"process is {bat['scipy'] / bat['read_and_solve']:.1f}×") if "read_and_solve" in bat else ""
        ratio_row(f"{bat['files']} files × {bat['samples']:,} samples, one process: ≥ 20× the SciPy loop", bat["ctfit"], bat["scipy"], 20.0,
                  floor_at, what, solves + _solves_floor(fl, bat))
    return rows


def _solves_floor(fl: dict, bat: dict) -> str:
    """What the many files cost with their solves as they are (``SOLVES_ALONE``; the solves are
    ctfit's own, no floor): the bare JAX process, then reading and solving shared out over every
    core at once, with 3 seeds (the default) and with 1."""
    if "solves_alone" not in bat:
        return ""
    a, cores = bat["solves_alone"], os.cpu_count() or 1
    at = {k: fl["jax"] + (a["read_cpu_s"] + a[f"solve_cpu_s_{k}"]) / cores for k in (3, 1)}
    need = bat["scipy"] / 20.0
    side = lambda k: "above" if at[k] > need else "below"
    return (f". Reading the files takes {a['read_cpu_s']:.2f} CPU-s, their compiled solves alone (`fit_core`, one file a call) "
            f"{a['solve_cpu_s_3']:.2f} CPU-s with 3 seeds and {a['solve_cpu_s_1']:.2f} with 1: with the solves as they are, shared out over "
            f"the {cores} cores after the bare JAX process, no run goes below {_s(at[3])} with 3 seeds ({side(3)} the {_s(need)} that 20× needs) "
            f"or {_s(at[1])} with 1 ({side(1)} it; `--starts 1` took {_s(bat['one_start'])})")


def section(args, fl, cases, bat, mer, tex, mit, started: float, changed: bool) -> str:
    import jax
    import scipy

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    cpu = cpu_name()
    reps = args.repeat
    L = [SECTION, "",
         f"`scripts/bench_fit.py{' --small' if args.small else ''} --repeat {reps}` ({datetime.date.today().isoformat()}; {os.cpu_count()}-core "
         f"{cpu}, shared with other jobs: load average {load:.1f} at the end; Python {platform.python_version()}, JAX {jax.__version__} on CPU, NumPy "
         f"{np.__version__}, SciPy {scipy.__version__}; the run took {(time.perf_counter() - started) / 60:.0f} min). Every time is a **whole process** "
         f"(interpreter start to exit, measured from outside), {'the median of ' + str(reps) + ' runs' if reps > 1 else 'one run'}; the columns of a case "
         "alternate run by run. ctfit runs "
         "as users run it, `ctfit fit FILE`, float64, with its cache folder (`JAX_COMPILATION_CACHE_DIR`: JAX's compilation cache and "
         "ctfit's store of compiled fit programs) empty (**cold**: a new folder for every run, the first run on a machine) or filled by an "
         "earlier run (**warm**). SciPy runs as its users would write it: a process that reads the same CSV with NumPy and calls "
         "`scipy.optimize.least_squares(method=\"lm\")` (MINPACK, finite-difference Jacobian, default tolerances) on a NumPy "
         "implementation of the same model and loss (`scripts/_numpy_model.py`; every sample its own F, as the data is scattered), "
         "started from ctfit's default start (m = 0.1, 0.3; w = ½, ½; F0 = 0.5; s = 0.5 — the point ctfit's own grid seeding starts "
         "from; ctfit's seeding and its 3 raced starts are inside its time). **New size**: a file of another sample count with the cache "
         "as the first run left it (put back in place after each such run). **Warm from another size**: the cache as one fit of a file of "
         "another size (same structure) left it; the fit's programs do not depend on the data's size (`ctfit/_fitting/chunked_fit.py`)."]
    if changed:
        L += ["", "**Warning: ctfit's source changed during this run, so warm runs may have compiled again; these figures are not reliable.**"]
    L += ["", "Floor — what any process of each kind costs here:", "", "| process | wall time |", "|---|---|",
          f"| Python interpreter alone (`python -c pass`) | {_s(fl['python'])} |",
          f"| bare JAX process (import JAX, start its CPU backend, leave at once: `os._exit`, as `ctfit` does) | {_s(fl['jax'])} |",
          f"| `ctfit --version` | {_s(fl['version'])} |", ""]
    L += ["### Scattered samples", "",
          "Every row its own direction pair, one of 31 bands (400–700 nm) at random; two lobes (m = 0.2, 0.4; w = 0.6, 0.4), s = 0.9 with "
          "R_d = F0/π, F0 0.5 → 0.95, 2 % noise, relative loss (`ctfit fit FILE --lobes 2 --loss relative`: the same least-squares problem as the SciPy "
          "peer).", ""]
    L += [f"Failed, {c['n']:,} samples: {c['failed']}" for c in cases if "failed" in c]
    ok = [c for c in cases if "failed" not in c]
    L += ["| | " + " | ".join(f"{c['n']:,} samples" for c in ok) + " |", "|---|" + "---|" * len(ok)] if ok else []

    def row(label, fn):
        if ok:
            L.append(f"| {label} | " + " | ".join(fn(c) for c in ok) + " |")

    row("SciPy, whole process", lambda c: _s(c["scipy"]) + f" (fit {c['scipy_fit_s']:.2f} s, {c['scipy_nfev']} evaluations)")
    if any("scipy_grid" in c for c in ok):
        row("SciPy, F computed on the whole pair × band grid (31× the Fresnel work; the NumPy model behind the issue's 2.1–2.7 s)",
            lambda c: _s(c["scipy_grid"]) if "scipy_grid" in c else "—")
    row("ctfit, cold", lambda c: _s(c["cold"]) + f" (fit() {c['cold_fit_s']:.2f} s)")
    row("ctfit, cold, every program at the cheapest compile effort (`scripts/_cheapest_compile.py`)",
        lambda c: _s(c["cold_cheapest"]) if "cold_cheapest" in c else "—")
    row("ctfit, warm", lambda c: _s(c["warm"]) + f" (fit() {c['warm_fit_s']:.2f} s; peak {c['peak_mb']:.0f} MB)")
    row("ctfit, new sample count, warm cache", lambda c: f"{_s(c['new'])} ({c['new_n']:,} samples)" if "new" in c else "—")
    row("ctfit, warm from another size (the cache one fit of another file size left)",
        lambda c: f"{_s(c['other'])} (fit() {c['other_fit_s']:.2f} s; cache from {c['prime_n']:,} samples)" if "other" in c else "—")
    row("in one warm process: `ctfit.fit` first call (loads the stored program) / second "
        "call", lambda c: f"{c['in_process']['first_s']:.2f} s / {c['in_process']['second_s']:.2f} s")
    row("one Levenberg–Marquardt step (a one-start fit's time / its steps) / one evaluation of residual, Jᵀr and JᵀJ alone",
        lambda c: f"{_step_ratio(c):.2f}× ({_step_s(c) * 1e3:.1f} ms / {c['in_process']['normal_s'] * 1e3:.1f} ms)")
    row("speed-up, warm (SciPy / ctfit)", lambda c: _ratio(c["scipy"] / c["warm"]))
    row("cold / SciPy", lambda c: _ratio(c["cold"] / c["scipy"]))
    row("final cost ½‖r‖², SciPy", lambda c: f"{c['scipy_cost']:.10g}")
    row("final cost ½‖r‖², ctfit", lambda c: f"{c['ctfit_cost']:.10g}")
    row("errors, SciPy: m (rel.), w, s, F0 (max abs.)", lambda c: "{m:.1e}, {w:.1e}, {s:.1e}, {f0:.1e}".format(**c["scipy_rec"]))
    row("errors, ctfit", lambda c: "{m:.1e}, {w:.1e}, {s:.1e}, {f0:.1e}".format(**c["ctfit_rec"]))
    if bat and "failed" in bat:
        L += ["", "### Many files", "", f"Failed: {bat['failed']}."]
    elif bat:
        L += ["", "### Many files", "",
              f"{bat['files']} files × {bat['samples']:,} scattered samples of one geometry (each its own truth and noise): one `ctfit fit DIR -o OUT "
              "--lobes 2` process (warm) against one SciPy process looping over the files. SciPy solves from one start; ctfit from "
              "three seeds by default, each to convergence (they guard against a wrong basin on real materials, docs/fitting.md); "
              "with `--starts 1` (one seed, as SciPy) it is timed too. **Read and solve**: a process written the plain way with the library "
              "(read each file, `ctfit.fit_batch` 64 files a call, the same warm cache) that prints and writes nothing: what the command "
              "costs without its outputs.", "",
              "| SciPy loop | ctfit fit DIR | read and solve | files per second (SciPy / ctfit) | speed-up | ctfit `--starts 1` (speed-up) | "
              "ctfit peak memory | results | same cost (10⁻⁶) | lower cost: ctfit / SciPy |", "|---|---|---|---|---|---|---|---|---|---|",
              f"| {_s(bat['scipy'])} | {_s(bat['ctfit'])} | {_s(bat['read_and_solve']) if 'read_and_solve' in bat else '—'} | "
              f"{bat['files'] / bat['scipy']:.1f} / {bat['files'] / bat['ctfit']:.1f} | "
              f"{_ratio(bat['scipy'] / bat['ctfit'])} | {_s(bat['one_start'])} ({_ratio(bat['scipy'] / bat['one_start'])}) | "
              f"{bat['peak_mb']:.0f} MB | {bat['results']} "
              f"({bat['converged']} converged) | {bat['same']} | {bat['ctfit_lower']} / {bat['scipy_lower']} |"]
    if mer and "failed" in mer:
        L += ["", "### MERL-sized", "", f"Failed: {mer['failed']}."]
    elif mer:
        L += ["", "### MERL-sized", "",
              f"A MERL `.binary` table of a one-lobe RGB metal (m = 0.15, F0 = 0.9, 0.7, 0.5, 2 % noise), {mer['pairs']:,} cells measured "
              f"(× R, G, B = {mer['samples']:,} "
              f"samples{'; a full table has 1,096,216 cells above the horizon' if mer['pairs'] < 1_000_000 else ', every cell above the horizon'}): "
              "`ctfit fit FILE --lobes 1 --no-diffuse`.", "",
              "| run | wall time | fit() | peak memory | m | F0 (R, G, B) | converged |", "|---|---|---|---|---|---|---|",
              f"| warm | {_s(mer['warm'])} | {mer['fit_s']:.2f} s | {mer['peak_mb']:.0f} MB | {mer['m']:.5f} | {', '.join(f'{x:.4f}' for x in mer['f0'])} | "
              f"{mer['converged']} |",
              f"| cold | {_s(mer['cold'])} | | {mer['cold_peak_mb']:.0f} MB | | | |"]
    L += ["", "### Per texel", ""]
    if tex is None or "skipped" in tex or "failed" in tex:
        L.append(f"Failed: {tex['failed']}." if tex and "failed" in tex else f"Skipped: {tex['skipped'] if tex else 'not run (--no-texels)'}.")
    else:
        r0 = tex["rows"][0]
        L += [f"`ctfit.fit_batch(geometry, values=...)` in one process: {r0['texels']:,} texels × {r0['samples']} samples (67 direction pairs × R, G, B), "
              "one lobe, no diffuse part, F0 per channel; each texel its own m (0.1–0.3) and F0 (0.3–0.95), 2 % noise. Time of a call after a first, "
              f"compiling one on {r0['warmup']:,} texels.", "",
              "| dtype | texels per second | time | first call (compiles) | converged | median rel. error of m | median max ΔF0 "
              "|", "|---|---|---|---|---|---|---|"]
        for r in tex["rows"]:
            L.append(f"| {r['dtype']} | {r['per_s']:,.0f} | {_s(r['time_s'])} | {_s(r['first_s'])} | {r['converged']:.1%} | {r['m_err']:.1e} | "
                     f"{r['f0_err']:.1e} |")
    L += ["", "### Against Mitsuba 3", ""]
    if mit is None or "skipped" in mit or "failed" in mit:
        L.append(f"Failed: {mit['failed']}." if mit and "failed" in mit else f"Skipped: {mit['skipped'] if mit else 'not run (--no-mitsuba)'}.")
    else:
        t = mit["truth"]
        L += [f"{mit['pairs']:,} direction pairs × RGB rendered by Mitsuba's `roughconductor` (Beckmann, copper: Mitsuba's η = "
              f"{', '.join(f'{x:.3f}' for x in t['eta'])}, k = {', '.join(f'{x:.3f}' for x in t['k'])}, α = 0.15; {t['zeros']:.0%} of the values exactly 0). "
              "The peer is the graphics community's own way to fit it: Dr.Jit autodiff through the same BSDF (`llvm_ad_rgb`, float32), "
              "`mi.ad.Adam(lr=0.05)`, log loss, 1,000 iterations, α, η and k free, started from α = 0.3, η = 1.5, k = 2 "
              f"(`scripts/_mitsuba_fit.py`; {mit['llvm']}). ctfit: `ctfit fit FILE --fresnel conductor --geometry G --no-diffuse` (warm), with "
              "`smith-rational` — Walter et al.'s rational G1, which Mitsuba evaluates, so both sides fit the model that made the data — and with "
              "`smith`, the exact G1 (up to 0.31 % per factor away from Mitsuba's: a model difference, not a solver error).", "",
              "| | whole process | fit | max ΔF0 over R, G, B | relative α error |", "|---|---|---|---|---|",
              f"| Mitsuba + Dr.Jit + Adam | {_s(mit['peer'])} | {mit['peer_fit_s']:.2f} s | {mit['peer_df0']:.1e} | {mit['peer_da']:.1e} |",
              f"| ctfit `--geometry smith-rational` | {_s(mit['ctfit'])} | {mit['ctfit_fit_s']:.2f} s | {mit['ctfit_df0']:.1e} | {mit['ctfit_da']:.1e} |",
              f"| ctfit `--geometry smith` (exact G1) | {_s(mit['exact']['ctfit'])} | {mit['exact']['ctfit_fit_s']:.2f} s | {mit['exact']['ctfit_df0']:.1e} | "
              f"{mit['exact']['ctfit_da']:.1e} |"]
    L += ["", "### Targets (issue 11)", "", "| target | measured | met | what dominates |", "|---|---|---|---|"]
    L += [f"| {a} | {b} | {c} | {d} |" for a, b, c, d in targets(fl, cases, bat, mer, mit)]
    L += ["", "### Targets (issue 21: one compiled fit per structure, whatever the data size)", "",
          "| target | measured | met | floor (what no run of it goes below here) |", "|---|---|---|---|"]
    L += [f"| {a} | {b} | {c} | {d} |" for a, b, c, d in targets_21(fl, cases, bat)]
    L += ["", f"The floor caps a whole process: no ctfit run can be shorter than the bare JAX process ({_s(fl['jax'])} here) and the reading of "
          f"its file, so a speed-up target of k× over a SciPy process of T seconds is out of reach whenever T/k is below it."]
    return "\n".join(L) + "\n"


def cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _source_digest() -> str:
    h = hashlib.sha256()
    for p in sorted((ROOT / "ctfit").glob("*.py")):
        h.update(p.read_bytes())
    return h.hexdigest()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", "--small", dest="small", action="store_true", help="small version (2,000 samples, 8 files, MERL 100,000 pairs, 64 texels, "
                                                                                  "no Mitsuba)")
    ap.add_argument("--repeat", type=int, default=None, help="runs per figure (median); default 3, 1 with --small")
    ap.add_argument("--no-merl", action="store_true", help="skip the MERL-sized case")
    ap.add_argument("--no-batch", action="store_true", help="skip the many-files case")
    ap.add_argument("--no-texels", action="store_true", help="skip the per-texel case")
    ap.add_argument("--no-mitsuba", action="store_true", help="skip the Mitsuba peer")
    ap.add_argument("--docs", type=Path, help=f"write the section {SECTION!r} of DIR/benchmarks.md")
    args = ap.parse_args(argv)
    args.repeat = args.repeat or (1 if args.small else 3)
    started, digest = time.perf_counter(), _source_digest()
    byte_compile()  # as an installed ctfit is (_whole_process.byte_compile)
    import jax

    jax.config.update("jax_enable_x64", True)
    print(f"machine: {cpu_name()}, {os.cpu_count()} CPUs; python {platform.python_version()}, jax {jax.__version__}; {args.repeat} runs per figure", flush=True)
    with tempfile.TemporaryDirectory(prefix="ctfit-bench-fit-") as tmp:
        b = Bench(Path(tmp), args.repeat)
        fl = floor(b)
        sizes = [(2_000, 1_900)] if args.small else [(20_000, 19_000), (200_000, None)]
        prime = 5_000 if args.small else 50_000
        primed = attempt(f"priming with {prime:,} samples", lambda: {"cache": primed_by(b, prime, seed=11)})
        cases = [attempt(f"scattered {n:,}", scattered, b, n, new, seed=1 + i, grid_peer=not args.small and n <= 20_000, primed_other=primed.get("cache"),
                         cheapest=i == 0) | {"n": n, "prime_n": prime} for i, (n, new) in enumerate(sizes)]
        n_files = 8 if args.small else 256
        bat = None if args.no_batch else {"files": n_files} | attempt("many files", batch, b, n_files, 2_000, seed=7)
        mer = None if args.no_merl else attempt("MERL-sized", merl, b, 100_000 if args.small else None, seed=2)
        tex = None if args.no_texels else attempt("per texel", texels, 64 if args.small else 100_000, seed=3)
        if args.no_mitsuba:
            mit = None
        elif args.small:
            mit = _skip("not in --small (Dr.Jit's compile and 1,000 iterations are the full run's business)")
        else:
            mit = attempt("Mitsuba", mitsuba, b, 20_000, seed=4)
    changed = _source_digest() != digest
    if changed:
        print("warning: ctfit's source changed during the run: warm figures may include compiling", flush=True)
    text = section(args, fl, cases, bat, mer, tex, mit, started, changed)
    print(text)
    if args.docs:
        from _docs import write_section

        write_section(args.docs / "benchmarks.md", SECTION, text)
    return 1 if any("failed" in (c or {}) for c in (*cases, bat, mer, tex, mit)) else 0


def attempt(what: str, fn, *args, **kwargs) -> dict:
    """``fn(*args, **kwargs)``, or ``{"failed": reason}`` (printed) when it raises: one case that
    fails or hangs (killed at the time limit) does not cost the others."""
    try:
        return fn(*args, **kwargs)
    except Exception as e:  # reported in the section, and in the exit status
        reason = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        print(f"{what}: failed: {reason}", flush=True)
        return dict(failed=reason)


if __name__ == "__main__":
    sys.exit(main())
