"""Stability of the fit on stiff and extreme cases: converged, steps, error, time, non-finite values.

Each case is synthetic data with a known truth, fitted by :func:`ctfit.fit` with its defaults
(grid seeding, 3 starts, structured Levenberg–Marquardt, the sigma-weighted loss the data's
``sigma`` column selects), once in float64 and once in float32 (each its own row). Data:
:func:`ctfit.simulate` (its goniometer sampling, 1 % relative Gaussian noise, the samples
carry the sigma that was used), except where a case says otherwise: two cases need directions
``simulate`` does not draw (grazing-only data; a lobe narrower than ``simulate``'s smallest
spread around the mirror direction), built from :func:`ctfit.goniometer_directions` or a
uniform draw, evaluated with :func:`ctfit.evaluate` and given ``simulate``'s noise model.

Per row:

- converged and steps: ``FitResult.stats``; time: the ``fit`` call, warm (the same fit is run
  twice and the second call is timed; the first call's time, which includes compiling the
  fit for that structure, data shape and dtype, is given where it differs by more than 1 s);
- error: the relative RMS of the fitted model against the noise-free truth at the data's
  directions, ‖R_fit − R_true‖₂/‖R_true‖₂ (the fitted material evaluated in the fit's dtype),
  and the parameter errors where the data determines them (m relative; F0 and s absolute);
- non-finite: the number of NaN/±inf values anywhere in the result — the fitted parameters
  (s, m, w, F0, n, k, R_d), the standard errors, the fitted model at every sample and the
  numeric fit statistics (cost, rmse, rel_rmse, bic, time, relative floor);
- what ctfit reports: the result's warnings (degeneracy, bounds, standard errors, residual
  structure), shortened.

The summary names the fits that did not converge, with the reason read off the result (step
limit, parameters at a bound, singular JᵀJ), and those reported as converged but more than 5 %
(relative RMS) from the truth.

The model itself is also evaluated at the extremes (m from 1e-4 to 3, θ up to 90°, F0 from 0
to 1, a conductor's n or k up to the dtype's largest value, both dtypes), values and gradients
with respect to every parameter; that is tested in
``tests/test_stability.py`` and only counted here (not with ``--small``).

``--small`` runs the cases that share one compiled fit per dtype (one lobe, effective index:
m = 0.00935 and 3, data up to 89.9°, F0 = 1e-6 and 0.999999); the test suite runs it.

Writes the section ``## Stability: stiff and extreme cases`` of ``DIR/stability.md`` and prints
it; exits with status 1 if any non-finite value was found (so ``make report`` fails loudly).

Usage: ``python scripts/stability.py [--docs DIR] [--small] [--json FILE]``
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import math
import os
import pathlib
import platform
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from _docs import DOCS, write_section

SECTION = "## Stability: stiff and extreme cases"
TITLE = "# Stability\n\nWritten by `scripts/stability.py`; do not edit by hand.\n\n"
WL = (400.0, 500.0, 600.0, 700.0)
F0_SPECTRUM = (0.55, 0.70, 0.85, 0.95)
NOISE = 0.01
DTYPES = ("float64", "float32")
MAX_STEPS = 256  # ctfit.fit's default
WRONG = 0.05  # a converged fit further than this (relative RMS) from the truth is flagged


@dataclasses.dataclass(frozen=True)
class Case:
    """One stiff case: a structure, its true parameters and how the data is sampled.

    ``sampling``: "simulate" (``ctfit.simulate``), "mirror" (``goniometer_directions`` with an
    explicit ``spread`` around the mirror direction) or "grazing" (θ_i, θ_o uniform in
    [``min_theta``, ``max_theta``], φ_o within ±30° of the mirror plane). ``compare``: the
    parameters the data determines (compared with the truth). ``start_at_truth``: the fit
    starts from the true parameters (the grid seeding still runs) instead of ctfit's defaults.
    """

    name: str
    truth: str
    structure: dict
    params: dict
    pairs: int = 300
    max_theta: float = 85.0
    min_theta: float = 0.0
    sampling: str = "simulate"
    spread: float = 0.0
    compare: tuple[str, ...] = ("m", "F0")
    start_at_truth: bool = False
    seed: int = 1
    small: bool = False


def _m_case(m: float, note: str = "", **kw) -> Case:
    kw.setdefault("name", f"m = {m:g}")
    return Case(
        truth=f"one Beckmann lobe m = {m:g}, F0 = {', '.join(f'{f:g}' for f in F0_SPECTRUM)}{note}",
        structure=dict(lobes=1),
        params=dict(m=[m], w=[1.0], f0=F0_SPECTRUM),
        **kw,
    )


def _f0_case(f0: float, **kw) -> Case:
    kw.setdefault("name", f"F0 = {f0:g}")
    return Case(
        truth=f"one lobe m = 0.2, F0 = {f0:g} in every band",
        structure=dict(lobes=1),
        params=dict(m=[0.2], w=[1.0], f0=[f0] * len(WL)),
        **kw,
    )


CASES = [
    # One lobe, effective index, no diffuse part: one compiled fit per dtype for all of these.
    _m_case(1e-4, name="m = 1e-4 (simulate's sampling)", note="; `simulate` spreads its mirror samples over ≥ 0.02 rad = 200 m"),
    _m_case(1e-4, name="m = 1e-4 (sampled around the mirror)", sampling="mirror", spread=2.5e-4,
            note="; `goniometer_directions` with a spread of 2.5 m around the mirror direction"),
    _m_case(1e-3),
    _m_case(0.00935, name="m = 0.00935 (chrome-like)", small=True),
    _m_case(0.1),
    _m_case(1.0),
    _m_case(3.0, small=True),
    Case(
        name="data up to θ = 89.9°",
        truth=f"one lobe m = 0.2, F0 = {', '.join(f'{f:g}' for f in F0_SPECTRUM)}; θ_i, θ_o up to 89.9°",
        structure=dict(lobes=1),
        params=dict(m=[0.2], w=[1.0], f0=F0_SPECTRUM),
        max_theta=89.9,
        small=True,
    ),
    _f0_case(1e-6, small=True),
    _f0_case(1e-3),
    _f0_case(0.5),
    _f0_case(0.98),
    _f0_case(0.999999, small=True),
    Case(
        name="grazing-only data",
        truth=f"one lobe m = 0.2, F0 = {', '.join(f'{f:g}' for f in F0_SPECTRUM)}; θ_i, θ_o in [80°, 89.9°] only",
        structure=dict(lobes=1),
        params=dict(m=[0.2], w=[1.0], f0=F0_SPECTRUM),
        sampling="grazing",
        min_theta=80.0,
        max_theta=89.9,
    ),
    Case(
        name="two near-identical lobes",
        truth="two lobes m = 0.2, 0.2002, weights 0.5, 0.5, F0 = 0.9",
        structure=dict(lobes=2),
        params=dict(m=[0.2, 0.2002], w=[0.5, 0.5], f0=[0.9] * len(WL)),
        compare=("F0",),
    ),
    Case(
        name="s = 0 (diffuse only)",
        truth="s = 0, R_d = 0.02–0.08 sr⁻¹; the specular part (m = 0.2, F0 = 0.9) is invisible",
        structure=dict(lobes=1, diffuse="spectrum"),
        params=dict(s=0.0, m=[0.2], w=[1.0], f0=[0.9] * len(WL), rd=(0.02, 0.04, 0.06, 0.08)),
        compare=("s",),
    ),
    Case(
        name="s = 1 (no diffuse)",
        truth="s = 1, one lobe m = 0.2, F0 = 0.9; R_d (0.02–0.08 sr⁻¹) is invisible",
        structure=dict(lobes=1, diffuse="spectrum"),
        params=dict(s=1.0, m=[0.2], w=[1.0], f0=[0.9] * len(WL), rd=(0.02, 0.04, 0.06, 0.08)),
        compare=("s", "m", "F0"),
    ),
    Case(
        name="n(λ) crossing 1 (F0 → 0)",
        truth="conductor Fresnel, n = 1.3, 1.1, 1.0, 0.8 and k = 0: F0 = 0.017, 0.0023, 0, 0.012; one lobe m = 0.2",
        structure=dict(lobes=1, fresnel="conductor"),
        params=dict(m=[0.2], w=[1.0], n=(1.3, 1.1, 1.0, 0.8), k=(0.0, 0.0, 0.0, 0.0)),
    ),
    Case(
        name="n(λ) crossing 1, started at the truth",
        truth="as above; `fit(start=truth)`",
        structure=dict(lobes=1, fresnel="conductor"),
        params=dict(m=[0.2], w=[1.0], n=(1.3, 1.1, 1.0, 0.8), k=(0.0, 0.0, 0.0, 0.0)),
        start_at_truth=True,
    ),
]


# --------------------------------------------------------------------------- data


def _material(case: Case):
    import ctfit

    params = {k: np.asarray(v, dtype=float) for k, v in case.params.items()}
    return ctfit.Material(ctfit.Structure(**case.structure), ctfit.Params(**params), wavelength_nm=np.asarray(WL), name=case.name)


def _measure(material, ti, pi, to, po, seed: int):
    """``simulate``'s measurement and noise model at given direction pairs (every pair × every band)."""
    import ctfit

    nb = len(WL)
    rep = lambda a: np.repeat(np.asarray(a, dtype=float), nb)
    base = ctfit.Measurement(
        theta_i=rep(ti), phi_i=rep(pi) % 360, theta_o=rep(to), phi_o=rep(po) % 360, band=np.tile(np.arange(nb), len(ti)),
        wavelength_nm=np.asarray(WL), source="<stability case>",
    )
    truth = ctfit.evaluate(material, base)
    rng = np.random.default_rng([seed, 1])
    values = np.maximum(truth * (1 + NOISE * rng.standard_normal(truth.shape)), 0.0)
    return base.replace(brdf=values, sigma=NOISE * np.maximum(truth, 1e-6 * np.max(truth)))


