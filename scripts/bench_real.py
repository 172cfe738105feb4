"""Fits of data the Cook–Torrance model cannot represent exactly: ctfit's default fit against the
best fit an exhaustive search finds and against two peers; writes the section "## Results" of
``docs/real-materials.md`` with ``--docs DIR``.

Data: every file of ``measurements/testbed/`` (Mitsuba 3 BSDFs that are not this model,
``measurements/testbed/README.md``) and the three real ALTA files of ``measurements/brdf/``.

Quality: :func:`relative_error`, the median and the 90th percentile of |f − y|/y over the samples
with y > 0 and θ_i, θ_o ≤ 80°, for every method alike. Time: whole processes (interpreter start
to exit, ``_whole_process.py``), except the exhaustive search, which runs in this process (its
time is the sum of its fits').

- **ctfit default**: ``ctfit fit FILE -o out.json`` (``--param-out`` where the file lacks its
  ``#PARAM_OUT``), cold (an empty compilation cache) and warm (the cache the cold run filled);
  the fit JSON's ``quality`` section is printed too when the library writes one.
- **best CT**: every candidate of :func:`candidates` (family × lobes 1–3 × diffuse form) × every
  loss of ``SEARCH_LOSSES``, ``ctfit.fit(..., starts=20)``, one process per loss; the one with the
  lowest median relative error.
- **SciPy**: ``_scipy_fit.py``, one lobe + an R_d per band (``--diffuse spectrum``),
  ``scipy.optimize.least_squares(method="lm")`` on log-ratio residuals ln f − ln y, from F0 = 0.5,
  m = 0.1, s = 0.5, R_d = 0.1 sr⁻¹ (ALTA files are first written as CSV, outside the timing).
- **Mitsuba**: ``_mitsuba_fit.py fit-plastic``: ``roughplastic`` + Adam on the log loss,
  1,000 steps, α, ``int_ior`` and an RGB (single band: grey) ``diffuse_reflectance`` free, Dr.Jit
  ``llvm_ad_rgb`` (needs libLLVM ≥ 17; skipped with the reason otherwise).

Run: ``python scripts/bench_real.py [--quick] [--docs DIR] [--starts N] [--losses a,b] [--steps N] [FILE...]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = ROOT / "scripts"
sys.path.insert(0, str(SCRIPTS))

from _numpy_model import NumpyProblem, read_csv_numpy  # noqa: E402
from _whole_process import byte_compile, run  # noqa: E402
from bench_fit import CTFIT, PY, cpu_name, llvm_path  # noqa: E402  (the same interpreter and ctfit command)

import ctfit  # noqa: E402

SECTION = "## Results"
MAX_THETA = 80.0
FILES = [*sorted((ROOT / "measurements" / "testbed").glob("*.csv")),
         *(ROOT / "measurements" / "brdf" / n for n in ("retro-gray-tape.dat", "retro-3M-jaune.dat", "pink-felt-1d.alta"))]
QUICK_FILES = [ROOT / "measurements" / "brdf" / "pink-felt-1d.alta"]
PARAM_OUT = {"retro-gray-tape.dat": "INV_STERADIAN_COSINE_FACTOR"}  # its README: the file lacks the line
METAL_FRESNELS, METAL_DIFFUSES = ("f0", "conductor"), (None, "F0/pi", "spectrum", "constant")
PLASTIC_DIFFUSES = ("spectrum", "constant", "transmitted")
COLUMNS = ("file", "samples", "default median", "default p90", "cold s", "warm s", "best median", "best p90", "best structure", "search s",
           "SciPy median", "SciPy p90", "SciPy s", "Mitsuba median", "Mitsuba p90", "Mitsuba s")
TIMEOUT = 1800.0
SEARCH_LOSSES = ("relative", "robust-relative", "log", "log-ratio")
"""The search's losses: every loss whose residual is a relative error, or close to one (the
error the table reports); ``absolute`` and ``cosine`` weight by the value itself, so the peak
owns them (``scripts/loss_choice.py`` compares losses on the same files)."""


def relative_error(f, y, theta_i, theta_o, max_theta: float = MAX_THETA) -> tuple[float, float]:
    """(median, 90th percentile) of |f − y|/y over the samples with y > 0 and θ_i, θ_o ≤ ``max_theta`` (degrees)."""
    f, y = np.asarray(f, dtype=float), np.asarray(y, dtype=float)
    keep = (y > 0) & (np.asarray(theta_i) <= max_theta) & (np.asarray(theta_o) <= max_theta)
    r = np.abs(f[keep] - y[keep]) / y[keep]
    return float(np.median(r)), float(np.percentile(r, 90))


def candidates(losses, quick: bool = False) -> list[tuple[str, ctfit.Structure, str]]:
    """(label, structure, loss) for every structure the search tries × ``losses``: the metal family
    (Fresnel "f0" or "conductor" × diffuse None, "F0/pi", "spectrum", "constant") and the plastic
    family (diffuse "spectrum", "constant", "transmitted"), 1–3 lobes each (``quick``: one lobe, the
    metal structure "f0", R_d = F0/π, and the plastic with a Lambertian R_d)."""
    lobes = (1,) if quick else (1, 2, 3)
    metal = [dict(lobes=n, fresnel=fr, diffuse=d) for fr in METAL_FRESNELS for n in lobes for d in METAL_DIFFUSES]
    plastic = [dict(family="plastic", lobes=n, diffuse=d) for n in lobes for d in PLASTIC_DIFFUSES[: 1 if quick else None]]
    out = []
    for kw in (metal[1:2] if quick else metal) + plastic:
        label = ", ".join(f"{k}={v}" for k, v in kw.items())
        out += [(f"{label}; loss {loss}", ctfit.Structure(**kw), loss) for loss in losses]
    return out


def read(path: Path) -> ctfit.Measurement:
    return ctfit.read_measurement(path, **({"param_out": PARAM_OUT[path.name]} if path.name in PARAM_OUT else {}))


def ctfit_default(path: Path, folder: Path, env: dict, data: ctfit.Measurement, warm_runs: int = 1) -> dict:
    """``ctfit fit FILE -o out.json`` cold and then ``warm_runs`` times warm, timed as whole
    processes (``warm_s`` the median of the warm ones, ``warm_range`` their least and most); the fit's error."""
    cache, out = folder / "cache", folder / "default.json"
    extra = ["--param-out", PARAM_OUT[path.name]] if path.name in PARAM_OUT else []
    walls = []
    for _ in range(1 + max(1, warm_runs)):
        r = run([CTFIT, "fit", str(path), "-o", str(out), *extra], env=dict(env, JAX_COMPILATION_CACHE_DIR=str(cache)), timeout=TIMEOUT)
        if r.returncode not in (0, 1):  # 1: did not converge, still a result
            r.check(f"ctfit fit {path.name}")
        walls.append(r.wall_s)
    doc = json.loads(out.read_text())
    material = ctfit.load_material(out)
    med, p90 = relative_error(ctfit.evaluate(material, data), data.brdf, data.theta_i, data.theta_o)
    chosen = [row["structure"] for row in doc["fit"].get("structure_choice", []) if row.get("chosen")]  # as chosen (a fit with s = 0 keeps no lobes)
    return dict(median=med, p90=p90, cold_s=walls[0], warm_s=float(np.median(walls[1:])), warm_range=(min(walls[1:]), max(walls[1:])),
                quality=doc.get("quality"), converged=doc["fit"]["converged"],
                structure=chosen[0] if chosen else ctfit.structure_label(material.structure))


