"""Which loss the default fit should use: the data-chosen default structure fitted with each loss
to data the Cook–Torrance model cannot represent; writes the section "## The default loss,
measured" of ``docs/fitting.md`` with ``--docs DIR``.

Data: the model-mismatch test-bed of ``scripts/bench_real.py`` (Mitsuba 3 renders of other BSDFs
in ``measurements/testbed/`` and the three real ALTA files of ``measurements/brdf/``).

For every file and loss, one process (each its own compiled programs; a single process would
hold them all) runs ``ctfit.fit(data, loss=LOSS)`` — the structure chosen by the data as the
default does — and reports the median and 90th percentile of |f − y|/y over the samples with
y > 0 and θ_i, θ_o ≤ 80° (``bench_real.relative_error``, the figure users judge a fit by), the
structure chosen and the fit's time.

Run: ``python scripts/loss_choice.py [--small] [--docs DIR] [--losses a,b] [FILE...]``.
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = ROOT / "scripts"
sys.path.insert(0, str(SCRIPTS))

from _docs import write_section  # noqa: E402

SECTION = "## The default loss, measured"
LOSSES = ("relative", "robust-relative", "log", "log-ratio", "absolute")
SMALL_LOSSES = ("relative", "robust-relative")


def one(path: Path, loss: str) -> dict:
    """Fit ``path`` with the data-chosen structure and ``loss`` in this process; its error."""
    import warnings

    import jax

    jax.config.update("jax_enable_x64", True)
    from bench_real import read, relative_error

    import ctfit

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ctfit.DataWarning)
        data = read(path)
    t0 = time.perf_counter()
    res = ctfit.fit(data, loss=loss)
    seconds = time.perf_counter() - t0
    med, p90 = relative_error(ctfit.evaluate(res.material, data), data.brdf, data.theta_i, data.theta_o)
    return dict(median=med, p90=p90, seconds=seconds, structure=ctfit.structure_label(res.material.structure))


def run_one(path: Path, loss: str) -> dict:
    r = subprocess.run([sys.executable, __file__, "--one", str(path), loss], capture_output=True, text=True, timeout=3600)
    if r.returncode:
        raise SystemExit(f"{path.name}, loss {loss}: the fit process failed:\n{r.stderr[-2000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def section(rows: dict, files, losses, started: float) -> str:
    head = ["file", *(f"`{loss}`" for loss in losses), "best"]
    lines = [SECTION, "",
             f"Measured {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime(started))} with `python scripts/loss_choice.py` on "
             f"{platform.processor() or platform.machine()}, Python {platform.python_version()}, {time.time() - started:.0f} s in all. "
             "Each cell: the median |f − y|/y (θ_i, θ_o ≤ 80°) of `ctfit.fit(data, loss=…)` with the structure the data chooses, "
             "the 90th percentile in parentheses.", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for f in files:
        cells = [f.name]
        for loss in losses:
            r = rows[f.name][loss]
            cells.append(f"{100 * r['median']:.2f} % ({100 * r['p90']:.0f} %)")
        medians = {loss: rows[f.name][loss]["median"] for loss in losses}
        cells.append("every one (exact)" if max(medians.values()) < 1e-6 else f"`{min(medians, key=medians.get)}`")
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "Structures chosen (same order of losses):", ""]
    for f in files:
        lines.append(f"- {f.name}: " + "; ".join(f"`{loss}` {rows[f.name][loss]['structure']}" for loss in losses))
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", type=Path, nargs="*", help="data files (default: the test-bed and the three ALTA files)")
    ap.add_argument("--small", action="store_true", help="smoke run: the pink felt, the relative and robust-relative losses")
    ap.add_argument("--losses", default=None, help=f"comma-separated (default: {','.join(LOSSES)})")
    ap.add_argument("--docs", type=Path, default=None, help="write the section into DIR/fitting.md (default: print only)")
    ap.add_argument("--one", nargs=2, metavar=("FILE", "LOSS"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.one:
        print(json.dumps(one(Path(args.one[0]), args.one[1])))
        return 0
    from bench_real import FILES, QUICK_FILES

    files = args.files or (QUICK_FILES if args.small else FILES)
    losses = tuple(args.losses.split(",")) if args.losses else (SMALL_LOSSES if args.small else LOSSES)
    started, rows = time.time(), {}
    for f in files:
        rows[f.name] = {}
        for loss in losses:
            rows[f.name][loss] = r = run_one(f, loss)
            print(f"{f.name} {loss}: median {100 * r['median']:.2f} %, p90 {100 * r['p90']:.1f} %, {r['structure']}, {r['seconds']:.1f} s", flush=True)
    text = section(rows, files, losses, started)
    print(text)
    if args.docs is not None:
        write_section(args.docs / "fitting.md", SECTION, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