def make_data(case: Case):
    """(measurement with noise and sigma, noise-free truth at its samples)."""
    import ctfit

    mat = _material(case)
    if case.sampling == "simulate":
        data = ctfit.simulate(mat, case.pairs, wavelength_nm=np.asarray(WL), noise=NOISE, seed=case.seed, max_theta=case.max_theta)
    elif case.sampling == "mirror":
        ti, pi, to, po = ctfit.goniometer_directions(case.pairs, spread=case.spread, max_theta=case.max_theta, seed=case.seed)
        data = _measure(mat, ti, pi, to, po, case.seed)
    elif case.sampling == "grazing":
        rng = np.random.default_rng(case.seed)
        ti = rng.uniform(case.min_theta, case.max_theta, case.pairs)
        to = rng.uniform(case.min_theta, case.max_theta, case.pairs)
        po = 180.0 + rng.uniform(-30.0, 30.0, case.pairs)
        data = _measure(mat, ti, np.zeros(case.pairs), to, po, case.seed)
    else:
        raise ValueError(f"unknown sampling {case.sampling!r}")
    return data, np.asarray(ctfit.evaluate(mat, data), dtype=float)


# --------------------------------------------------------------------------- one fit


def _non_finite(res, model) -> dict[str, int]:
    """Non-finite counts by place in the result: params.*, stderr.*, model, stats.*."""
    out = {}
    p = res.material.params
    for k in ("s", "m", "w", "f0", "n", "k", "rd"):
        v = getattr(p, k)
        if v is not None:
            out[f"params.{k}"] = int(np.sum(~np.isfinite(np.asarray(v, dtype=float))))
    by_design = set(res.stats.get("no_stderr", ()))  # a parameter on its bound, or one the data does not determine
    for k, v in (res.stderr or {}).items():
        bad = np.flatnonzero(~np.isfinite(np.asarray(v, dtype=float)))
        out[f"stderr.{k}"] = int(sum(f"{k}[{i}]" not in by_design for i in bad))
    out["model"] = int(np.sum(~np.isfinite(model)))
    for k, v in res.stats.items():
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            out[f"stats.{k}"] = int(not math.isfinite(v))
    return out


