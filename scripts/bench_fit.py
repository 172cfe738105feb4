"""Benchmark of the fit: ctfit (whole process, cold and warm compilation cache) against
``scipy.optimize.least_squares(method="lm")`` on a NumPy implementation of the same model, plus
a MERL-sized fit in process.

The standard case: a two-lobe metal (m = 0.2, 0.4; weights 0.6, 0.4; an F0 spectrum rising from
0.5 to 0.95) at 31 wavelengths 400–700 nm, 6452 direction pairs × 31 bands = 200,012 samples
(grid layout) with 2 % relative Gaussian noise, simulated with ``seed=1``; loss sigma-weighted.

- ctfit: ``python -c`` loads the data (NumPy .npz), enables JAX's persistent compilation cache
  (a fresh temporary directory: run 1 is cold, run 2 warm), calls ``ctfit._fit.fit`` with the
  defaults (grid seeding, 3 starts, structured Levenberg–Marquardt, float64) and prints its
  result; the wall time of the whole process (interpreter start to exit) is reported.
- SciPy: the same residual r = (R − y)/σ with the same parameterisation (log m, the logit of the
  second weight, logit F0 per band) written in NumPy, from ctfit's best grid seed (the start
  ctfit's solver uses for its best run), MINPACK LM with its default finite-difference Jacobian
  and default tolerances; timed in this process (``least_squares`` call only).
- MERL-sized: 1.5 million direction pairs × 3 RGB channels (4.5 million samples), one lobe, no
  sigma (relative loss), in process, float32 and float64; first call (compiling) and second.

``--quick`` runs a small version (1000 pairs; MERL-sized case at 100,000 pairs).
Run: ``.venv/bin/python scripts/bench_fit.py [--quick] [--no-merl]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

CHILD = r"""
import sys, time, json
t0 = time.perf_counter()
import numpy as np
import jax
jax.config.update("jax_enable_x64", True)
from ctfit._cache import enable_compilation_cache
enable_compilation_cache()
from ctfit import Measurement, Structure
from ctfit._fit import fit
z = np.load(sys.argv[1])
data = Measurement(theta_i=z["theta_i"], phi_i=z["phi_i"], theta_o=z["theta_o"], phi_o=z["phi_o"], band=z["band"],
                   wavelength_nm=z["wavelength_nm"], brdf=z["brdf"], sigma=z["sigma"], source=sys.argv[1])
t1 = time.perf_counter()
r = fit(data, Structure(lobes=2))
p = r.material.params
print(json.dumps({"fit_s": time.perf_counter() - t1, "startup_s": t1 - t0, "cost": r.stats["cost"], "steps": r.stats["steps"],
                  "converged": r.converged, "m": np.asarray(p.m).tolist(), "w": np.asarray(p.w).tolist(),
                  "f0": np.asarray(p.f0).tolist()}))
