"""Sampling benchmark: walker-steps per second of emcee with ctfit's log-probability (jitted,
vmapped, ``vectorize=True``) next to a NumPy log-probability of the same model called once per
walker (emcee's default, ``vectorize=False``).

Every figure comes from the same run on the same machine, on the same synthetic data, same
walkers, same number of steps, same starting ensemble:

- ``ctfit``: :class:`ctfit._sample._Engine`, the function :func:`ctfit.sample` hands to emcee
  (one call per half ensemble; compiled before the clock starts).
- ``NumPy per sample``: the same posterior — one Beckmann lobe, V-cavity G, the paper's Fresnel
  with the effective index from F0, sigma-weighted Gaussian likelihood, flat priors in (m, F0)
  with the log-Jacobian of the (exp, sigmoid) transforms — written the straightforward way: one
  value per sample, H, D, G and F computed per sample on each call (unit vectors from the
  angles computed once).
- ``NumPy grid``: the same, written the efficient way: ctfit's own precomputed geometry per
  direction pair, D·G once per pair, F per pair × band. It shows how much of the speed-up is
  the layout and how much is XLA (fusion, constant folding) and the batching over walkers.

Both NumPy functions are checked equal to ctfit's log-probability (to 1e-9 relative), and the
three chains equal up to rounding (same moves, same random numbers), before anything is timed.

Both columns include emcee's own per-step work (the stretch move, the bookkeeping), which is
the same for both; ``log-prob only`` times the functions alone on one ensemble.

Usage: ``python scripts/bench_sample.py [--pairs 500] [--bands 8] [--walkers 32] [--steps 200]
[--sizes 100,500,2000] [--markdown]``
"""

from __future__ import annotations

import argparse
import os
import platform
import time
import warnings

import numpy as np


def _setup():
    import jax

    jax.config.update("jax_platforms", "cpu")
    jax.config.update("jax_enable_x64", True)
    return jax


class NumpyLogProb:
    """log p(u | y) for one walker u = (u_F0[0..W-1], u_m) of a one-lobe metal, in NumPy."""

    def __init__(self, problem):
        g = problem.geom
        a = lambda x: np.asarray(x, dtype=float)  # noqa: E731
        self.valid = a(g.valid)[:, None] > 0
        self.tan2 = a(g.tan2_h)
        self.cos_vh = np.clip(a(g.cos_vh), 0, 1)[:, None]
        cl, cv, ch, cvh = a(g.cos_l), a(g.cos_v), a(g.cos_h), a(g.cos_vh)
        self.g_red = np.minimum(1 / (cl * cv), np.minimum(2 * ch / (cvh * cl), 2 * ch / (cvh * cv)))
        self.y = a(problem.y)
        self.inv_sigma = 1 / a(problem.sigma)
        self.mask = a(problem.mask)
        self.k = 0.25 / np.pi

    def __call__(self, x):
        u_f0, u_m = x[:-1], x[-1]
        f0 = 1 / (1 + np.exp(-u_f0))
        m2 = np.exp(2 * u_m)
        t = self.tan2
        dg = self.k * np.exp(-t / m2) * (1 + t) ** 2 / m2 * self.g_red  # per pair
        r = np.sqrt(f0)
        n = (1 + r) / (1 - r)
        c = self.cos_vh
        g = np.sqrt(n * n + c * c - 1)
        f = 0.5 * (g - c) ** 2 / (g + c) ** 2 * (1 + ((c * (g + c) - 1) / (c * (g - c) + 1)) ** 2)
        model = np.where(self.valid, f * dg[:, None], 0.0)
        res = (model - self.y) * self.inv_sigma * self.mask
        log_jac = np.sum(-np.logaddexp(0, -u_f0) - np.logaddexp(0, u_f0)) + u_m
        out = -0.5 * np.sum(res * res) + log_jac
        return out if np.isfinite(out) else -np.inf


