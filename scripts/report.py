"""Regenerate every measured report in ``docs/`` (``make report``), each from its own run.

Runs, one after another so that their timings do not disturb each other:

- ``bench_eval.py``     → docs/benchmarks.md, "## Model evaluation" (model throughput vs NumPy)
- ``bench_fit.py``      → docs/benchmarks.md, "## Fitting" (whole processes vs SciPy and Mitsuba; many files, MERL-sized, per texel)
- ``coverage.py`` (sigma, absolute and relative likelihoods) and ``bench_sample.py``
                        → docs/benchmarks.md, "## Sampling" (emcee speed vs NumPy; coverage)
- ``bench_colour.py``    → docs/benchmarks.md, "## Colour: error against run time", and its plot
- ``fit_tradeoffs.py``  → docs/fitting-tradeoffs.md (error against run time; the recommended default)
- ``stability.py``      → docs/stability.md (stiff and extreme cases)
- ``bench_real.py``     → docs/real-materials.md, "## Results" (fits of data the model cannot represent: default, best, peers)
- ``loss_choice.py``    → docs/fitting.md, "## The default loss, measured" (each loss on the same test-bed)
- ``run_notebooks.py``  → notebooks/*.ipynb executed in place, with their outputs

``--small`` runs the quick version of each into ``--docs DIR`` (a scratch folder: the
committed docs are written only by the full run) and leaves the notebooks alone; ``--only``
picks steps by name. A step that fails stops the report with its exit status. On a terminal a
progress bar over the steps stays at the bottom (stderr) and each step's output scrolls above
it; ``--quiet`` (or no terminal) leaves the output as it is.

Run: ``make report`` or ``.venv/bin/python scripts/report.py [--small --docs DIR] [--only NAME ...]``.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import subprocess
import sys
import tempfile
import time

from tqdm import tqdm

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPTS = ROOT / "scripts"


def steps(docs: pathlib.Path, small: bool, scratch: pathlib.Path) -> list[tuple[str, list[list[str]]]]:
    """(name, commands) for every report; each command is an argument list for Python."""
    d = ["--docs", str(docs)]
    q = ["--small"] if small else []
    coverage = []
    if not small:
        for loss in ("sigma", "absolute", "relative"):
            coverage.append([str(SCRIPTS / "coverage.py"), "--loss", loss, "--json", str(scratch / f"coverage-{loss}.json"), "-q"])
    sample = [str(SCRIPTS / "bench_sample.py"), *d, *q]
    if not small:
        sample += ["--coverage", *(str(scratch / f"coverage-{loss}.json") for loss in ("sigma", "absolute", "relative"))]
    return [
        ("bench_eval", [[str(SCRIPTS / "bench_eval.py"), *d, *q]]),
        ("bench_fit", [[str(SCRIPTS / "bench_fit.py"), *d, *q] + (["--no-merl"] if small else [])]),
        ("bench_sample", [*coverage, sample]),
        ("bench_colour", [[str(SCRIPTS / "bench_colour.py"), *d, *q]]),
        ("fit_tradeoffs", [[str(SCRIPTS / "fit_tradeoffs.py"), *d, *q]]),
        ("stability", [[str(SCRIPTS / "stability.py"), *d, *q]]),
        ("bench_real", [[str(SCRIPTS / "bench_real.py"), *d, *q]]),
        ("loss_choice", [[str(SCRIPTS / "loss_choice.py"), *d, *q]]),
        ("notebooks", [] if small else [[str(SCRIPTS / "run_notebooks.py")]]),
    ]


def progress_shown(quiet: bool) -> bool:
    """A bar as ``ctfit`` draws one: never with --quiet; ``CTFIT_PROGRESS`` 1/0 forces it; else on a terminal."""
    forced = os.environ.get("CTFIT_PROGRESS", "").strip()
    return not quiet and (forced == "1" if forced in ("0", "1") else sys.stderr.isatty())


def run_step(cmd: list[str], show: bool) -> int:
    """Run one command (Python arguments); with a progress bar its output is passed on above the bar."""
    if not show:
        return subprocess.run([sys.executable, *cmd], cwd=ROOT).returncode
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    with subprocess.Popen([sys.executable, *cmd], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env) as proc:
        for line in proc.stdout:
            tqdm.write(line.rstrip("\n"))
    return proc.returncode


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--small", action="store_true", help="quick versions, into --docs (required with --small)")
    ap.add_argument("--docs", type=pathlib.Path, default=None, help="where the Markdown goes (default: the repository's docs/)")
    ap.add_argument("--only", nargs="+", default=None, help="run only these steps (names as listed by --list)")
    ap.add_argument("--list", action="store_true", help="print the steps and their commands, run nothing")
    ap.add_argument("-q", "--quiet", action="store_true", help="no progress bar (shown only on a terminal)")
    args = ap.parse_args(argv)
    if args.small and args.docs is None:
        ap.error("--small writes only into a scratch folder: give --docs DIR")
    docs = (args.docs or ROOT / "docs").resolve()
    with tempfile.TemporaryDirectory(prefix="ctfit-report-") as tmp:
        plan = steps(docs, args.small, pathlib.Path(tmp))
        names = [n for n, _ in plan]
        unknown = sorted(set(args.only or ()) - set(names))
        if unknown:
            ap.error(f"unknown step(s) {unknown}; the steps are {names}")
        todo = [(name, cmd) for name, commands in plan if not args.only or name in args.only for cmd in commands]
        show = progress_shown(args.quiet) and not args.list
        for name, cmd in tqdm(todo, desc="report", disable=not show, leave=True, file=sys.stderr, dynamic_ncols=True):
            line = " ".join([pathlib.Path(sys.executable).name, *(pathlib.Path(c).name if c.startswith(str(SCRIPTS)) else c for c in cmd)])
            if args.list:
                print(f"{name}: {line}")
                continue
            tqdm.write(f"== {name}: {line}")
            t = time.perf_counter()
            code = run_step(cmd, show)
            tqdm.write(f"== {name}: exit {code} after {time.perf_counter() - t:.0f} s")
            if code != 0:
                return code
    return 0


if __name__ == "__main__":
    sys.exit(main())
