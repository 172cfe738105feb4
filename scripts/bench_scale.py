"""Benchmark of fitting at scale: files per second and texels per second for (a) a serial loop
of ``ctfit.fit``, (b) ``fit_batch`` in one process, (c) a local Dask cluster of 2 workers
(``ctfit fit ... --workers 2``), with a SciPy loop as the peer — every figure from this run.

Every figure is a whole process (interpreter start to exit, ``_whole_process.py``), the median
of ``--repeat`` runs, with the compiled programs already in the cache folder (a priming run of
each mode, on the same inputs, first): what a user's second run of the day costs. "Fixed" is the same mode on
one file (one texel for the loops, 64 texels for the others): start-up, imports, cluster start
and loading programs, which the rate "beyond it" leaves out.

- **Database**: ``--files`` CSVs × ``--samples`` scattered samples of one geometry (31 bands, two
  lobes and a diffuse part; ``_bench_fit_data.write_batch``). SciPy: ``_scipy_fit.py`` over the
  files in one process. (a) one process calling ``ctfit.fit`` per file; (b) ``ctfit fit DIR -o
  OUT`` (``fit_batch``); (c) ``ctfit fit DIR -o OUT --workers 2`` into an empty OUT.
- **Texels**: ``--texels`` texels × 67 direction pairs × RGB (one lobe;
  ``_bench_fit_data.texel_case``) in a Zarr store. SciPy on the first ``--scipy-texels``
  (written as CSVs) and (a) on the first ``--loop-texels`` texels only; (b) one process calling
  ``ctfit.fit_batch(geometry, values=...)``; (c) ``ctfit fit TEXELS.zarr -o MAPS.zarr --workers 2``.

The machine's load is printed with the figures (``os.getloadavg``): on a shared machine every
figure is a lower bound of what the hardware gives.

Run: ``.venv/bin/python scripts/bench_scale.py [--small] [--repeat N] [--files N] [--samples N]
[--texels N] [--loop-texels N] [--scipy-texels N] [--json FILE] [--no-warm-up] [--no-fixed]``.
"""

from __future__ import annotations

import argparse
import json
import os
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

PY = sys.executable
CTFIT = str(Path(sys.executable).with_name("ctfit"))
TIMEOUT = 1800.0
LOOP = r"""
import sys, jax
jax.config.update("jax_enable_x64", True)
import ctfit
ctfit.enable_compilation_cache()
st = ctfit.Structure(lobes=int(sys.argv[1]), diffuse=None if sys.argv[2] == "none" else sys.argv[2])
for p in sys.argv[3:]:
    ctfit.fit(ctfit.read_measurement(p), st)
"""
TEXEL_LOOP = r"""
import sys, jax, xarray as xr
jax.config.update("jax_enable_x64", True)
import ctfit
ctfit.enable_compilation_cache()
geometry, _, _ = ctfit.read_texel_geometry(sys.argv[1])
with xr.open_zarr(sys.argv[1], consolidated=False) as ds:
    values = ds["values"][: int(sys.argv[2])].values
for row in values:
    ctfit.fit(geometry.replace(brdf=row), ctfit.Structure(lobes=1), loss="relative")
"""
TEXEL_BATCH = r"""
import sys, jax, xarray as xr
jax.config.update("jax_enable_x64", True)
import ctfit
ctfit.enable_compilation_cache()
geometry, _, _ = ctfit.read_texel_geometry(sys.argv[1])
with xr.open_zarr(sys.argv[1], consolidated=False) as ds:
    values = ds["values"].values
ctfit.fit_batch(geometry, ctfit.Structure(lobes=1), values=values)
"""


def _remove(path: Path) -> None:
    if path.is_dir():
        shutil.rmtree(path)
    elif path.exists():
        path.unlink()


