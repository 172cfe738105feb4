"""Fitting: error against run time over solver, precision, bands, samples, lobes and loss.

Synthetic truth from ``ctfit.simulate``: a metal (Beckmann lobes, V-cavity G, the paper's
effective-index Fresnel, no diffuse part) with known parameters — one lobe m = 0.2; two lobes
m = (0.2, 0.4), w = (0.6, 0.4); three lobes m = (0.1, 0.25, 0.5), w = (0.4, 0.35, 0.25) — and
F0 rising linearly from 0.5 at 400 nm to 0.95 at 700 nm; 2 % relative Gaussian noise (the
samples carry σ), ``seed=1``. Samples = direction pairs × bands (every pair in every band).

The sweep varies one axis at a time around a standard case (2 lobes, 31 bands, 645 pairs × 31
= 19,995 samples, float64, Levenberg–Marquardt, loss ``auto``, which is σ-weighted for this
data): solver (lm, gauss-newton, dogleg, bfgs), precision (float64, float32), bands (8, 16, 31,
81 at ≈ 20,000 samples), samples (2k, 20k, 200k, 1M at 31 bands), lobes (1, 2, 3) and loss
(auto = sigma, absolute, relative, cosine, log). Every ctfit run is ``ctfit.fit`` with its
defaults otherwise (3 grid seeds, max_steps 256), called twice in the same process: the first
call includes tracing and XLA compilation (JAX's persistent cache is off), the second is warm
(best of up to 3 warm calls).

Peer, in the same run: ``scipy.optimize.least_squares`` (MINPACK ``lm``; ``trf`` on the
smaller data sets) on the NumPy model of ``_numpy_model.py`` with the same parameterisation and
loss, finite-difference Jacobian, default tolerances, started from ctfit's best grid seed (the
seeding is not timed for SciPy), on every data set of the bands, samples and lobes axes and for
every loss.

Errors: the fitted model against the noise-free truth and against the data, as a relative RMS
√mean(((f − t)/max(t, 10⁻³ max t))²); parameter errors max |Δm|/m, max |Δw|, max |ΔF0| (lobes in
ascending m), and their maximum ("parameter error").

The recommendation: ctfit's current default (lm, float64, loss auto) stays unless another
configuration is within the error tolerance on the standard case and at least 25 % faster
(warm) there, and then — run over the bands, samples and lobes axes — within the tolerance and
nowhere more than 25 % slower than the default. Tolerance: converged, no non-finite values, and
relative RMS error against the truth and parameter error each at most 1.5 × the best of any run
(ctfit or SciPy) on the same data.

Usage: ``python scripts/fit_tradeoffs.py [--docs DIR] [--small] [--json FILE] [--from-json FILE]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import gc
import inspect
import json
import os
import pathlib
import platform
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

from _docs import DOCS, figure_link, write_section  # noqa: E402
from _numpy_model import NumpyProblem  # noqa: E402

SECTION = "## Fitting: error against run time"
DOC_NAME = "fitting-tradeoffs.md"
FIGURE_NAME = "fit_error_vs_time.png"
NOISE = 0.02
SEED = 1
TRUE_M = {1: (0.2,), 2: (0.2, 0.4), 3: (0.1, 0.25, 0.5)}
TRUE_W = {1: (1.0,), 2: (0.6, 0.4), 3: (0.4, 0.35, 0.25)}
TOL = 1.5  # error tolerance: × the best run on the same data
SPEED_MARGIN = 0.25  # a challenger must be ≥ 25 % faster (timings on a shared machine: ±20 %)
DEFAULT = ("lm", "float64", "auto")


@dataclasses.dataclass(frozen=True)
class Case:
    lobes: int
    bands: int
    pairs: int

    @property
    def samples(self) -> int:
        return self.pairs * self.bands

    def label(self) -> str:
        return f"{self.samples:,} ({self.pairs:,} × {self.bands})"


@dataclasses.dataclass(frozen=True)
class Config:
    solver: str = "lm"
    dtype: str = "float64"
    loss: str = "auto"

    def label(self) -> str:
        return f"ctfit {self.solver} {self.dtype}" + ("" if self.loss == "auto" else f" {self.loss}")


def sweep(small: bool):
    """(standard case, {axis: [(value label, Case, Config)]}, robustness cases, largest sample count for SciPy trf)."""
    if small:
        # Tiny: one lobe (the smallest compiled fit), 4 bands, 400 and 200 samples. Three compiled
        # fits in all (float64 and float32 on the standard data, float64 on the samples point: a
        # new data shape is a new program), which is most of the run time; SciPy (lm and trf)
        # runs on both data sets.
        std = Case(1, 4, 100)
        axes = {
            "precision": [("float32", std, Config(dtype="float32"))],
            "samples": [(Case(1, 4, 50).label(), Case(1, 4, 50), Config())],
        }
        robust = []  # no robustness runs: every first call compiles, and the small sweep must stay quick
        trf_max = 10_000
    else:
        std = Case(2, 31, 645)
        axes = {
            "solver": [(s, std, Config(solver=s)) for s in ("gauss-newton", "dogleg", "bfgs")],
            "precision": [("float32", std, Config(dtype="float32"))],
            "bands": [(str(b), Case(2, b, p), Config()) for b, p in ((8, 2500), (16, 1250), (81, 247))],
            "samples": [(Case(2, 31, p).label(), Case(2, 31, p), Config()) for p in (65, 6452, 32258)],
            "lobes": [(str(j), Case(j, 31, 645), Config()) for j in (1, 3)],
            "loss": [(loss, std, Config(loss=loss)) for loss in ("absolute", "relative", "cosine", "log")],
        }
        robust = [c for ax in ("bands", "samples", "lobes") for v, c, _ in axes[ax] if v != "16"]
        trf_max = 250_000
    return std, axes, robust, trf_max


# --- data and error measures


def f0_true(wl):
    return 0.5 + 0.45 * (np.asarray(wl, dtype=float) - 400.0) / 300.0


def make_case(case: Case):
    import ctfit
    from ctfit import evaluate, simulate

    wl = np.linspace(400.0, 700.0, case.bands)
    st = ctfit.Structure(lobes=case.lobes)
    mat = ctfit.Material(st, ctfit.Params(m=np.array(TRUE_M[case.lobes]), w=np.array(TRUE_W[case.lobes]), f0=f0_true(wl)), wavelength_nm=wl, name="truth")
    data = simulate(mat, case.pairs, wavelength_nm=wl, noise=NOISE, seed=SEED)
    return dict(case=case, structure=st, material=mat, data=data, truth=evaluate(mat, data), wl=wl)


def _rel_rms(f, ref):
    floor = 1e-3 * float(np.max(ref))
    return float(np.sqrt(np.mean(((f - ref) / np.maximum(ref, floor)) ** 2)))


def errors(d, m, w, f0, cost) -> dict:
    """Error measures of fitted (m, w, F0) on data set ``d`` (model evaluated by ctfit in float64)."""
    import ctfit
    from ctfit import evaluate

    m, w, f0 = (np.asarray(a, dtype=float).reshape(-1) for a in (m, w, f0))
    order = np.argsort(m)
    m, w = m[order], w[order]
    nonfinite = int(np.sum(~np.isfinite(m)) + np.sum(~np.isfinite(w)) + np.sum(~np.isfinite(f0)) + (0 if np.isfinite(cost) else 1))
    out = dict(m=m.tolist(), w=w.tolist())
    if nonfinite:
        return dict(out, nonfinite=nonfinite, rel_rms_truth=float("nan"), rel_rms_data=float("nan"), m_err=float("nan"), w_err=float("nan"),
                    f0_err=float("nan"), param_err=float("nan"))
    fitted = ctfit.Material(d["structure"], ctfit.Params(m=m, w=w, f0=f0), wavelength_nm=d["wl"], name="fit")
    f = evaluate(fitted, d["data"])
    nonfinite += int(np.sum(~np.isfinite(f)))
    tm, tw = np.array(TRUE_M[d["case"].lobes]), np.array(TRUE_W[d["case"].lobes])
    e = dict(
        m_err=float(np.max(np.abs(m / tm - 1))),
        w_err=float(np.max(np.abs(w - tw))),
        f0_err=float(np.max(np.abs(f0 - f0_true(d["wl"])))),
    )
    return dict(out, nonfinite=nonfinite, rel_rms_truth=_rel_rms(f, d["truth"]), rel_rms_data=_rel_rms(f, d["data"].brdf), param_err=max(e.values()), **e)


# --- runs


def run_ctfit(d, cfg: Config) -> dict:
    import jax.numpy as jnp

    from ctfit import fit

    dtype = getattr(jnp, cfg.dtype)

    def call():
        gc.collect()
        t = time.perf_counter()
        r = fit(d["data"], d["structure"], loss=cfg.loss, solver=cfg.solver, dtype=dtype)
        return r, time.perf_counter() - t

    r, first = call()
    warm, spent = [], 0.0
    while len(warm) < 3 and (not warm or spent < 1.5):
        r2, t = call()
        warm.append(t)
        spent += t
    p = r2.material.params
    same = bool(np.array_equal(np.asarray(p.f0), np.asarray(r.material.params.f0)))
    row = dict(first_s=first, warm_s=min(warm), converged=r2.converged, steps=r2.stats["steps"], nfev=None, cost=r2.stats["cost"], loss_used=r2.loss,
               warm_same_as_first=same)
    return row | errors(d, p.m, p.w, p.f0, r2.stats["cost"])


def scipy_start(d):
    """ctfit's best grid seed (the start of its best-ranked solve, ``ctfit.seed_params``), as
    SciPy's flat vector: logit F0, log m and the weights' logits against w_0 (the sampler's
    unconstrained coordinates)."""
    import ctfit

    seed = ctfit.seed_params(d["data"], d["structure"], starts=1, loss="sigma")[0]
    f0, m = np.asarray(seed.f0, dtype=float), np.asarray(seed.m, dtype=float)
    u = [np.log(f0) - np.log1p(-f0), np.log(m)]
    if m.size > 1:
        w = np.asarray(seed.w, dtype=float)
        u.append(np.log(w[1:]) - np.log(w[0]))
    return np.concatenate(u)


def run_scipy(d, method: str, loss: str, x0) -> dict:
    from scipy.optimize import least_squares

    loss = "sigma" if loss == "auto" else loss
    prob = NumpyProblem(d["data"], lobes=d["case"].lobes, loss=loss)
    gc.collect()
    t = time.perf_counter()
    sol = least_squares(prob.residual, x0, method=method)
    el = time.perf_counter() - t
    f0, m, w = prob.params(sol.x)
    row = dict(first_s=el, warm_s=el, converged=bool(sol.status > 0), steps=None, nfev=int(sol.nfev), cost=float(sol.cost), loss_used=loss,
               warm_same_as_first=True)
    return row | errors(d, m, w, f0, sol.cost)


def machine() -> dict:
    import jax
    import scipy

    return dict(
        date=datetime.date.today().isoformat(),
        platform=platform.platform(),
        processor=platform.processor() or platform.machine(),
        cpus=os.cpu_count(),
        python=platform.python_version(),
        jax=jax.__version__,
        numpy=np.__version__,
        scipy=scipy.__version__,
        load_start=os.getloadavg(),
    )


def warm_up():
    """One tiny fit per precision and one SciPy call, so one-off costs do not land on the first row."""
    d = make_case(Case(1, 4, 40))
    for dt in ("float64", "float32"):
        run_ctfit(d, Config(dtype=dt))
    run_scipy(d, "lm", "sigma", scipy_start(d))


def run(small: bool, log=print) -> dict:
    import jax

    jax.config.update("jax_platforms", "cpu")
    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_enable_compilation_cache", False)  # first calls compile
    info = machine()
    t_start = time.perf_counter()
    std, axes, robust, trf_max = sweep(small)
    cases: dict[Case, dict] = {}
    rows: list[dict] = []

    def data(case):
        if case not in cases:
            cases[case] = make_case(case)
            cases[case]["x0"] = scipy_start(cases[case])
        return cases[case]

    def add(axis, value, case, impl, cfg: Config | None, result):
        row = dict(axis=axis, value=value, impl=impl, lobes=case.lobes, bands=case.bands, pairs=case.pairs, samples=case.samples,
                   solver=cfg.solver if cfg else impl.split()[1], dtype=cfg.dtype if cfg else "float64", loss=cfg.loss if cfg else result["loss_used"]) | result
        rows.append(row)
        log(f"  {axis:9s} {value:24s} {impl:28s} first {row['first_s']:7.2f} s  warm {row['warm_s']:7.3f} s  conv {row['converged']!s:5s} "
            f"relRMS(truth) {row['rel_rms_truth']:.2e}  param {row['param_err']:.2e}  nonfinite {row['nonfinite']}", flush=True)
        return row

    def ctfit_row(axis, value, case, cfg):
        return add(axis, value, case, cfg.label(), cfg, run_ctfit(data(case), cfg))

    def scipy_rows(axis, value, case, loss="auto"):
        d = data(case)
        methods = ("lm", "trf") if case.samples <= trf_max and loss == "auto" else ("lm",)
        for meth in methods:
            add(axis, value, case, f"SciPy {meth}" + ("" if loss == "auto" else f" {loss}"), None, run_scipy(d, meth, loss, d["x0"]))

    if not small:
        log("warm-up (not in the table) ...", flush=True)
        warm_up()
    ctfit_row("standard", "standard", std, Config())
    scipy_rows("standard", "standard", std)
    for axis, points in axes.items():
        for value, case, cfg in points:
            ctfit_row(axis, value, case, cfg)
            if axis in ("bands", "samples", "lobes"):
                scipy_rows(axis, value, case)
            elif axis == "loss":
                scipy_rows(axis, value, case, loss=cfg.loss)

    # Challengers of the default on the standard case, then their robustness runs.
    best = best_errors(rows)
    default_std = find(rows, std, Config())
    challengers = []
    for r in rows:
        if r["impl"].startswith("ctfit") and (r["lobes"], r["bands"], r["pairs"]) == (std.lobes, std.bands, std.pairs):
            cfg = Config(r["solver"], r["dtype"], r["loss"])
            if cfg != Config() and within(r, best) and r["warm_s"] <= (1 - SPEED_MARGIN) * default_std["warm_s"] and cfg not in challengers:
                challengers.append(cfg)
    for cfg in challengers:
        for case in robust:
            if find(rows, case, cfg) is None:
                axis = next(ax for ax, pts in axes.items() if any(c == case for _, c, _ in pts))
                value = next(v for v, c, _ in axes[axis] if c == case)
                ctfit_row(axis, value, case, cfg)
    best = best_errors(rows)
    rec = recommend(rows, std, robust, challengers, best)
    info["load_end"] = os.getloadavg()
    info["total_s"] = time.perf_counter() - t_start
    return dict(machine=info, small=small, standard=dataclasses.asdict(std), robust=[dataclasses.asdict(c) for c in robust], rows=rows, recommendation=rec,
                tolerance=TOL, speed_margin=SPEED_MARGIN)


def key(case_or_row):
    if isinstance(case_or_row, Case):
        return (case_or_row.lobes, case_or_row.bands, case_or_row.pairs)
    return (case_or_row["lobes"], case_or_row["bands"], case_or_row["pairs"])


def find(rows, case: Case, cfg: Config):
    for r in rows:
        if key(r) == key(case) and r["impl"].startswith("ctfit") and (r["solver"], r["dtype"], r["loss"]) == (cfg.solver, cfg.dtype, cfg.loss):
            return r
    return None


def best_errors(rows) -> dict:
    """Per data set: the smallest relative RMS error against the truth and parameter error of any run."""
    out = {}
    for r in rows:
        if r["nonfinite"] or not r["converged"]:
            continue
        b = out.setdefault(key(r), [np.inf, np.inf])
        b[0] = min(b[0], r["rel_rms_truth"])
        b[1] = min(b[1], r["param_err"])
    return out


def within(r, best) -> bool:
    b = best.get(key(r))
    return bool(b and r["converged"] and r["nonfinite"] == 0 and r["rel_rms_truth"] <= TOL * b[0] and r["param_err"] <= TOL * b[1])


def recommend(rows, std: Case, robust, challengers, best) -> dict:
    default = Config()
    d_std = find(rows, std, default)
    verdicts = []
    winner, winner_total = default, None
    for cfg in challengers:
        notes, ok, total, total_default = [], True, 0.0, 0.0
        for case in [std] + list(robust):
            r, rd = find(rows, case, cfg), find(rows, case, default)
            if r is None or rd is None:
                continue
            total += r["warm_s"]
            total_default += rd["warm_s"]
            if not within(r, best):
                ok = False
                notes.append(f"outside the tolerance at {case.label()} samples, {case.lobes} lobe(s)")
            if r["warm_s"] > (1 + SPEED_MARGIN) * rd["warm_s"]:
                ok = False
                notes.append(f"{r['warm_s'] / rd['warm_s']:.1f}× slower than the default at {case.label()} samples, {case.lobes} lobe(s) "
                             f"({r['warm_s']:.2f} s vs {rd['warm_s']:.2f} s warm)")
        verdicts.append(dict(config=dataclasses.asdict(cfg), label=cfg.label(), robust=ok, notes=notes, total_warm_s=total, total_warm_default_s=total_default,
                             standard_speedup=d_std["warm_s"] / find(rows, std, cfg)["warm_s"]))
        if ok and (winner_total is None or total < winner_total):
            winner, winner_total = cfg, total
    return dict(solver=winner.solver, precision=winner.dtype, loss=winner.loss, is_current_default=(winner == default), challengers=verdicts,
                default_within_tolerance=within(d_std, best))


# --- ctfit's own defaults (the doc must agree with them)


def ctfit_defaults() -> dict:
    """Defaults of ``ctfit.fit`` and of ``ctfit fit`` (the CLI) as (solver, precision, loss)."""
    import jax.numpy as jnp
    import typer.main

    import ctfit
    from ctfit.cli import app

    sig = inspect.signature(ctfit.fit).parameters
    lib = (sig["solver"].default, jnp.dtype(sig["dtype"].default).name, sig["loss"].default)
    cs = {p.name: p.default for p in typer.main.get_command(app).commands["fit"].params}
    opt = cs.__getitem__
    cli_d = (opt("solver"), "float32" if opt("float32") else "float64", opt("loss"))
    return dict(library=lib, cli=cli_d)


# --- output


def _g(x, digits=2):
    if x is None:
        return "—"
    if isinstance(x, float) and not np.isfinite(x):
        return "nan"
    return f"{x:.{digits}e}"


def _t(x):
    return f"{x:.3g}" if x < 10 else f"{x:.1f}"


def pareto(points):
    """Indices of the non-dominated (time, error) points (lower is better in both)."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    front, best = [], np.inf
    for i in order:
        if points[i][1] < best * (1 - 1e-3):  # ties (the same optimum found by two codes) are not a new point
            front.append(i)
            best = points[i][1]
    return front


