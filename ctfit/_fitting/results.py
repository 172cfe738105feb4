"""Fit results to the outside: the fit-result JSON and the readable table.

The JSON is the material document of ``docs/formats.md`` plus a ``fit`` section:
``{"converged", "steps", "cost", "rmse", "rel_rmse", "time_s", "n_samples", "n_params", "bic",
"loss", "solver", "dtype", "starts", "relative_floor", "stderr": {...}, "warnings": [...]}``
where ``stderr`` mirrors the parameters (``s``, ``lobes[j].m``, ``lobes[j].weight``, ``F0``, ``n``,
``k``, ``Rd``) and is null when JᵀJ was too ill-conditioned to invert.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from jaxtyping import ArrayLike

from .._io import material_to_dict
from .._model import Material
from .fit_warnings import FitWarning
from .least_squares import FitResult

__all__ = ["fit_result_to_dict", "format_fit_table", "stderr_block"]


def stderr_block(res: FitResult) -> dict | None:
    """The standard errors of a fit in the JSON's names and layout (``FitResult.parameter_errors``)."""
    se = res.stderr
    if se is None:
        return None
    out: dict[str, object] = {}
    if "s" in se:
        out["s"] = float(np.asarray(se["s"]).reshape(-1)[0])
    if "m" in se:
        w = se.get("weight", np.full(len(se["m"]), np.nan)) if len(se["m"]) > 1 else [0.0]
        out["lobes"] = [{"m": float(m), "weight": float(wj)} for m, wj in zip(se["m"], w)]
    st = res.material.structure
    for name in ("F0", "n", "k", "Rd"):
        if name in se:
            v = np.asarray(se[name], dtype=float).reshape(-1)
            one = (name == "Rd" and st.diffuse == "constant") or (name in ("F0", "n") and st.shared_index)  # one value for every band, as in the JSON
            out[name] = float(v[0]) if one else [float(x) for x in v]
    return out


def fit_result_to_dict(res: FitResult, material_keys: bool = True) -> dict:
    """The fit result as a JSON-ready dict; with ``material_keys=False`` only the ``fit`` section.

    >>> import numpy as np, ctfit
    >>> gold = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None),
    ...                       ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.4, 0.9])),
    ...                       wavelength_nm=np.array([450.0, 650.0]))
    >>> doc = ctfit.fit_result_to_dict(ctfit.fit(ctfit.simulate(gold, n_pairs=300, seed=1), gold.structure))
    >>> round(doc["lobes"][0]["m"], 4), doc["fit"]["converged"]
    (0.2, True)
    """
    block = dict(res.stats)
    block["stderr"] = stderr_block(res)
    block["warnings"] = [str(w) for w in res.warnings]
    block["warning_details"] = [w.as_dict() for w in res.warnings if isinstance(w, FitWarning)]
    block = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in block.items()}
    if not material_keys:
        return {"fit": block}
    return material_to_dict(res.material, extra={"fit": block})


def _pm(value: float, err: float | None) -> str:
    if err is None or not math.isfinite(err):
        return f"{value:.6g}"
    return f"{value:.6g} ± {err:.2g}"