def best_fit(path: Path, losses, starts: int, quick: bool, env: dict) -> dict:
    """Every candidate × loss fitted with ``starts`` starts; the lowest median relative error.

    One process per loss (each compiles its structures once; a single process compiling every
    structure of every loss ran out of XLA's code memory, "LLVM ERROR: Unable to allocate section
    memory"); the time is the sum of the fits' own times."""
    best, seconds, tried, per_loss = None, 0.0, 0, {}
    for loss in losses:
        cmd = [PY, str(Path(__file__).resolve()), "--search", str(path), loss, "--starts", str(starts), *(["--quick"] if quick else [])]
        r = run(cmd, env=env, timeout=4 * TIMEOUT).check(f"the search of {path.name} with loss {loss}")
        got = json.loads(r.stdout.strip().splitlines()[-1])
        seconds, tried, per_loss[loss] = seconds + got["search_s"], tried + got["tried"], got["median"]
        if best is None or got["median"] < best["median"]:
            best = got
    best = dict(best or dict(median=float("nan"), p90=float("nan"), structure="none"))
    return dict(best, search_s=seconds, tried=tried, per_loss=per_loss)


def search_one_loss(data: ctfit.Measurement, cands, starts: int) -> dict:
    """Every candidate of one loss fitted in this process; the lowest median relative error."""
    best, t0, tried = None, time.perf_counter(), 0
    for label, st, loss in cands:
        res = ctfit.fit(data, st, loss=loss, starts=starts)
        tried += 1
        med, p90 = relative_error(ctfit.evaluate(res.material, data), data.brdf, data.theta_i, data.theta_o)
        if best is None or med < best["median"]:
            best = dict(median=med, p90=p90, structure=label, converged=bool(res.converged))
    return dict(best or dict(median=float("nan"), p90=float("nan"), structure="none"), search_s=time.perf_counter() - t0, tried=tried)


