"""The compile time of each program of a fit, and what a first run on a machine pays for several
structures; writes the section "## Compiled programs" of ``docs/benchmarks.md`` with ``--docs DIR``.

Two fresh processes, each fitting the same small scattered file (2,000 samples, 31 bands) with
every candidate structure in turn (``STRUCTURES``: the metal and plastic families, 1–3 lobes,
the diffuse forms), both with one cache folder (``JAX_COMPILATION_CACHE_DIR``): the first
starts with it empty (the first run on a machine: every program is compiled and stored), the
second finds it filled (compiled before: the programs are loaded). Per program, the XLA compile
time (JAX's ``/jax/core/compile/backend_compile_duration`` event, with the program's name) of
the first process; per structure, the fit's wall time in both.

Run: ``.venv/bin/python scripts/compile_times.py [--docs DIR]``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = ROOT / "scripts"
sys.path.insert(0, str(SCRIPTS))
SECTION = "## Compiled programs"
STRUCTURES = [
    dict(lobes=1, diffuse="F0/pi"), dict(lobes=2, diffuse="F0/pi"), dict(lobes=3, diffuse="F0/pi"),
    dict(lobes=1, diffuse=None), dict(lobes=2, diffuse=None), dict(lobes=1, diffuse=None, fresnel="conductor"),
    dict(lobes=1, diffuse="spectrum"), dict(lobes=2, diffuse="spectrum"), dict(lobes=1, diffuse="constant"),
]
CHILD = r"""
import json, re, sys, time, collections
import jax
jax.config.update("jax_enable_x64", True)
import ctfit
ctfit.enable_compilation_cache()
compiles = collections.defaultdict(list)
def listener(event, duration, **kw):
    if event == "/jax/core/compile/backend_compile_duration":
        compiles[re.sub(r"_[0-9a-f]{16}(?=\)?$)", "", kw.get("fun_name", "?"))].append(duration)  # a stored program's name ends in its key
jax.monitoring.register_event_duration_secs_listener(listener)
data = ctfit.read_measurement(sys.argv[1])
rows = []
for spec in json.loads(sys.argv[2]):
    before = {k: len(v) for k, v in compiles.items()}
    t = time.perf_counter()
    res = ctfit.fit(data, ctfit.Structure(**spec))
    rows.append(dict(structure=spec, time_s=time.perf_counter() - t, converged=res.converged,
                     compiled=sum(len(v) - before.get(k, 0) for k, v in compiles.items())))
print(json.dumps(dict(rows=rows, compiles={k: v for k, v in compiles.items()})))
"""


def _child(path: Path, cache: Path) -> tuple[dict, float]:
    env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=str(cache))
    t = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", CHILD, str(path), json.dumps(STRUCTURES)], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1]), time.perf_counter() - t


def _label(spec: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in spec.items())


def section(first: dict, first_s: float, again: dict, again_s: float) -> str:
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    L = [SECTION, "",
         f"`scripts/compile_times.py` (2,000 scattered samples × 31 bands; {os.cpu_count()} cores shared with other jobs, load average {load:.1f}). "
         f"One process fits {len(STRUCTURES)} structures in turn with an empty cache folder (the first run on a machine), a second with the "
         "folder the first filled. Every program depends on the structure (and bands and dtype), none on the number of samples "
         "(`ctfit/_fitting/chunked_fit.py`); `lm_init` and `lm_step` depend only on the number of parameters.", "",
         "| program | compilations | compile time each (median) | in all |", "|---|---|---|---|"]
    for name, times in sorted(first["compiles"].items(), key=lambda kv: -sum(kv[1])):
        times = sorted(times)
        L.append(f"| `{name}` | {len(times)} | {times[len(times) // 2]:.2f} s | {sum(times):.2f} s |")
    L += ["", "| structure | first run: fit (programs compiled) | compiled before: fit (programs compiled) |", "|---|---|---|"]
    for a, b in zip(first["rows"], again["rows"]):
        L.append(f"| {_label(a['structure'])} | {a['time_s']:.2f} s ({a['compiled']}) | {b['time_s']:.2f} s ({b['compiled']}) |")
    L += ["", f"Whole processes: first run {first_s:.1f} s, compiled before {again_s:.1f} s, for all {len(STRUCTURES)} structures."]
    return "\n".join(L) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--docs", type=Path, help=f"write the section {SECTION!r} of DIR/benchmarks.md")
    args = ap.parse_args(argv)
    import _bench_fit_data as data

    with tempfile.TemporaryDirectory(prefix="ctfit-compile-times-") as tmp:
        path = data.write_scattered(Path(tmp) / "scattered.csv", 2_000, 5)
        cache = Path(tmp) / "cache"
        first, first_s = _child(path, cache)
        again, again_s = _child(path, cache)
    text = section(first, first_s, again, again_s)
    print(text)
    if args.docs:
        from _docs import write_section

        write_section(args.docs / "benchmarks.md", SECTION, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