def format_fit_table(res: FitResult, label: str = "") -> str:
    """A plain-text table of the parameters ± standard errors and the fit statistics.

    >>> import numpy as np, ctfit
    >>> gold = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None),
    ...                       ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.4, 0.9])),
    ...                       wavelength_nm=np.array([450.0, 650.0]))
    >>> table = ctfit.format_fit_table(ctfit.fit(ctfit.simulate(gold, n_pairs=300, noise=0.01, seed=1), gold.structure), "gold")
    >>> print(*table.splitlines()[:3], sep=chr(10))
    fit of gold
    ------------------------------------------------------------
      s = 1 (fixed by the structure)
    """
    mat, st, se = res.material, res.material.structure, res.stderr or {}
    p = mat.params
    lines = [f"fit of {label}" if label else "fit", "-" * 60]
    if st.has_s:
        lines.append(f"  s = {_pm(float(p.s), _first(se.get('s')))}   d = {1 - float(p.s):.6g}")
    else:
        lines.append(f"  s = {1.0 if st.has_specular else 0.0:g} (fixed by the structure)")
    if st.has_specular:
        for j, (m, w) in enumerate(zip(np.asarray(p.m), np.asarray(p.w))):
            sm = _at(se.get("m"), j)
            sw = _at(se.get("weight"), j) if st.lobes > 1 else None
            lines.append(f"  lobe {j}: m = {_pm(m, sm)}   weight = {_pm(w, sw)}")
    lines += _band_rows(mat, se)
    s = res.stats
    lines.append("-" * 60)
    lines.append(
        f"  converged: {s['converged']}{'' if s['converged'] or 'fit_status' not in s else ' (' + str(s['fit_status']) + ')'}   "
        f"steps: {s['steps']}   loss: {s['loss']}   solver: {s['solver']} ({s['dtype']})"
    )
    lines.append(
        f"  cost: {s['cost']:.6g}   rmse: {s['rmse']:.4g} sr⁻¹   rel_rmse (rms of (f − y)/max(y, floor)): {s['rel_rmse']:.4g}   "
        f"samples: {s['n_samples']}   params: {s['n_params']}   time: {s['time_s']:.2f} s"
    )
    if s.get("quality"):
        lines.append("  " + quality_line(s["quality"]))
    if s.get("on_bound"):
        lines.append(f"  on a bound (a result, no standard error): {', '.join(s['on_bound'])}")
    for w in res.warnings:
        lines.append(f"  warning: {w}")
    return "\n".join(lines)


def quality_line(quality: dict) -> str:
    """One line of the ``quality`` section: median and 90th-percentile |f − y|/y, per region."""
    def pct(x: float | None) -> str:
        return "–" if x is None else f"{x:.1%}"

    regions = ", ".join(f"{name.replace('_', '-')} {pct(r['median_relative_error'])}" for name, r in quality["regions"].items() if r["samples"])
    below = quality.get("below_sigma")
    what = f"|f − y|/y (leaving out {below:,} values below their σ, met within σ)" if below else "|f − y|/y"
    return (f"relative error {what}: median {pct(quality['median_relative_error'])}, 90th percentile "
            f"{pct(quality['p90_relative_error'])} (medians: {regions})")


def _band_rows(mat: Material, se: dict) -> list[str]:
    """The per-band rows (F0, n, k, R_d); a plastic's one index on a line of its own."""
    st, p, labels = mat.structure, mat.params, mat.band_labels  # (a property: made once here)
    lines, cols, values = [], ["band"], []
    if st.needs_fresnel_params:
        f0 = np.asarray(_f0(mat))
        if st.shared_index:
            lines.append(f"  plastic: n = {_pm(float(np.asarray(p.n)[0]), _at(se.get('n'), 0))} in every band   F0 = {_pm(float(f0[0]), _at(se.get('F0'), 0))}")
        else:
            cols += ["F0", "n"] + (["k"] if st.fresnel == "conductor" else [])
            values += [(f0, "F0"), (np.asarray(p.n), "n")] + ([(np.asarray(p.k), "k")] if st.fresnel == "conductor" else [])
    if st.has_rd:
        cols.append("Rd (sr⁻¹)" + (", transmitted" if st.diffuse == "transmitted" else ""))
        values.append((np.broadcast_to(np.asarray(p.rd, dtype=float), (len(labels),)), "Rd"))
    if len(cols) > 1:
        lines.append("  " + "  ".join(f"{c:>18}" for c in cols))
        columns = [(np.asarray(v, dtype=float).tolist(), _errors(se.get(name), len(labels), name == "Rd" and st.diffuse == "constant")) for v, name in values]
        for i, lab in enumerate(labels):  # Python floats: formatting NumPy's scalars took most of a table's time
            lines.append("  " + "  ".join(f"{c:>18}" for c in [lab] + [_pm(v[i], e[i]) for v, e in columns]))
    return lines


def _errors(a: ArrayLike | None, bands: int, one: bool) -> list:
    """Per band the standard error of a quantity (``one``: its first, for every band; None: none)."""
    if a is None:
        return [None] * bands
    flat = np.asarray(a, dtype=float).reshape(-1).tolist()
    return [flat[0]] * bands if one else flat


def _f0(mat: Material) -> Any:
    from .._model import normal_reflectance

    return normal_reflectance(mat.structure, mat.params)


def _first(a: ArrayLike | None) -> float | None:
    return None if a is None else float(np.asarray(a).reshape(-1)[0])


def _at(a: ArrayLike | None, i: int) -> float | None:
    return None if a is None else float(np.asarray(a).reshape(-1)[i])