"""

WL31 = np.linspace(400.0, 700.0, 31)
F0_TRUE = np.linspace(0.5, 0.95, 31)
M_TRUE, W_TRUE = np.array([0.2, 0.4]), np.array([0.6, 0.4])


def standard_case(n_pairs: int):
    import ctfit
    from ctfit._simulate import simulate

    st = ctfit.Structure(lobes=2)
    mat = ctfit.Material(st, ctfit.Params(m=M_TRUE, w=W_TRUE, f0=F0_TRUE), wavelength_nm=WL31, name="two-lobe metal")
    return simulate(mat, n_pairs, noise=0.02, seed=1)


# --- NumPy model (same as ctfit: normalised Cook–Torrance, Beckmann, V-cavity G, effective-index F)


def np_geometry(pairs):
    def direction(theta, phi):
        t, p = np.deg2rad(theta), np.deg2rad(np.mod(phi, 360))
        return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.sin(np.deg2rad(90 - theta))], axis=-1)

    l, v = direction(pairs[:, 0], pairs[:, 1]), direction(pairs[:, 2], pairs[:, 3])
    cos_l, cos_v = l[:, 2], v[:, 2]
    valid = (cos_l > 0) & (cos_v > 0)
    n = np.array([0.0, 0.0, 1.0])
    l = np.where(valid[:, None], l, n)
    v = np.where(valid[:, None], v, n)
    cos_l, cos_v = l[:, 2], v[:, 2]
    h = l + v
    h_len = np.linalg.norm(h, axis=1)
    cross = h[:, 0] ** 2 + h[:, 1] ** 2
    return dict(cos_l=cos_l, cos_v=cos_v, cos_h=h[:, 2] / h_len, tan2=cross / h[:, 2] ** 2, cos_vh=0.5 * h_len, valid=valid)


def np_fresnel_f0(c, f0):
    r = np.sqrt(np.maximum(f0, 1e-30))
    c2 = c * c
    s2 = 1 - c2
    one_plus_r = 1 + r
    u = (1 - r) / one_plus_r
    a = 4 * r / (one_plus_r * one_plus_r)
    g2 = c2 + s2 * a
    g = np.sqrt(g2)
    gcu = g + c * u
    p = c * g + s2 * u
    num = 16 * f0 * (c2 * g2 + s2 * s2 * u * u)
    den = (one_plus_r * one_plus_r * gcu * gcu) ** 2 * (p * p)
    return np.clip(num / den, 0, 1)


class NumpyProblem:
    """r(u) = (R(u) − y)/σ on the (pairs × bands) grid, u = (logit F0 (W), log m (2), logit w₂ (1))."""

    def __init__(self, data):
        from ctfit._problem import _directions

        pairs, index = _directions(data)
        self.shape = (len(pairs), data.n_bands)
        self.geom = np_geometry(pairs)
        g = self.geom
        self.g_red = np.minimum(1 / (g["cos_l"] * g["cos_v"]), np.minimum(2 * g["cos_h"] / g["cos_vh"] / g["cos_l"], 2 * g["cos_h"] / g["cos_vh"] / g["cos_v"]))
        self.tan2 = np.minimum(g["tan2"], 1e12)
        self.index, self.band = index, data.band
        self.y, self.sigma = data.brdf, data.sigma
        self.w_bands = data.n_bands

    def model(self, u):
        w_b = self.w_bands
        f0 = 1 / (1 + np.exp(-u[:w_b]))
        m = np.exp(u[w_b : w_b + 2])
        w = np.exp(np.concatenate([[0.0], u[w_b + 2 :]]))
        w /= w.sum()
        t = self.tan2[:, None]
        d = np.exp(-t / m**2) * (1 + t) ** 2 / m**2
        s = (0.25 / np.pi) * self.g_red * (d @ w)
        s = np.where(self.geom["valid"], s, 0.0)
        rgrid = np_fresnel_f0(self.geom["cos_vh"][:, None], f0[None, :]) * s[:, None]
        return rgrid[self.index, self.band]

    def residual(self, u):
        return (self.model(u) - self.y) / self.sigma


def run_ctfit_process(npz: Path, cache: Path) -> dict:
    env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=str(cache), JAX_PLATFORMS="cpu")
    t = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", CHILD, str(npz)], env=env, capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - t
    if out.returncode != 0:
        raise RuntimeError(out.stderr[-3000:])
    res = json.loads(out.stdout.strip().splitlines()[-1])
    res["wall_s"] = wall
    return res


def recovery(m, w, f0) -> str:
    m, w = np.asarray(m), np.asarray(w)
    return (f"m = {np.round(m, 5).tolist()} (max rel. error {np.max(np.abs(m / M_TRUE - 1)):.2e}), "
            f"w = {np.round(w, 5).tolist()} (max abs. error {np.max(np.abs(w - W_TRUE)):.1e}), "
            f"max |ΔF0| = {np.max(np.abs(np.asarray(f0) - F0_TRUE)):.1e}")


def merl_case(n_pairs: int, dtypes) -> list[dict]:
    import jax
    import jax.numpy as jnp

    import ctfit
    from ctfit._fit import fit
    from ctfit._simulate import simulate

    st = ctfit.Structure(lobes=1)
    mat = ctfit.Material(st, ctfit.Params(m=np.array([0.15]), w=np.array([1.0]), f0=np.array([0.9, 0.7, 0.5])), channels=("R", "G", "B"), name="rgb metal")
    data = simulate(mat, n_pairs, noise=0.02, seed=2).replace(sigma=None)  # MERL files have no uncertainties
    rows = []
    for dt in dtypes:
        if dt == "float64":
            jax.config.update("jax_enable_x64", True)
        for call in (1, 2):
            t = time.perf_counter()
            r = fit(data, st, dtype=getattr(jnp, dt))
            rows.append(dict(dtype=dt, call=call, time_s=time.perf_counter() - t, samples=len(data), steps=r.stats["steps"], cost=r.stats["cost"],
                             m=float(np.asarray(r.material.params.m)[0]), f0=np.asarray(r.material.params.f0).round(4).tolist(), converged=r.converged))
            print(f"  MERL-sized {dt} call {call}: {rows[-1]['time_s']:.2f} s, {rows[-1]['steps']} steps, m = {rows[-1]['m']:.5f}, F0 = {rows[-1]['f0']}", flush=True)
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="small version (1000 pairs; MERL-sized case at 100,000 pairs)")
    ap.add_argument("--no-merl", action="store_true", help="skip the MERL-sized case")
    ap.add_argument("--no-scipy", action="store_true", help="skip SciPy")
    args = ap.parse_args()
    n_pairs = 1000 if args.quick else 6452
    import jax

    jax.config.update("jax_enable_x64", True)
    data = standard_case(n_pairs)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs; python {platform.python_version()}, jax {jax.__version__}")
    print(f"standard case: two-lobe metal, {data.n_bands} bands, {len(data)} samples, 2 % noise, loss sigma")
    with tempfile.TemporaryDirectory() as tmp:
        npz = Path(tmp) / "standard.npz"
        np.savez(npz, theta_i=data.theta_i, phi_i=data.phi_i, theta_o=data.theta_o, phi_o=data.phi_o, band=data.band,
                 wavelength_nm=data.wavelength_nm, brdf=data.brdf, sigma=data.sigma)
        cache = Path(tmp) / "jax-cache"
        runs = []
        for label in ("cold", "warm"):
            r = run_ctfit_process(npz, cache)
            runs.append(r)
            print(f"ctfit process ({label} cache): {r['wall_s']:.2f} s wall (fit() {r['fit_s']:.2f} s, imports + load {r['startup_s']:.2f} s), "
                  f"cost {r['cost']:.6f}, {r['steps']} LM iterations, converged {r['converged']}", flush=True)
        print("ctfit recovery: " + recovery(runs[-1]["m"], runs[-1]["w"], runs[-1]["f0"]))

    if not args.no_scipy:
        import jax.numpy as jnp
        from scipy.optimize import least_squares

        from ctfit._fit import _default_start, _m_grid, _seed_points
        from ctfit._problem import from_params, make_problem

        st_seed = __import__("ctfit").Structure(lobes=2)
        start = _default_start(st_seed, data)
        pb = make_problem(st_seed, data, fixed_params=start, loss="sigma")
        u0 = {k: jnp.asarray(v) for k, v in from_params(pb.spec, start).items()}
        seed = jax.tree.map(lambda a: np.asarray(a)[0], _seed_points(pb, u0, 1, jnp.asarray(np.log(_m_grid(2)))))
        x0 = np.concatenate([seed["f0"], seed["m"], seed["w"]])
        nprob = NumpyProblem(data)
        t = time.perf_counter()
        sol = least_squares(nprob.residual, x0, method="lm")
        t_scipy = time.perf_counter() - t
        w_b = data.n_bands
        w = np.exp(np.concatenate([[0.0], sol.x[w_b + 2 :]]))
        print(f"SciPy least_squares(method='lm'): {t_scipy:.2f} s, cost {sol.cost:.6f}, {sol.nfev} function evaluations, status {sol.status}")
        print("SciPy recovery: " + recovery(np.exp(sol.x[w_b : w_b + 2]), w / w.sum(), 1 / (1 + np.exp(-sol.x[:w_b]))))
        print(f"speed-up: {t_scipy / runs[0]['wall_s']:.1f}× (cold process), {t_scipy / runs[1]['wall_s']:.1f}× (warm process), "
              f"{t_scipy / runs[1]['fit_s']:.1f}× (fit() call of the warm process)")

    if not args.no_merl:
        merl_case(100_000 if args.quick else 1_500_000, ("float32", "float64"))


if __name__ == "__main__":
    main()