class Bench:
    def __init__(self, tmp: Path, repeat: int, warm: bool = True, fixed: bool = True):
        self.tmp, self.repeat, self.warm, self.fixed = tmp, repeat, warm, fixed
        self.cache = tmp / "cache"
        self.env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=str(self.cache), CTFIT_PROGRESS="0", JAX_PLATFORMS="cpu")

    def warm_up(self, cmd: list[str], what: str, fresh: Path | None = None) -> None:
        """A run whose time is not kept: the programs it compiles are in the cache for the timed runs."""
        if self.warm:
            self.prime(cmd, what, fresh)

    def time(self, cmd: list[str], what: str, fresh: Path | None = None) -> float:
        """Median wall time of ``cmd`` over the repeats (``fresh``: a folder removed before each run)."""
        return median([self.prime(cmd, what, fresh).wall_s for _ in range(self.repeat)])

    def fixed_cost(self, cmd: list[str], what: str, fresh: Path | None = None) -> float | None:
        """The median time of the one-item run (primed first), or None with ``--no-fixed``."""
        if not self.fixed:
            return None
        self.warm_up(cmd, what, fresh)
        return self.time(cmd, what, fresh)

    def prime(self, cmd: list[str], what: str, fresh: Path | None = None):
        """One run of ``cmd``; it must succeed (``ctfit``: exit 1, a fit that did not converge, is a
        result), and the SciPy peer must print one result per file."""
        if fresh is not None:
            _remove(fresh)
        r = run(cmd, env=self.env, cwd=self.tmp, timeout=TIMEOUT)
        if not (r.returncode == 1 and cmd[0] == CTFIT):
            r.check(what)
        if what == "scipy" and r.stdout.count('{"file"') != sum(a.endswith(".csv") for a in cmd):
            raise RuntimeError(f"the SciPy peer did not fit every file:\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}")
        return r


def scipy_cmd(start: Path, files: list[Path], lobes: int, diffuse: bool) -> list[str]:
    return [PY, str(SCRIPTS / "_scipy_fit.py"), str(start), *map(str, files), "--lobes", str(lobes), "--loss", "relative"] + (["--diffuse"] if diffuse else [])


def database(b: Bench, n_files: int, n_samples: int, seed: int) -> dict:
    folder = b.tmp / "db"
    files = data.write_batch(folder / "files", n_files, n_samples, seed)
    one = folder / "one"
    one.mkdir()
    shutil.copy(files[0], one)
    start = folder / "start.json"
    start.write_text(json.dumps({"x0": data.default_start_x0(2, len(data.WL31), True)}))
    out = folder / "out"
    modes = {
        "scipy": lambda fs: scipy_cmd(start, fs, 2, True),
        "fit loop": lambda fs: [PY, "-c", LOOP, "2", "F0/pi", *map(str, fs)],
        "fit_batch": lambda fs: [CTFIT, "fit", *map(str, fs), "--lobes", "2", "--family", "metal", "--diffuse", "F0/pi", "-q", "-o", str(out)],
        "--workers 2": lambda fs: [CTFIT, "fit", *map(str, fs), "--lobes", "2", "--family", "metal", "--diffuse", "F0/pi", "-q", "-o", str(out), "--workers",
                                   "2"],
    }
    res = {}
    for name, cmd in modes.items():
        b.warm_up(cmd(files), name, fresh=out)
        whole = b.time(cmd(files), name, fresh=out)
        fixed = b.fixed_cost(cmd([one / files[0].name]), name, fresh=out)
        per = _beyond(n_files - 1, whole, fixed)
        res[name] = dict(whole_s=whole, fixed_s=fixed, files_per_s=n_files / whole, marginal_files_per_s=per)
        print(f"database {n_files} files × {n_samples:,} samples, {name:>12}: {whole:7.2f} s, {n_files / whole:7.2f} files/s "
              f"(one file: {_seconds(fixed)}; beyond it {_rate(per)} files/s)", flush=True)
    return res


def _beyond(count: int, whole: float, fixed: float | None) -> float | None:
    """Items per second beyond the one-item run (None where the run is within the fixed cost's
    noise, or was not run)."""
    return count / (whole - fixed) if fixed is not None and whole > 1.05 * fixed else None


def _seconds(value: float | None) -> str:
    return "not run" if value is None else f"{value:.2f} s"


def _rate(value: float | None) -> str:
    return "—" if value is None else f"{value:.1f}"