def _param_errors(case: Case, res) -> dict[str, float]:
    import ctfit

    truth = _material(case)
    p = res.material.params
    st = res.material.structure
    err = {}
    if "m" in case.compare:
        m_true = np.sort(np.asarray(truth.params.m))
        err["m"] = float(np.max(np.abs(np.sort(np.asarray(p.m)) / m_true - 1)))
    if "F0" in case.compare:
        f0_true = np.asarray(ctfit.normal_reflectance(truth.structure, truth.params), dtype=float)
        f0_fit = np.asarray(ctfit.normal_reflectance(st, p), dtype=float)
        err["F0"] = float(np.max(np.abs(f0_fit - f0_true)))
    if "s" in case.compare:
        err["s"] = float(abs(float(p.s) - float(truth.params.s)))
    return err


def run_case(case: Case, dtype_name: str, data, clean) -> dict:
    import warnings

    import jax.numpy as jnp

    import ctfit

    dtype = getattr(jnp, dtype_name)
    st = ctfit.Structure(**case.structure)
    start = _material(case).params if case.start_at_truth else None
    row = dict(case=case.name, truth=case.truth, dtype=dtype_name, samples=len(data))
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            t0 = time.perf_counter()
            ctfit.fit(data, st, start=start, dtype=dtype)
            first = time.perf_counter() - t0
            res = ctfit.fit(data, st, start=start, dtype=dtype)
            model = np.asarray(ctfit.evaluate(res.material, data, dtype=dtype), dtype=float)
    except ValueError as exc:  # ctfit refuses the input with a message: what the user sees, not a crash
        row.update(converged=False, steps=None, error=None, param_error={}, time_s=None, first_s=None,
                   non_finite={}, reports=[f"refused (ValueError): {exc}"], python_warnings=[])
        return row
    except Exception as exc:  # a crash is a result too: reported as such
        row.update(converged=False, steps=None, error=None, param_error={}, time_s=None, first_s=None,
                   non_finite={"exception": 1}, reports=[f"raised {type(exc).__name__}: {exc}"], python_warnings=[])
        return row
    with np.errstate(all="ignore"):
        rel = float(np.sqrt(np.sum((model - clean) ** 2)) / np.sqrt(np.sum(clean**2)))
    p = res.material.params
    row.update(
        converged=res.converged,
        steps=res.stats["steps"],
        error=rel,
        param_error=_param_errors(case, res),
        time_s=res.stats["time_s"],
        first_s=first,
        non_finite=_non_finite(res, model),
        reports=list(res.warnings),
        python_warnings=sorted({f"{w.category.__name__}: {w.message}" for w in caught}),
        fitted={k: np.asarray(getattr(p, k), dtype=float).tolist() for k in ("s", "m", "w", "f0", "n", "k", "rd") if getattr(p, k) is not None},
        stderr=None if res.stderr is None else {k: np.asarray(v, dtype=float).tolist() for k, v in res.stderr.items()},
        stats={k: v for k, v in res.stats.items() if isinstance(v, (bool, int, float, str))},
    )
    return row


