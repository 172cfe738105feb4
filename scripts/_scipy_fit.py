"""The SciPy peer of ``bench_fit.py``, run as a whole process: read measurement CSVs with NumPy,
fit each with ``scipy.optimize.least_squares(method="lm")`` on the NumPy model
(``_numpy_model.py``), print one JSON line per file.

MINPACK's Levenberg–Marquardt with its finite-difference Jacobian and default tolerances, from the
start given in START (a JSON file: ``{"x0": [...]}`` for every file, or ``{"x0": {name: [...]}}``
per file name), in the model's coordinates (logit F0, log m, logit w[, logit s][, log R_d]).
``--diffuse`` alone is R_d = F0/π, ``--diffuse spectrum`` an R_d per band (``bench_real.py``). Each
line has the solution ``x`` too, for the caller to evaluate the model. Imports NumPy and SciPy only.

Run: ``python scripts/_scipy_fit.py START.json FILE... [--lobes J] [--diffuse [spectrum]] [--loss NAME] [--grid]``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from _numpy_model import NumpyProblem, read_csv_numpy
from scipy.optimize import least_squares


def fit_file(path: Path, x0, lobes: int, diffuse: bool | str, loss: str, grid: bool = False) -> dict:
    t = time.perf_counter()
    data = read_csv_numpy(path)
    prob = NumpyProblem(data, lobes=lobes, loss=loss, diffuse=diffuse)
    prob.grid = prob.grid or grid
    t_read = time.perf_counter() - t
    sol = least_squares(prob.residual, np.asarray(x0, dtype=float), method="lm")
    f0, m, w, *s = prob.params(sol.x)
    return dict(file=path.name, cost=float(sol.cost), nfev=int(sol.nfev), status=int(sol.status), f0=f0.tolist(), m=m.tolist(),
                w=w.tolist(), s=float(s[0]) if s else 1.0, rd=s[1].tolist() if len(s) > 1 else None, x=sol.x.tolist(), read_s=t_read,
                fit_s=time.perf_counter() - t - t_read)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("start", type=Path)
    ap.add_argument("files", type=Path, nargs="+")
    ap.add_argument("--lobes", type=int, default=2)
    ap.add_argument("--diffuse", nargs="?", const=True, default=False, choices=[True, "F0/pi", "spectrum"])
    ap.add_argument("--loss", default="relative")
    ap.add_argument("--grid", action="store_true", help="evaluate F on the whole (pair × band) grid even for scattered data")
    args = ap.parse_args()
    x0 = json.loads(args.start.read_text())["x0"]
    for path in args.files:
        start = x0[path.name] if isinstance(x0, dict) else x0
        print(json.dumps(fit_file(path, start, args.lobes, args.diffuse, args.loss, args.grid)), flush=True)


if __name__ == "__main__":
    main()