def scipy_peer(csv: Path, folder: Path, env: dict) -> dict:
    """One lobe + R_d per band, log-ratio residuals, as a whole SciPy process; its error."""
    nd = read_csv_numpy(csv)
    start = folder / "scipy-start.json"
    start.write_text(json.dumps({"x0": [0.0] * nd.n_bands + [float(np.log(0.1)), 0.0] + [float(np.log(0.1))] * nd.n_bands}))
    r = run([PY, str(SCRIPTS / "_scipy_fit.py"), str(start), str(csv), "--lobes", "1", "--diffuse", "spectrum", "--loss", "log-ratio"], env=env,
            timeout=TIMEOUT).check("the SciPy process")
    out = json.loads(r.stdout.strip().splitlines()[-1])
    f = NumpyProblem(nd, lobes=1, loss="log-ratio", diffuse="spectrum").model(np.asarray(out["x"]))
    med, p90 = relative_error(f, nd.brdf, nd.theta_i, nd.theta_o)
    return dict(median=med, p90=p90, wall_s=r.wall_s, status=out["status"])


def mitsuba_peer(data: ctfit.Measurement, folder: Path, env: dict, steps: int) -> dict:
    """Mitsuba's roughplastic + Adam as a whole process on the data's direction pairs; its error."""
    llvm = llvm_path()
    if llvm is None:
        return dict(skipped="Dr.Jit's LLVM backend needs libLLVM ≥ 17 (make install-bench, or apt-get install libllvm19)")
    pairs, index = data.directions()
    value = np.full((len(data.channels or data.wavelength_nm), len(pairs)), np.nan)
    value[data.band, index] = data.brdf
    npz, out = folder / "mitsuba-data.npz", folder / "mitsuba-fit.npz"
    np.savez(npz, light=np.asarray(ctfit.direction_from_angles_deg(pairs[:, 0], pairs[:, 1]), dtype=float),
             view=np.asarray(ctfit.direction_from_angles_deg(pairs[:, 2], pairs[:, 3]), dtype=float), value=value)
    r = run([PY, str(SCRIPTS / "_mitsuba_fit.py"), "fit-plastic", str(npz), str(out), str(steps)], env=dict(env, DRJIT_LIBLLVM_PATH=llvm),
            timeout=TIMEOUT).check("the Mitsuba process")
    fitted = json.loads(r.stdout.strip().splitlines()[-1])
    f = np.load(out)["value"][data.band, index]
    med, p90 = relative_error(f, data.brdf, data.theta_i, data.theta_o)
    return dict(median=med, p90=p90, wall_s=r.wall_s, alpha=fitted["alpha"], eta=fitted["eta"])


def bench_file(path: Path, tmp: Path, env: dict, args) -> dict:
    """Every method on one file: a row of the table."""
    folder = tmp / path.stem
    folder.mkdir()
    data = read(path)
    csv = path if path.suffix == ".csv" else folder / f"{path.stem}.csv"
    if csv != path:
        ctfit.write_csv(data, csv)
    row = dict(file=path.name, samples=len(data), default=ctfit_default(path, folder, env, data))
    row["best"] = best_fit(path, [x for x in args.losses if x != "sigma" or data.sigma is not None], args.starts, args.quick, env)
    row["scipy"] = scipy_peer(csv, folder, env)
    row["mitsuba"] = mitsuba_peer(data, folder, env, args.steps)
    print(" | ".join(cells(row)), flush=True)
    if row["default"]["quality"] is not None:
        print(f"  {path.name}: quality section of the fit JSON: {json.dumps(row['default']['quality'])}", flush=True)
    return row


DEFAULT_SECTION = "## The default, measured"
DEFAULT_COLUMNS = ("file", "samples", "median", "p90", "structure chosen", "cold s", "warm s", "better of best CT and Mitsuba", "default / better")