# --------------------------------------------------------------------------- the model at the extremes


def model_extremes(dtype_name: str) -> dict:
    """Values and gradients of the model at the extremes of its domain; counts of non-finite ones."""
    import jax
    import jax.numpy as jnp

    import ctfit

    dtype = getattr(jnp, dtype_name)
    thetas = np.array([0.0, 1e-6, 30.0, 60.0, 85.0, 89.9, 90.0])
    ti, to, dp = (x.ravel() for x in np.meshgrid(thetas, thetas, [180.0, 0.0, 90.0], indexing="ij"))
    geom = ctfit.geometry_from_angles_deg(*(jnp.asarray(a, dtype) for a in (ti, np.zeros_like(ti), to, dp)))
    fresnel = dict(f0=jnp.asarray([0.0, 1e-8, 1e-6, 0.04, 0.5, 0.98, 1 - 1e-6, 1.0], dtype))
    # A conductor's n or k far beyond any material's, up to the dtype's largest value.
    huge = [1e7, 1e9, 1e20, 3.4e38] if dtype_name == "float32" else [1e20, 1e80, 1e155, 1e300]
    conductor = dict(n=jnp.asarray(huge + [1.0] * len(huge), dtype), k=jnp.asarray([0.0] * len(huge) + huge, dtype))
    ms = jnp.asarray([1e-4, 1e-3, 0.00935, 0.1, 1.0, 3.0], dtype)
    counts = dict(values=0, gradients=0, nonfinite_values=0, nonfinite_gradients=0)
    for structure, bands in ((ctfit.Structure(lobes=1, diffuse="spectrum"), fresnel),
                             (ctfit.Structure(lobes=1, geometry="smith", distribution="gaussian", diffuse="spectrum"), fresnel),
                             (ctfit.Structure(lobes=1, geometry="smith", fresnel="conductor", diffuse="spectrum"), conductor)):
        nb = len(next(iter(bands.values())))

        @jax.jit
        def one(m, st=structure, bands=bands, nb=nb):
            p = ctfit.Params(s=jnp.asarray(0.7, dtype), m=m[None], w=jnp.ones(1, dtype), rd=jnp.full(nb, 0.05, dtype), **bands)
            (_, vals), grads = jax.value_and_grad(lambda q: (jnp.sum(ctfit.brdf(st, q, geom)), ctfit.brdf(st, q, geom)), has_aux=True)(p)
            return vals, grads

        vals, grads = jax.vmap(one)(ms)
        leaves = [np.asarray(g) for g in jax.tree.leaves(grads)]
        counts["values"] += int(np.size(vals))
        counts["gradients"] += sum(g.size for g in leaves)
        counts["nonfinite_values"] += int(np.sum(~np.isfinite(np.asarray(vals))))
        counts["nonfinite_gradients"] += sum(int(np.sum(~np.isfinite(g))) for g in leaves)
    return counts