class NumpyLogProbPerSample:
    """The same log-probability written the straightforward way: every sample with its own light
    and view vectors (unit vectors from the file's angles, computed once), H, the cosines, D, G
    and F evaluated per sample on every call, F0 gathered from the band table."""

    def __init__(self, data):
        def unit(theta, phi):
            t, p = np.deg2rad(theta), np.deg2rad(phi)
            return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=1)

        self.l = unit(data.theta_i, data.phi_i)
        self.v = unit(data.theta_o, data.phi_o)
        self.band = data.band
        self.y = data.brdf
        self.sigma = data.sigma

    def __call__(self, x):
        u_f0, u_m = x[:-1], x[-1]
        f0 = 1 / (1 + np.exp(-u_f0))[self.band]
        m2 = np.exp(2 * u_m)
        l, v = self.l, self.v
        h = l + v
        h = h / np.linalg.norm(h, axis=1)[:, None]
        nl, nv, nh = l[:, 2], v[:, 2], h[:, 2]
        c = np.clip(np.sum(v * h, axis=1), 0, 1)
        tan2 = (1 - nh * nh) / (nh * nh)
        d = np.exp(-tan2 / m2) / (np.pi * m2 * nh**4)
        g = np.minimum(1, np.minimum(2 * nh * nv / c, 2 * nh * nl / c))
        r = np.sqrt(f0)
        n = (1 + r) / (1 - r)
        gg = np.sqrt(n * n + c * c - 1)
        f = 0.5 * (gg - c) ** 2 / (gg + c) ** 2 * (1 + ((c * (gg + c) - 1) / (c * (gg - c) + 1)) ** 2)
        model = np.where((nl > 0) & (nv > 0), f * d * g / (4 * nl * nv), 0.0)
        res = (model - self.y) / self.sigma
        log_jac = np.sum(-np.logaddexp(0, -u_f0) - np.logaddexp(0, u_f0)) + u_m
        out = -0.5 * np.sum(res * res) + log_jac
        return out if np.isfinite(out) else -np.inf


def _setup_problem(pairs: int, bands: int, seed: int = 0):
    import jax.numpy as jnp

    import ctfit
    from ctfit._problem import from_params, make_problem
    from ctfit._sample import _Engine, _Layout, _normalise_priors
    from ctfit._simulate import simulate

    wl = np.linspace(400.0, 700.0, bands)
    f0 = 0.55 + 0.4 / (1 + np.exp(-(wl - 570.0) / 25.0))
    st = ctfit.Structure(lobes=1)
    truth = ctfit.Material(st, ctfit.Params(m=np.array([0.25]), w=np.array([1.0]), f0=f0), wavelength_nm=wl)
    data = simulate(truth, pairs, noise=0.02, seed=seed)
    problem = make_problem(st, data, fixed_params=truth.params, loss="sigma")
    u0 = {k: jnp.asarray(v) for k, v in from_params(problem.spec, truth.params).items()}
    names = tuple(sorted(u0))  # ("f0", "m"): flat = (u_F0..., u_m)
    layout = _Layout(names, tuple(np.shape(u0[k]) for k in names), False, False, False)
    x0 = np.concatenate([np.ravel(u0[k]) for k in names])
    return problem, layout, _normalise_priors(None, layout, st), x0, data, _Engine


