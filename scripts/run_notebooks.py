"""Execute the notebooks in notebooks/ top to bottom and save them with their outputs.

Each notebook runs in a fresh ``python3`` kernel with the working directory notebooks/ (the
directory the notebooks assume), with a time limit per cell; a failing cell (an exception, a
failed ``assert``) stops that notebook and makes the script exit with status 1, and the file is
not rewritten. Execution timing is not recorded in the cells, so that re-running a notebook
changes only what its outputs change.

    python scripts/run_notebooks.py                 # run all notebooks, write outputs in place
    python scripts/run_notebooks.py quickstart      # only notebooks/quickstart.ipynb
    python scripts/run_notebooks.py --check         # run into a temporary copy, write nothing
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import tempfile
import time

import nbformat
from nbclient import NotebookClient
from nbclient.exceptions import CellExecutionError, CellTimeoutError, DeadKernelError

ROOT = pathlib.Path(__file__).resolve().parent.parent
NOTEBOOKS = ROOT / "notebooks"


def notebook_paths(names=()) -> list[pathlib.Path]:
    """The notebooks named (stem or file name), or all of notebooks/*.ipynb."""
    if not names:
        return sorted(NOTEBOOKS.glob("*.ipynb"))
    out = []
    for name in names:
        path = NOTEBOOKS / (name if name.endswith(".ipynb") else f"{name}.ipynb")
        if not path.is_file():
            raise SystemExit(f"no notebook {path}")
        out.append(path)
    return out


def kernel_env() -> dict:
    """The kernel's environment: this one, without a non-interactive MPLBACKEND (the notebooks
    select the inline backend themselves) and with Jupyter's platformdirs paths (no migration
    warning)."""
    env = dict(os.environ)
    env.pop("MPLBACKEND", None)
    env["JUPYTER_PLATFORM_DIRS"] = "1"
    env.setdefault("PYDEVD_DISABLE_FILE_VALIDATION", "1")
    return env


def execute(path: pathlib.Path, timeout: int = 120) -> nbformat.NotebookNode:
    """Run ``path`` in a fresh kernel (cwd = notebooks/) and return the executed notebook.

    Raises nbclient's CellExecutionError (or CellTimeoutError, DeadKernelError) on failure.
    """
    nb = nbformat.read(path, as_version=4)
    client = NotebookClient(
        nb,
        timeout=timeout,
        kernel_name="python3",
        resources={"metadata": {"path": str(NOTEBOOKS)}},
        record_timing=False,
    )
    # nbclient passes extra keyword arguments on to KernelManager.start_kernel.
    client.execute(env=kernel_env(), cwd=str(NOTEBOOKS))
    return nb


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("names", nargs="*", help="notebooks to run (default: all in notebooks/)")
    ap.add_argument("--check", action="store_true", help="execute into a temporary copy; do not write the notebooks")
    ap.add_argument("--timeout", type=int, default=120, help="time limit per cell in seconds (default 120)")
    args = ap.parse_args(argv)
    failed = []
    with tempfile.TemporaryDirectory(prefix="ctfit-notebooks-") as tmp:
        for path in notebook_paths(args.names):
            t0 = time.perf_counter()
            try:
                nb = execute(path, timeout=args.timeout)
            except (CellExecutionError, CellTimeoutError, DeadKernelError) as err:
                print(f"FAILED {path.name} after {time.perf_counter() - t0:.1f} s\n{err}", file=sys.stderr)
                failed.append(path.name)
                continue
            target = pathlib.Path(tmp) / path.name if args.check else path
            nbformat.write(nb, target)
            size = target.stat().st_size
            print(f"ok     {path.name}: {time.perf_counter() - t0:.1f} s, {size / 1024:.0f} KB" + ("" if args.check else f" written to {path}"))
    if failed:
        print(f"{len(failed)} notebook(s) failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