# --------------------------------------------------------------------------- report


def _short(msg: str, n: int = 90) -> str:
    msg = msg.replace("|", "\\|")
    return msg if len(msg) <= n else msg[: n - 1] + "…"


def _fmt_err(row: dict) -> str:
    if row["error"] is None:
        return "—"
    e = row["error"]
    return f"{e:.1e}" if math.isfinite(e) else str(e)


def _fmt_param_err(row: dict) -> str:
    parts = []
    for k, v in row["param_error"].items():
        if not math.isfinite(v):
            parts.append(f"{k}: {v}")
        elif k == "m":
            parts.append(f"m {v:.1e} rel.")
        else:
            parts.append(f"{k} {v:.1e}")
    return ", ".join(parts) or "—"


def _fmt_time(row: dict) -> str:
    if row["time_s"] is None:
        return "—"
    t = f"{row['time_s']:.2f}"
    if row["first_s"] - row["time_s"] > 1.0:
        t += f" ({row['first_s']:.0f})"
    return t


def _why(row: dict) -> str:
    """Why a fit did not converge, from its result: step limit, parameters at a bound, singular JᵀJ."""
    if row["steps"] is None:
        return row["reports"][0]
    out = []
    if row["steps"] >= MAX_STEPS:
        out.append(f"step limit {MAX_STEPS}")
    if not math.isfinite(row["stats"].get("cost", math.nan)):
        out.append("cost not finite")
    p = row["fitted"]
    f0 = np.asarray(p.get("f0", []))
    if np.any(f0 > 1 - 1e-6):
        out.append("F0 → 1")
    if np.any(f0 < 1e-6):
        out.append("F0 → 0")
    if "s" in p and not 1e-4 <= p["s"] <= 1 - 1e-4:
        out.append(f"s → {round(p['s'])}")
    if len(p.get("w", [])) > 1 and min(p["w"]) < 1e-3:
        out.append("a lobe weight → 0")
    m = np.sort(np.asarray(p.get("m", [])))
    if len(m) > 1 and np.any(np.diff(m) <= 0.02 * m[1:]):
        out.append("two lobes merge")
    if np.any(m > 10):
        out.append(f"m → ∞ ({m.max():.3g})")
    if np.any(np.asarray(p.get("k", [])) < 1e-6):
        out.append("k → 0")
    if row["stderr"] is None:
        out.append("JᵀJ singular")
    return ", ".join(out) or "optimistix reported failure"


def _fmt_reports(row: dict) -> str:
    notes = [_short(w) for w in row["reports"]]
    bad = [k for k, v in row["non_finite"].items() if v]
    if bad:
        notes.append("non-finite: " + ", ".join(bad))
    notes += [_short("Python warning " + w) for w in row["python_warnings"]]
    return "; ".join(notes) or "nothing"