def reference_errors(doc: Path) -> dict:
    """{file: (best CT median, Mitsuba median)} from the "## Results" table of ``doc`` (fractions; NaN where absent)."""
    if not doc.is_file():
        return {}
    lines = doc.read_text(encoding="utf-8").split(SECTION, 1)[-1].split("\n## ", 1)[0].splitlines()
    head = next((ln for ln in lines if ln.startswith("| file |")), None)
    if head is None:
        return {}
    names = [c.strip() for c in head.strip("|").split("|")]
    pct = lambda c: float(c.split("%")[0]) / 100 if "%" in c else float("nan")
    out = {}
    for ln in lines:
        cells = [c.strip() for c in ln.strip("|").split("|")]
        if ln.startswith("| ") and len(cells) == len(names) and cells[0] not in ("file", "---"):
            out[cells[0]] = (pct(cells[names.index("best median")]), pct(cells[names.index("Mitsuba median")]))
    return out


def default_section(rows: list[dict], refs: dict, args, started: float, load: tuple[float, float]) -> str:
    """The section of ``--default-only``: the default fit of every file, against the search's best and Mitsuba's."""
    lines = [DEFAULT_SECTION, "", f"Measured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())} with `python scripts/bench_real.py "
             f"{' '.join(args.argv)}` on {cpu_name()} ({os.cpu_count()} CPUs, shared: load average {load[0]:.1f} at the start, "
             f"{load[1]:.1f} at the end), Python {platform.python_version()}; {time.perf_counter() - started:.0f} s in all. `ctfit fit FILE` "
             "as a user runs it, whole processes: cold (an empty compilation cache), then warm (the cache the cold run filled"
             + (f"; {args.warm} runs, their median and in brackets their range" if getattr(args, "warm", 1) > 1 else "") + "). The "
             "reference is the better of the exhaustive search's best and Mitsuba + Adam in \"Results\" above (its own run).", "",
             "| " + " | ".join(DEFAULT_COLUMNS) + " |", "|" + "---|" * len(DEFAULT_COLUMNS)]
    for r in rows:
        d = r["default"]
        best, mits = refs.get(r["file"], (float("nan"), float("nan")))
        ref = float(np.nanmin([best, mits])) if np.isfinite([best, mits]).any() else float("nan")
        ratio = d["median"] / ref if np.isfinite(ref) and ref > 0 else float("nan")
        lines.append("| " + " | ".join([r["file"], f"{r['samples']:,}", f"{100 * d['median']:.2f} %", f"{100 * d['p90']:.2f} %", d["structure"],
                                         f"{d['cold_s']:.1f}", _warm_cell(d), f"{100 * ref:.2f} %" if np.isfinite(ref) else "–",
                                         f"{ratio:.2f}" if np.isfinite(ratio) else ("≤ 1" if d["median"] <= 1e-6 else "–")]) + " |")
    return "\n".join(lines) + "\n"


def _warm_cell(d: dict) -> str:
    """The warm time: the median, and where several runs were timed, their range."""
    low, high = d.get("warm_range", (d["warm_s"], d["warm_s"]))
    return f"{d['warm_s']:.1f}" + (f" ({low:.1f}–{high:.1f})" if high > low else "")


def cells(row: dict) -> list[str]:
    """The row's cells in the order of ``COLUMNS``."""
    d, b, s, m = row["default"], row["best"], row["scipy"], row["mitsuba"]
    pct = lambda x: f"{100 * x:.2f} %"
    mits = [pct(m["median"]), pct(m["p90"]), f"{m['wall_s']:.1f}"] if "skipped" not in m else ["skipped", "skipped", "skipped"]
    return [row["file"], f"{row['samples']:,}", pct(d["median"]), pct(d["p90"]), f"{d['cold_s']:.1f}", f"{d['warm_s']:.1f}", pct(b["median"]),
            pct(b["p90"]), b["structure"], f"{b['search_s']:.0f}", pct(s["median"]), pct(s["p90"]), f"{s['wall_s']:.1f}", *mits]