def texels(b: Bench, n_texels: int, n_loop: int, n_scipy: int, seed: int) -> dict:
    import xarray as xr

    folder = b.tmp / "tex"
    folder.mkdir()
    geometry, values, _, _ = data.texel_case(n_texels, 67, seed)
    table = {k: (("sample",), getattr(geometry, k)) for k in ("theta_i", "phi_i", "theta_o", "phi_o", "band")}

    def store(path, rows):
        xr.Dataset({"values": (("texel", "sample"), rows), **table}, attrs={"channels": ",".join(geometry.channels)}).to_zarr(path, consolidated=False)
        return path

    full, small = store(folder / "texels.zarr", values), store(folder / "small.zarr", values[:64])
    csvs = []
    import ctfit

    for i in range(n_scipy):
        csvs.append(folder / "csv" / f"t{i:04d}.csv")
        csvs[-1].parent.mkdir(exist_ok=True)
        # SciPy's reader takes wavelength bands: R, G, B as 450, 550, 650 nm (the model does not depend on the labels)
        ctfit.write_csv(geometry.replace(brdf=values[i], channels=None, wavelength_nm=np.array([450.0, 550.0, 650.0])), csvs[-1])
    start = folder / "start.json"
    start.write_text(json.dumps({"x0": data.default_start_x0(1, 3, False)}))
    maps = folder / "maps.zarr"
    modes = {
        "scipy": (lambda src, k: scipy_cmd(start, csvs[:k], 1, False), n_scipy),
        "fit loop": (lambda src, k: [PY, "-c", TEXEL_LOOP, str(src), str(k)], n_loop),
        "fit_batch": (lambda src, k: [PY, "-c", TEXEL_BATCH, str(src)], n_texels),
        "--workers 2": (lambda src, k: [CTFIT, "fit", str(src), "-o", str(maps), "--no-diffuse", "--lobes", "1", "-q", "--workers", "2"], n_texels),
    }
    res = {}
    for name, (cmd, count) in modes.items():
        b.warm_up(cmd(full, count), name, fresh=maps)
        whole = b.time(cmd(full, count), name, fresh=maps)
        fixed = b.fixed_cost(cmd(small, 1), name, fresh=maps)
        per = _beyond(count - (1 if name in ("scipy", "fit loop") else 64), whole, fixed)
        res[name] = dict(texels=count, whole_s=whole, fixed_s=fixed, texels_per_s=count / whole, marginal_texels_per_s=per)
        print(f"texels {count:,} × {values.shape[1]} samples, {name:>12}: {whole:7.2f} s, {count / whole:9.1f} texels/s "
              f"(fixed {_seconds(fixed)}; beyond it {_rate(per)} texels/s)", flush=True)
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--small", action="store_true", help="a few seconds per mode: 4 files × 300 samples, 256 texels")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--files", type=int, default=256)
    ap.add_argument("--samples", type=int, default=2000)
    ap.add_argument("--texels", type=int, default=40000)
    ap.add_argument("--loop-texels", type=int, default=64, help="texels of the ctfit.fit loop")
    ap.add_argument("--scipy-texels", type=int, default=1000, help="texels of the SciPy loop")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", type=Path, help="write the figures here too")
    ap.add_argument("--no-warm-up", dest="warm", action="store_false", help="no untimed first runs (figures then include compiling; for tests)")
    ap.add_argument("--no-fixed", dest="fixed", action="store_false", help="no one-item runs (no fixed cost, no rate beyond it; for tests)")
    args = ap.parse_args()
    if args.small:
        args.files, args.samples, args.texels, args.loop_texels, args.scipy_texels = 4, 300, 256, 4, 16
    byte_compile()  # as an installed ctfit is (_whole_process.byte_compile)
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench-scale-") as tmp:
        b = Bench(Path(tmp), args.repeat, args.warm, args.fixed)
        load = os.getloadavg()
        print(f"machine: {os.cpu_count()} cores, load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} at the start", flush=True)
        res = dict(database=database(b, args.files, args.samples, args.seed), texels=texels(b, args.texels, args.loop_texels, args.scipy_texels, args.seed))
        load = os.getloadavg()
        res["load_end"] = load
        print(f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} at the end; {time.perf_counter() - started:.0f} s in all", flush=True)
    if args.json:
        args.json.write_text(json.dumps(res, indent=2))


if __name__ == "__main__":
    main()