def report(rows: list[dict], extremes: dict, *, small: bool, elapsed: float) -> str:
    import jax

    total_nf = sum(sum(r["non_finite"].values()) for r in rows)
    model_nf = sum(e["nonfinite_values"] + e["nonfinite_gradients"] for e in extremes.values())
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = [
        SECTION,
        "",
        f"`scripts/stability.py{' --small' if small else ''}` ({datetime.date.today().isoformat()}; {platform.machine()} CPU, "
        f"{os.cpu_count()} cores shared with other jobs, load average {load:.1f} at the end; Python {platform.python_version()}, "
        f"JAX {jax.__version__}; {elapsed:.0f} s in all). Each case is synthetic data with the stated truth — "
        f"`ctfit.simulate` at 4 wavelengths (400–700 nm), {NOISE:.0%} relative Gaussian noise, the samples carrying their sigma, "
        "unless the case says otherwise — fitted by `ctfit.fit` with its defaults (grid seeding, 3 starts, Levenberg–Marquardt, "
        "sigma-weighted loss) in float64 and in float32. *Error*: ‖R_fit − R_true‖/‖R_true‖ over the data's samples, against "
        "the noise-free truth; *parameters*: |m_fit/m − 1|, |ΔF0| (max over the bands), |Δs|, where the data determines them. "
        "*Time*: the warm `fit` call in seconds (in brackets: the first call, which compiles the fit for that structure, data "
        "shape and dtype). *Non-finite*: NaN/inf anywhere in the result — fitted parameters (including the effective index n), "
        "standard errors, the fitted model at every sample, the fit statistics. *ctfit reports*: the result's warnings, shortened.",
        "",
        "| case | truth | dtype | converged | steps | error | parameters | time (s) | non-finite | what ctfit reports |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        nf = sum(r["non_finite"].values())
        steps = "—" if r["steps"] is None else str(r["steps"])
        lines.append(
            f"| {r['case']} | {r['truth']} | {r['dtype']} | {'yes' if r['converged'] else '**no**'} | {steps} | {_fmt_err(r)} | "
            f"{_fmt_param_err(r)} | {_fmt_time(r)} | {nf if nf == 0 else f'**{nf}**'} | {_fmt_reports(r)} |"
        )
    failing = [f"{r['case']} ({r['dtype']}: {_why(r)})" for r in rows if not r["converged"]]
    wrong = [f"{r['case']} ({r['dtype']}, error {_fmt_err(r)})" for r in rows if r["converged"] and (r["error"] is None or not r["error"] <= WRONG)]
    with_nf = [f"{r['case']} ({r['dtype']}: {', '.join(k for k, v in r['non_finite'].items() if v)})" for r in rows if sum(r["non_finite"].values())]
    if extremes:
        lines += [
            "",
            "The model itself at the extremes (m from 1e-4 to 3, θ_i, θ_o up to 90° in the mirror, retro and 90° planes, "
            "F0 from 0 to 1; Beckmann/V-cavity and Gaussian/Smith with a diffuse spectrum; and a conductor, Beckmann/Smith, "
            "with n or k up to 3.4e38 in float32 and 1e300 in float64), values and gradients with respect "
            "to every parameter: "
            + "; ".join(f"{d}: {e['values']} values, {e['gradients']} gradient entries, {e['nonfinite_values'] + e['nonfinite_gradients']} "
                        "non-finite" for d, e in extremes.items())
            + ".",
        ]
    lines += [
        "",
        f"**Summary**: {len(rows) // len(DTYPES)} cases × {len(DTYPES)} dtypes = {len(rows)} fits. Non-finite values in the results: **{total_nf}**"
        + (" — " + "; ".join(with_nf) if with_nf else "")
        + (f" (in the model at the extremes: {model_nf})" if extremes else "")
        + f". Not converged: {len(failing)}"
        + (" — " + "; ".join(failing) if failing else "")
        + f". Reported as converged but more than {WRONG:.0%} from the truth: {len(wrong)}"
        + (" — " + "; ".join(wrong) if wrong else "")
        + ".",
    ]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--docs", type=pathlib.Path, default=DOCS, help="write DIR/stability.md (default: the repository's docs/)")
    ap.add_argument("--small", action="store_true", help="a subset of the cases (one compiled fit per dtype)")
    ap.add_argument("--json", type=pathlib.Path, default=None, help="also write the raw numbers to this JSON file")
    args = ap.parse_args(argv)

    t0 = time.perf_counter()
    import jax

    jax.config.update("jax_platforms", "cpu")
    jax.config.update("jax_enable_x64", True)

    cases = [c for c in CASES if c.small] if args.small else CASES
    rows = []
    for case in cases:
        data, clean = make_data(case)
        for dt in DTYPES:
            row = run_case(case, dt, data, clean)
            rows.append(row)
            print(f"  {case.name:40s} {dt}: converged {row['converged']}, steps {row['steps']}, "
                  f"non-finite {sum(row['non_finite'].values())}, {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    extremes = {} if args.small else {dt: model_extremes(dt) for dt in DTYPES}
    text = report(rows, extremes, small=args.small, elapsed=time.perf_counter() - t0)
    print(text)
    path = args.docs / "stability.md"
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(TITLE, encoding="utf-8")
    write_section(path, SECTION, text)
    if args.json:
        args.json.write_text(json.dumps({"rows": rows, "model_extremes": extremes}, indent=1, default=str), encoding="utf-8")
    total = sum(sum(r["non_finite"].values()) for r in rows) + sum(e["nonfinite_values"] + e["nonfinite_gradients"] for e in extremes.values())
    return 1 if total else 0


if __name__ == "__main__":
    sys.exit(main())