def section(rows: list[dict], args, started: float, load: tuple[float, float], pending: list[Path] = ()) -> str:
    """The Markdown section: the table, what ran and on what machine; ``pending``: files not (yet) run."""
    lines = [SECTION, "", f"Measured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())} with `python scripts/bench_real.py {' '.join(args.argv)}` on "
             f"{cpu_name()} ({os.cpu_count()} CPUs, shared: load average {load[0]:.1f} at the start, {load[1]:.1f} at the end), Python "
             f"{platform.python_version()}; {args.starts} starts per search fit, losses {', '.join(args.losses)}, {args.steps} Adam steps; "
             f"{time.perf_counter() - started:.0f} s in all. Errors: |f − y|/y over samples with y > 0 and θ_i, θ_o ≤ {MAX_THETA:.0f}°, "
             "median and 90th percentile (p90); times in seconds, whole processes except the search (the sum of its fits in one process).", "",
             "| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(cells(r)) + " |" for r in rows]
    skipped = {r["mitsuba"]["skipped"] for r in rows if "skipped" in r["mitsuba"]}
    lines += [f"\nMitsuba skipped: {'; '.join(sorted(skipped))}."] if skipped else []
    lines += [f"\nNot run (the run was stopped before them): {', '.join(p.name for p in pending)}."] if pending else []
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", type=Path, nargs="*", help="data files (default: the test-bed and the three ALTA files)")
    ap.add_argument("--quick", "--small", dest="quick", action="store_true", help="smoke run: the pink felt only, one search structure per family, 2 starts, "
                                                                                  "20 Adam steps")
    ap.add_argument("--starts", type=int, default=None, help="starts per search fit (default 20; --quick: 2)")
    ap.add_argument("--losses", default=None, help=f"comma-separated losses for the search (default: {','.join(SEARCH_LOSSES)}; --quick: log)")
    ap.add_argument("--steps", type=int, default=None, help="Adam steps of the Mitsuba peer (default 1000; --quick: 20)")
    ap.add_argument("--docs", type=Path, help=f"write the section {SECTION!r} of DIR/real-materials.md")
    ap.add_argument("--default-only", action="store_true", help=f"only ctfit's default fit: writes the section {DEFAULT_SECTION!r}")
    ap.add_argument("--warm", type=int, default=1, help="warm runs of the default fit per file (their median is reported; default 1)")
    ap.add_argument("--search", nargs=2, metavar=("FILE", "LOSS"), help=argparse.SUPPRESS)  # one loss's search, in its own process
    args = ap.parse_args(argv)
    if args.search:
        import jax

        jax.config.update("jax_enable_x64", True)
        path, loss = Path(args.search[0]), args.search[1]
        print(json.dumps(search_one_loss(read(path), candidates([loss], args.quick), args.starts or (2 if args.quick else 20))))
        return 0
    args.argv = list(sys.argv[1:] if argv is None else argv)
    args.starts = args.starts or (2 if args.quick else 20)
    args.steps = args.steps or (20 if args.quick else 1000)
    args.losses = (args.losses or ("log" if args.quick else ",".join(SEARCH_LOSSES))).split(",")
    files = args.files or (QUICK_FILES if args.quick else FILES)
    import jax

    jax.config.update("jax_enable_x64", True)
    byte_compile()  # as an installed ctfit is (_whole_process.byte_compile)
    started, load0 = time.perf_counter(), os.getloadavg()[0]
    print(" | ".join(COLUMNS), flush=True)
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    rows = []
    if args.default_only:
        refs = reference_errors((args.docs or ROOT / "docs") / "real-materials.md")
        with tempfile.TemporaryDirectory(prefix="ctfit-bench-real-") as tmp:
            for path in map(Path, files):
                (Path(tmp) / path.stem).mkdir()
                data = read(path)
                rows.append(dict(file=path.name, samples=len(data), default=ctfit_default(path, Path(tmp) / path.stem, env, data, args.warm)))
                d = rows[-1]["default"]
                print(f"{path.name}: median {100 * d['median']:.2f} %, {d['structure']}, cold {d['cold_s']:.1f} s, warm {d['warm_s']:.1f} s", flush=True)
                text = default_section(rows, refs, args, started, (load0, os.getloadavg()[0]))
                if args.docs:
                    from _docs import write_section

                    write_section(args.docs / "real-materials.md", DEFAULT_SECTION, text)
        print(text)
        return 0
    with tempfile.TemporaryDirectory(prefix="ctfit-bench-real-") as tmp:
        for i, path in enumerate(files):
            rows.append(bench_file(Path(path), Path(tmp), env, args))
            text = section(rows, args, started, (load0, os.getloadavg()[0]), [Path(p) for p in files[i + 1 :]])
            if args.docs:  # after every file: a run stopped early still leaves what it measured
                from _docs import write_section

                write_section(args.docs / "real-materials.md", SECTION, text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
