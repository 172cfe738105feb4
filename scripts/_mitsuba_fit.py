"""Mitsuba 3 for ``bench_fit.py``: render a rough conductor at given directions, and the graphics
community's own way to fit one — Dr.Jit autodiff through Mitsuba's ``roughconductor`` with Adam —
as a whole process. Imports NumPy, Dr.Jit and Mitsuba only.

- ``render DIRS.npz OUT.npz``: Mitsuba's ``roughconductor`` (Beckmann, ``sample_visible`` off,
  α = 0.15, ``material = "Cu"``: Mitsuba's own copper η, k in RGB) evaluated at the direction
  pairs ``light``, ``view`` (N, 3 unit vectors) of DIRS; writes ``value`` (3, N) = f_r · cos θ_o
  (what ``BSDF.eval`` returns) and the true ``alpha``, ``eta``, ``k``.
- ``fit DATA.npz``: the peer. The same BSDF with α, η, k (RGB) free, started from α = 0.3,
  η = 1.5, k = 2 (ctfit's default starting n and k), Adam (``mi.ad.Adam``, lr 0.05), log loss
  mean((ln(1 + f cos θ_o) − ln(1 + y cos θ_o))²) over samples and channels, 1,000 iterations,
  α kept in [10⁻³, 2] and η, k ≥ 0 after each step; prints the result as one JSON line.

Run with ``DRJIT_LIBLLVM_PATH`` naming libLLVM ≥ 17 where the system's default LLVM is older
(Dr.Jit aborts with "Cannot select fmaximum" on LLVM 14/15).
"""

from __future__ import annotations

import json
import sys
import time

T0 = time.perf_counter()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402
import numpy as np  # noqa: E402

VARIANT = "llvm_ad_rgb"
ALPHA, METAL = 0.15, "Cu"
START = dict(alpha=0.3, eta=1.5, k=2.0)
LR, ITERATIONS = 0.05, 1000


def _interaction(light: np.ndarray):
    si = dr.zeros(mi.SurfaceInteraction3f, len(light))
    si.wi = mi.Vector3f(np.ascontiguousarray(light.T, dtype=np.float32))
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    return si


def render(dirs_path: str, out_path: str) -> None:
    z = np.load(dirs_path)
    bsdf = mi.load_dict({"type": "roughconductor", "distribution": "beckmann", "alpha": ALPHA, "material": METAL, "sample_visible": False})
    p = mi.traverse(bsdf)
    value = bsdf.eval(mi.BSDFContext(), _interaction(z["light"]), mi.Vector3f(np.ascontiguousarray(z["view"].T, dtype=np.float32)))
    np.savez(out_path, value=np.array(value, dtype=np.float64), alpha=float(p["alpha.value"][0]),
             eta=np.array(p["eta.value"], dtype=np.float64).reshape(-1), k=np.array(p["k.value"], dtype=np.float64).reshape(-1))


def fit(data_path: str) -> None:
    z = np.load(data_path)
    t_load = time.perf_counter()
    ctx, si = mi.BSDFContext(), _interaction(z["light"])
    wo = mi.Vector3f(np.ascontiguousarray(z["view"].T, dtype=np.float32))
    target = dr.log(1 + mi.Color3f(np.ascontiguousarray(z["value"], dtype=np.float32)))
    bsdf = mi.load_dict({"type": "roughconductor", "distribution": "beckmann", "alpha": START["alpha"], "sample_visible": False,
                         "eta": {"type": "rgb", "value": [START["eta"]] * 3}, "k": {"type": "rgb", "value": [START["k"]] * 3}})
    params = mi.traverse(bsdf)
    opt = mi.ad.Adam(lr=LR)
    for key in ("alpha.value", "eta.value", "k.value"):
        opt[key] = params[key]
    params.update(opt)
    for _ in range(ITERATIONS):
        loss = dr.mean(dr.square(dr.log(1 + bsdf.eval(ctx, si, wo)) - target), axis=None)
        dr.backward(loss)
        opt.step()
        opt["alpha.value"] = dr.clip(opt["alpha.value"], 1e-3, 2.0)
        opt["eta.value"] = dr.maximum(opt["eta.value"], 0.0)
        opt["k.value"] = dr.maximum(opt["k.value"], 0.0)
        params.update(opt)
    out = dict(alpha=float(params["alpha.value"][0]), eta=np.array(params["eta.value"]).reshape(-1).tolist(),
               k=np.array(params["k.value"]).reshape(-1).tolist(), loss=float(loss[0]), iterations=ITERATIONS,
               import_s=t_load - T0, fit_s=time.perf_counter() - t_load)
    print(json.dumps(out), flush=True)


def main(argv: list[str]) -> int:
    mi.set_variant(VARIANT)
    if argv[:1] == ["render"] and len(argv) == 3:
        render(argv[1], argv[2])
    elif argv[:1] == ["fit"] and len(argv) == 2:
        fit(argv[1])
    else:
        print("usage: _mitsuba_fit.py render DIRS.npz OUT.npz | fit DATA.npz", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