def run(pairs: int, bands: int, walkers: int, steps: int, seed: int = 0) -> dict:
    import emcee

    problem, layout, prior, x0, data, Engine = _setup_problem(pairs, bands, seed)
    engine = Engine(problem, layout, prior, walkers // 2)
    refs = {"numpy": NumpyLogProbPerSample(data), "numpy_grid": NumpyLogProb(problem)}
    rng = np.random.default_rng(seed)
    start = x0 + 1e-3 * rng.standard_normal((walkers, x0.size))
    # Same posterior: compare on the starting ensemble.
    lp_jax = engine(start)
    for ref in refs.values():
        np.testing.assert_allclose(np.array([ref(x) for x in start]), lp_jax, rtol=1e-9)

    out = {"pairs": pairs, "bands": bands, "samples": len(data), "walkers": walkers, "steps": steps, "ndim": x0.size}
    # log-prob alone, one ensemble (best of 7).
    def best(fn):
        ts = []
        for _ in range(7):
            t = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t)
        return 1e6 * min(ts) / walkers

    half = start[: walkers // 2]
    out["logprob_ctfit_per_walker_us"] = best(lambda: engine(half)) * 2  # per walker of a half-ensemble call
    for name, ref in refs.items():
        out[f"logprob_{name}_per_walker_us"] = best(lambda: [ref(x) for x in start])

    def timed(fn, vectorize, repeat=2):
        best = np.inf
        for _ in range(repeat):  # best of ``repeat`` identical runs (the machine may be shared)
            s = emcee.EnsembleSampler(walkers, x0.size, fn, vectorize=vectorize)
            s.random_state = np.random.RandomState(seed).get_state()
            t = time.perf_counter()
            s.run_mcmc(start, steps)
            best = min(best, time.perf_counter() - t)
        return walkers * steps / best, float(np.mean(s.acceptance_fraction)), s.get_chain()

    out["ctfit_walker_steps_per_s"], acc_j, chain_j = timed(engine, True)
    # emcee's own ceiling: the same run with a trivial (vectorised) log-probability.
    out["emcee_only_walker_steps_per_s"], _, _ = timed(lambda xs: -0.5 * np.sum((xs - x0) ** 2, axis=1) * 1e6, True)
    out["same_chain"] = True
    for name, ref in refs.items():
        out[f"{name}_walker_steps_per_s"], _, chain_n = timed(ref, False)
        out[f"{name}_speedup"] = out["ctfit_walker_steps_per_s"] / out[f"{name}_walker_steps_per_s"]
        out[f"{name}_logprob_speedup"] = out[f"logprob_{name}_per_walker_us"] / out["logprob_ctfit_per_walker_us"]
        # Same moves, same random numbers, same posterior: the same chain up to rounding.
        out["same_chain"] &= bool(np.allclose(chain_j, chain_n, rtol=1e-6, atol=1e-9))
    out["acceptance"] = acc_j
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pairs", type=int, default=None, help="one size only (direction pairs)")
    ap.add_argument("--sizes", default="100,500,2000", help="direction pairs, comma separated")
    ap.add_argument("--bands", type=int, default=8)
    ap.add_argument("--walkers", type=int, default=32)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--markdown", action="store_true", help="print a Markdown table")
    args = ap.parse_args(argv)
    _setup()
    warnings.simplefilter("ignore", RuntimeWarning)
    sizes = [args.pairs] if args.pairs else [int(s) for s in args.sizes.split(",")]
    rows = [run(p, args.bands, args.walkers, args.steps) for p in sizes]
    import jax

    print("# emcee alone: the same run with a trivial vectorised log-probability (emcee's own per-step cost)")
    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} cores, jax {jax.__version__} (CPU, float64), "
          f"{args.walkers} walkers, {args.steps} steps, {args.bands} bands")
    cols = [("numpy", "NumPy per sample"), ("numpy_grid", "NumPy grid")]
    if args.markdown:
        print("| pairs | samples | ctfit walker-steps/s | " + " | ".join(f"{t} walker-steps/s | speed-up" for _, t in cols)
              + " | log-prob µs/walker: ctfit | " + " | ".join(t for _, t in cols) + " | emcee alone walker-steps/s |")
        print("|" + "---:|" * (3 + 2 * len(cols) + 1 + len(cols) + 1))
        for r in rows:
            print(f"| {r['pairs']} | {r['samples']} | {r['ctfit_walker_steps_per_s']:.0f} | "
                  + " | ".join(f"{r[k + '_walker_steps_per_s']:.0f} | {r[k + '_speedup']:.1f}×" for k, _ in cols)
                  + f" | {r['logprob_ctfit_per_walker_us']:.1f} | "
                  + " | ".join(f"{r['logprob_' + k + '_per_walker_us']:.1f}" for k, _ in cols)
                  + f" | {r['emcee_only_walker_steps_per_s']:.0f} |")
    else:
        for r in rows:
            print(f"pairs {r['pairs']:>6} ({r['samples']:>6} samples): walker-steps/s ctfit {r['ctfit_walker_steps_per_s']:>8.0f}  "
                  + "  ".join(f"{t} {r[k + '_walker_steps_per_s']:>7.0f} ({r[k + '_speedup']:.1f}×)" for k, t in cols)
                  + f"  | log-prob µs/walker ctfit {r['logprob_ctfit_per_walker_us']:.1f}, "
                  + ", ".join(f"{t} {r['logprob_' + k + '_per_walker_us']:.1f}" for k, t in cols)
                  + f" | emcee alone {r['emcee_only_walker_steps_per_s']:.0f} | same chain: {r['same_chain']}")
    return rows


if __name__ == "__main__":
    main()