def short(r) -> str:
    impl = r["impl"].replace("ctfit ", "").replace("float64", "f64").replace("float32", "f32")
    return f"{impl}, {r['axis']} {r['value'].split(' ')[0]}" if r["axis"] != "standard" else f"{impl}, standard"


def plot(res, path: pathlib.Path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in res["rows"] if r["nonfinite"] == 0 and np.isfinite(r["param_err"])]
    colours = {"standard": "k", "solver": "tab:red", "precision": "tab:purple", "bands": "tab:blue", "samples": "tab:green", "lobes": "tab:orange",
               "loss": "tab:brown"}
    markers = {"ctfit f64": "o", "ctfit f32": "s", "SciPy lm": "^", "SciPy trf": "v"}

    def marker(r):
        if r["impl"].startswith("SciPy"):
            return markers["SciPy " + r["impl"].split()[1]]
        return markers["ctfit f32"] if r["dtype"] == "float32" else markers["ctfit f64"]

    fig, axs = plt.subplots(1, 2, figsize=(13, 5.5))
    for ax, field, name in ((axs[0], "rel_rms_truth", "relative RMS error against the noise-free "
                                                      "truth"), (axs[1], "param_err", "parameter error max(|Δm|/m, |Δw|, |ΔF0|)")):
        for r in rows:
            scipy_pt = r["impl"].startswith("SciPy")
            c = colours.get(r["axis"], "grey")
            if not scipy_pt:
                ax.plot([r["first_s"], r["warm_s"]], [r[field]] * 2, color=c, lw=0.6, alpha=0.35)
                ax.scatter([r["first_s"]], [r[field]], s=18, marker=marker(r), facecolors="none", edgecolors=c, alpha=0.5, lw=0.8)
            ax.scatter([r["warm_s"]], [r[field]], s=46, marker=marker(r), color=c if not scipy_pt else "white", edgecolors=c, lw=1.4, zorder=3)
        pts = [(r["warm_s"], r[field]) for r in rows]
        front = pareto(pts)
        fx, fy = [pts[i][0] for i in front], [pts[i][1] for i in front]
        ax.step(fx, fy, where="post", color="0.3", ls="--", lw=1, zorder=2)
        ax.scatter(fx, fy, s=150, facecolors="none", edgecolors="0.2", lw=0.8, zorder=4)
        for i in front:
            ax.annotate(short(rows[i]), pts[i], textcoords="offset points", xytext=(6, 4), fontsize=7, color="0.2", rotation=12)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time of the fit call, s (filled/SciPy: warm; small hollow: ctfit first call incl. compilation)")
        ax.set_ylabel(name)
        ax.grid(True, which="both", alpha=0.25)
        ax.xaxis.label.set_fontsize(8)
    handles = [plt.Line2D([], [], ls="", marker="o", color=c, label=f"axis: {a}") for a, c in colours.items()]
    handles += [plt.Line2D([], [], ls="", marker=m, color="0.3", markerfacecolor=("white" if k.startswith("SciPy") else "0.3"), label=k) for k,
                m in markers.items()]
    handles.append(plt.Line2D([], [], ls="--", color="0.3", marker="o", markerfacecolor="none", markersize=10, label="Pareto front (warm times)"))
    axs[1].legend(handles=handles, fontsize=7, loc="upper right")
    fig.suptitle("ctfit.fit and SciPy least_squares on synthetic Cook–Torrance data (2 % noise): error against wall time", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def markdown(res, doc: pathlib.Path, fig: pathlib.Path) -> str:
    mi, rows, rec = res["machine"], res["rows"], res["recommendation"]
    std = Case(**res["standard"])
    defaults = ctfit_defaults()
    lines = [SECTION, ""]
    lines.append(
        f"`scripts/fit_tradeoffs.py{' --small' if res['small'] else ''}` ({mi['date']}; {mi['cpus']}-core CPU ({mi['processor']}, `{mi['platform']}`), "
        f"shared with other jobs — load average {mi['load_start'][0]:.1f} at the start, {mi['load_end'][0]:.1f} at the end of the run; "
        f"Python {mi['python']}, JAX {mi['jax']} on CPU, NumPy {mi['numpy']}, SciPy {mi['scipy']}; the whole run took {mi['total_s']:.0f} s). "
        f"Synthetic truth from `ctfit.simulate`: a metal (Beckmann lobes, V-cavity G, effective-index Fresnel, no diffuse part; one lobe m = 0.2, "
        f"two lobes m = (0.2, 0.4), w = (0.6, 0.4), three lobes m = (0.1, 0.25, 0.5), w = (0.4, 0.35, 0.25); F0 rising linearly from 0.5 at 400 nm "
        f"to 0.95 at 700 nm), {NOISE:.0%} relative Gaussian noise, the samples carry σ; samples = direction pairs × bands. "
        f"One axis varies at a time around the standard case: {std.lobes} lobe{'s' if std.lobes > 1 else ''}, {std.bands} bands, {std.label()} samples, "
        f"Levenberg–Marquardt, float64, loss `auto` (σ-weighted for this data). "
        "ctfit: `ctfit.fit` (3 grid seeds, max_steps 256), called twice in one process with JAX's persistent compilation cache off — "
        "**first call** (tracing + XLA compilation + solve) and **warm** (best of up to 3 further calls); "
        + ("no warm-up fit in `--small`, so the first row's first call also carries one-off start-up costs. " if res["small"]
           else "a tiny fit before the sweep takes the one-off start-up costs. ")
        + "SciPy: `least_squares` (MINPACK `lm`, and `trf` on the smaller data sets) on the NumPy model of `scripts/_numpy_model.py` "
        "(same parameterisation and loss), finite-difference Jacobian, default tolerances, started from ctfit's best grid seed (seeding not timed), "
        "one call (no compilation, so its time is in both columns)."
    )
    axes_seen = {}
    for r in rows:
        if r["axis"] != "standard" and (r["impl"].startswith("ctfit") or r["axis"] in ("loss",)):
            vals = axes_seen.setdefault(r["axis"], [])
            if r["value"] not in vals:
                vals.append(r["value"])
    lines.append("")
    lines.append("Axes (besides the standard case): " + "; ".join(f"{a}: {', '.join(v)}" for a, v in axes_seen.items()) + ".")
    lines.append("")
    lines.append(
        "Errors: relative RMS = √mean(((f − t)/max(t, 10⁻³ max t))²) of the fitted model f against the noise-free truth t (and against the noisy "
        "data); parameter errors max |Δm|/m, max |Δw|, max |ΔF0| over lobes and bands (lobes in ascending m). \"steps\": ctfit's solver "
        "steps for the best of its seeds; for SciPy the number of residual evaluations (nfev, including the finite-difference Jacobian's)."
    )
    lines.append("")
    lines.append("| axis | value | run | samples (pairs × bands) | first call, s | warm, s | converged | steps | rel. RMS vs truth | rel. RMS vs data | max "
                 "\\|Δm\\|/m | max \\|Δw\\| | max \\|ΔF0\\| | non-finite |")
    lines.append("|---|---|---|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        steps = str(r["steps"]) if r["steps"] is not None else f"nfev {r['nfev']}"
        lines.append(
            f"| {r['axis']} | {r['value']} | {r['impl']} | {Case(r['lobes'], r['bands'], r['pairs']).label()} | {_t(r['first_s'])} | {_t(r['warm_s'])} | "
            f"{'yes' if r['converged'] else '**no**'} | {steps} | {_g(r['rel_rms_truth'])} | {_g(r['rel_rms_data'])} | {_g(r['m_err'])} | "
            f"{_g(r['w_err']) if r['lobes'] > 1 else '—'} | {_g(r['f0_err'])} | {r['nonfinite']} |"
        )
    lines.append("")

    # ctfit (default) against SciPy lm on the same data.
    lines.append("ctfit with its defaults against SciPy `lm` on the same data (speed-up = SciPy time / ctfit time):")
    lines.append("")
    lines.append("| data | ctfit first call, s | ctfit warm, s | SciPy lm, s | speed-up, first call | speed-up, warm | SciPy lm cost / ctfit cost |")
    lines.append("|---|---:|---:|---:|---:|---:|---:|")
    seen = set()
    for r in rows:
        if r["impl"] != "SciPy lm" or key(r) in seen:
            continue
        seen.add(key(r))
        c = find(rows, Case(r["lobes"], r["bands"], r["pairs"]), Config())
        if c is None:
            continue
        desc = f"{r['lobes']} lobe{'s' if r['lobes'] > 1 else ''}, {Case(r['lobes'], r['bands'], r['pairs']).label()}"
        lines.append(f"| {desc} | {_t(c['first_s'])} | {_t(c['warm_s'])} | {_t(r['warm_s'])} | {r['warm_s'] / c['first_s']:.2g}× | "
                     f"{r['warm_s'] / c['warm_s']:.2g}× | {r['cost'] / c['cost']:.6f} |")
    lines.append("")

    # Observations, from the numbers above.
    obs = []
    d_std = find(rows, std, Config())
    best = best_errors(rows)
    b_std = best.get(key(std))
    if b_std:
        obs.append(f"On the standard case the best relative RMS error against the truth is {b_std[0]:.2e} and the best parameter error "
                   f"{b_std[1]:.2e} (the noise floor of {std.label()} samples at {NOISE:.0%} noise); the tolerance below is {TOL}× these.")
    slow = [r for r in rows if r["impl"].startswith("ctfit") and key(r) == key(std) and r is not d_std and r["loss"] == "auto"]
    for r in slow:
        state = "within" if within(r, best) else "**outside**"
        obs.append(f"{r['impl']}: warm {_t(r['warm_s'])} s vs {_t(d_std['warm_s'])} s for the default ({r['warm_s'] / d_std['warm_s']:.2g}×), "
                   f"first call {_t(r['first_s'])} s vs {_t(d_std['first_s'])} s; {r['steps']} steps, converged: {'yes' if r['converged'] else 'no'}; "
                   f"{state} the tolerance (relative RMS error {r['rel_rms_truth']:.2e}, parameter error {r['param_err']:.2e}).")
    losses = [r for r in rows if r["axis"] == "loss" and r["impl"].startswith("ctfit")]
    if losses:
        obs.append("Losses on the standard data (relative RMS error against the truth, parameter error, warm time): default `auto` (σ) "
                   f"{d_std['rel_rms_truth']:.2e}, {d_std['param_err']:.2e}, {_t(d_std['warm_s'])} s; "
                   + "; ".join(f"`{r['loss']}` {r['rel_rms_truth']:.2e}, {r['param_err']:.2e}, {_t(r['warm_s'])} "
                               f"s{'' if within(r, best) else ' (outside the tolerance)'}"
                               for r in losses)
                   + ". The noise is relative, so σ weighting is the maximum-likelihood choice.")
    for v in rec["challengers"]:
        obs.append(f"Challenger {v['label']} ({v['standard_speedup']:.2g}× faster warm than the default on the standard case): "
                   + ("robust over the bands, samples and lobes axes" if v["robust"] else "not robust — " + "; ".join(v["notes"]))
                   + f"; total warm time over the data sets run with both {v['total_warm_s']:.3g} s vs {v['total_warm_default_s']:.3g} s for the default.")
    bad = [r for r in rows if r["nonfinite"] or not r["converged"]]
    if bad:
        obs.append("Not converged or non-finite: " + "; ".join(f"{r['impl']} ({r['axis']} {r['value']})" for r in bad) + ".")
    else:
        obs.append("Every run converged and every fitted value is finite.")
    lines += [f"- {o}" for o in obs]
    lines.append("")
    lines.append(f"![error against run time]({figure_link(fig, doc)})")
    lines.append("")
    lines.append(
        "Filled markers and SciPy's open triangles: warm wall time; small hollow markers joined by a thin line: the same ctfit run's first call "
        "(with compilation). The Pareto front (dashed, ringed points) is over the warm times of all runs; it mixes data sets, so most of it traces "
        "the cost of more data rather than a choice of solver."
    )
    lines.append("")
    lines.append(
        f"Rule for the recommendation: ctfit's current default (solver `lm`, float64, loss `auto`) stays unless another configuration is within the "
        f"tolerance on the standard case (converged, no non-finite values, relative RMS error against the truth and parameter error each ≤ {TOL}× the "
        f"best of any run on the same data) and at least {SPEED_MARGIN:.0%} faster warm there, and then, run over the bands, samples and lobes axes, "
        f"within the tolerance everywhere and nowhere more than {SPEED_MARGIN:.0%} slower than the default; among several such, the smallest total warm time "
        "wins."
        + (" (`--small` runs no robustness points: its recommendation rests on the standard case alone.)" if res["small"] else
           " Robustness points (run for every challenger): "
           + ", ".join(f"{c['lobes']} lobe(s) × {c['bands']} bands × {c['pairs']:,} pairs" for c in res["robust"])
           + ("." if rec["challengers"] else "; there was no challenger, so none ran."))
    )
    lines.append("")
    loss_txt = "`auto` (σ-weighted when the data has σ, as here; else robust-relative)" if rec["loss"] == "auto" else f"`{rec['loss']}`"
    cur = defaults["library"]
    agree = (rec["solver"], rec["precision"], rec["loss"]) == cur == defaults["cli"]
    lines.append(
        f"**Recommended default:** solver `{rec['solver']}`, precision `{rec['precision']}`, loss {loss_txt}. "
        + ("This is what `ctfit.fit()` and `ctfit fit` use by default." if agree
           else f"ctfit's defaults are currently solver `{cur[0]}`, precision `{cur[1]}`, loss `{cur[2]}` (library) and {defaults['cli']} (CLI): they differ.")
    )
    lines.append("")
    load = max(mi["load_start"][0], mi["load_end"][0])
    lines.append(
        f"Timings come from a {mi['cpus']}-core machine shared with other jobs (load average up to {load:.1f} at the ends of this run"
        + (", i.e. several runnable processes per core" if load > 1.5 * mi["cpus"] else "")
        + f") and are good to a factor of about {2 if load > 1.5 * mi['cpus'] else 1.5} (first calls, which are mostly compilation, vary most); "
        "the errors are deterministic (fixed seeds). Every number above is from the run that wrote this section."
    )
    return "\n".join(lines) + "\n"


def _jsonable(o):
    if isinstance(o, dict):
        return {k: _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, (np.floating, float)):
        return float(o) if np.isfinite(o) else None
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, np.bool_):
        return bool(o)
    return o


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--docs", type=pathlib.Path, default=DOCS, help="folder of the Markdown file (default: the repository's docs/)")
    ap.add_argument("--small", action="store_true", help="a tiny sweep (1 lobe, 4 bands, 200–400 samples) for the test suite")
    ap.add_argument("--json", type=pathlib.Path, help="write the raw numbers here")
    ap.add_argument("--from-json", type=pathlib.Path, help="no runs: write the section and figure again from the raw numbers of an earlier run")
    args = ap.parse_args(argv)
    if args.from_json:
        res = json.loads(args.from_json.read_text(encoding="utf-8"))
        for r in res["rows"]:  # JSON has null for non-finite values
            for k, v in r.items():
                if v is None and k not in ("steps", "nfev"):
                    r[k] = float("nan")
    else:
        res = run(args.small)
    if args.json:  # first, so that the numbers survive whatever follows
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(_jsonable(res), indent=1), encoding="utf-8")
    doc = args.docs / DOC_NAME
    fig = args.docs / "figures" / FIGURE_NAME
    plot(res, fig)
    text = markdown(res, doc, fig)
    if not doc.exists():
        doc.parent.mkdir(parents=True, exist_ok=True)
        doc.write_text("# Fitting trade-offs\n\n", encoding="utf-8")
    write_section(doc, SECTION, text)
    print(text)


if __name__ == "__main__":
    main()
