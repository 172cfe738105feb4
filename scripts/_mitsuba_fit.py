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
- ``fit-plastic DATA.npz OUT.npz [STEPS]``: the peer of ``bench_real.py``. Mitsuba's
  ``roughplastic`` (Beckmann, Mitsuba's default distribution) with α, the index ``int_ior`` (η,
  ``ext_ior`` = 1) and an RGB ``diffuse_reflectance`` free (one grey value for single-band data:
  ``value`` of shape (1, N)), started from α = 0.3, η = 1.5, ρ = 0.5; Adam (lr 0.05), log loss
  mean((ln(1 + f cos θ_i) − ln(1 + y cos θ_i))²) over the finite values of DATA's ``value`` (C, N)
  (the BRDF f, sr⁻¹, no cosine), STEPS iterations (1,000), α in [10⁻³, 2], η in [1.01, 4], ρ in
  [0, 1] after each step. Writes the fitted f (C, N) to OUT.npz and prints the result as one JSON line.

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


def _plastic_loss(bsdf, ctx, si, wo, cos_i, cos_o, target, weight):
    f = bsdf.eval(ctx, si, wo) / cos_o
    return dr.sum(dr.square(dr.log(1 + f * cos_i) - target) * weight, axis=None) / dr.sum(weight, axis=None), f


def fit_plastic(data_path: str, out_path: str, steps: int = ITERATIONS) -> None:
    z = np.load(data_path)
    t_load = time.perf_counter()
    value = np.asarray(z["value"], dtype=float)
    grey = value.shape[0] == 1
    value = np.repeat(value, 3, axis=0) if grey else value  # grey: three equal channels, the same loss
    finite = np.isfinite(value)
    ctx, si = mi.BSDFContext(), _interaction(z["light"])
    wo = mi.Vector3f(np.ascontiguousarray(z["view"].T, dtype=np.float32))
    cos_i, cos_o = mi.Float(z["light"][:, 2].astype(np.float32)), mi.Float(z["view"][:, 2].astype(np.float32))
    target = dr.log(1 + mi.Color3f(np.where(finite, value, 0).astype(np.float32)) * cos_i)
    weight = mi.Color3f(finite.astype(np.float32))
    bsdf = mi.load_dict({"type": "roughplastic", "distribution": "beckmann", "alpha": START["alpha"], "int_ior": START["eta"], "ext_ior": 1.0,
                         "diffuse_reflectance": {"type": "rgb", "value": [0.5] * 3}})
    params = mi.traverse(bsdf)
    opt = mi.ad.Adam(lr=LR)
    opt["alpha"], opt["eta"] = mi.Float(START["alpha"]), mi.Float(START["eta"])
    opt["rho"] = mi.Float(0.5) if grey else mi.Color3f(0.5)

    def apply():
        params["alpha"], params["eta"] = opt["alpha"], opt["eta"]
        params["diffuse_reflectance.value"] = mi.Color3f(opt["rho"], opt["rho"], opt["rho"]) if grey else opt["rho"]
        params.update()

    apply()
    for _ in range(steps):
        loss, _ = _plastic_loss(bsdf, ctx, si, wo, cos_i, cos_o, target, weight)
        dr.backward(loss)
        opt.step()
        opt["alpha"] = dr.clip(opt["alpha"], 1e-3, 2.0)
        opt["eta"] = dr.clip(opt["eta"], 1.01, 4.0)
        opt["rho"] = dr.clip(opt["rho"], 0.0, 1.0)
        apply()
    loss, f = _plastic_loss(bsdf, ctx, si, wo, cos_i, cos_o, target, weight)
    f = np.array(f, dtype=np.float64).reshape(3, -1)
    np.savez(out_path, value=f[:1] if grey else f)
    rho = np.array(opt["rho"]).reshape(-1)
    print(json.dumps(dict(alpha=float(np.array(opt["alpha"]).reshape(-1)[0]), eta=float(np.array(opt["eta"]).reshape(-1)[0]),
                          diffuse_reflectance=rho.tolist(), loss=float(np.array(loss).reshape(-1)[0]), iterations=steps, import_s=t_load - T0,
                          fit_s=time.perf_counter() - t_load)), flush=True)


def main(argv: list[str]) -> int:
    mi.set_variant(VARIANT)
    if argv[:1] == ["render"] and len(argv) == 3:
        render(argv[1], argv[2])
    elif argv[:1] == ["fit"] and len(argv) == 2:
        fit(argv[1])
    elif argv[:1] == ["fit-plastic"] and len(argv) in (3, 4):
        fit_plastic(argv[1], argv[2], *map(int, argv[3:]))
    else:
        print("usage: _mitsuba_fit.py render DIRS.npz OUT.npz | fit DATA.npz | fit-plastic DATA.npz OUT.npz [STEPS]", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
