"""How close a fit is to the data, in terms a user can judge: the relative error of the typical
sample, overall and per region (near the specular peak, off the peak, grazing).

The figure is |f − y| / y over the samples with y > 0 — the error of one sample as a fraction of
its own value, whatever the loss the fit minimised. Where the data gives a sample's uncertainty σ
and its value is below it (known only as 0 ± σ), the sample is left out if the model is within σ
of it, and counts as |f − y|/σ if not (:func:`errors_below_uncertainty`). Its median says how far off the typical sample
is; the 90th percentile, how far off the worst tenth is. A norm ratio ‖f − y‖/‖y‖ would be set by
the few samples of the peak (a fit that misses the diffuse part by 45 % can read 3 %).

Regions, from each sample's half-vector angle α (N·H) and its larger polar angle:

- ``grazing``: max(θ_i, θ_o) ≥ 75°;
- ``peak``: not grazing, α ≤ the fitted peak's width, max(5°, atan(2 m̄)) with m̄ the lobes'
  weighted rms slope (no peak region for a material without a specular part);
- ``off_peak``: the rest.

When even the fitted model is far from the data (median above :data:`MODEL_LIMIT`, or a tenth of
the samples off by more than :data:`TAIL_LIMIT`), one plain warning says that the Cook–Torrance
model does not represent the material, and where it fails worst.
"""

from __future__ import annotations

import math

import jax
import numpy as np
from jaxtyping import ArrayLike, Float

from .._model import Material, Measurement, Params, Structure
from .diagnostics import ZEROS_HINT, pair_half_angle_deg
from .fit_warnings import FitWarning

__all__ = ["errors_below_uncertainty", "MODEL_LIMIT", "TAIL_LIMIT", "ZEROS_HINT", "zeros_hint", "GRAZING_DEG", "fit_quality", "quality_from_residuals",
           "quality_in_regions",
           "quality_warning", "sample_regions"]

MODEL_LIMIT = 0.3
"""A median relative error above this: the model does not represent the material (iridescent
paints, retro-reflectors, strongly anisotropic or layered materials)."""
TAIL_LIMIT = 0.9
"""A 90th-percentile relative error above this — a tenth of the samples off by 90 % or more —
says the same of a material that the model misses in one region only (a retro-reflection lobe)."""
GRAZING_DEG = 75.0
"""Samples with max(θ_i, θ_o) at or above this are the ``grazing`` region."""
_PEAK_MIN_DEG = 5.0


def peak_width_deg(st: Structure, p: Params) -> float | None:
    """The half-vector angle within which a sample counts as near the peak (None: no specular part)."""
    if not st.has_specular:
        return None
    m = float(np.sum(np.asarray(p.w, dtype=float) * np.asarray(p.m, dtype=float)))
    return max(_PEAK_MIN_DEG, math.degrees(math.atan(2 * m)))


def _summary(err: np.ndarray) -> dict:
    """Median and 90th percentile of ``err`` (finite), a copy of the caller's that is reordered in
    place (no further copies: a MERL table has 3.3 million samples).

    One partition finds the order statistics both need; they are combined as ``np.median`` and
    ``np.quantile(err, 0.9)`` (linear) combine them, to the last bit. The two NumPy calls took
    0.1 ms for any size, most of a database file's quality section (a file of 2,000 samples: 0.02 ms)."""
    n = err.size
    if not n:
        return {"samples": 0, "median_relative_error": None, "p90_relative_error": None}
    half = n // 2
    virtual = (n - 1) * 0.9  # np.quantile's linear method: (n − 1)·q, its floor and the next index
    below = min(math.floor(virtual), n - 1)
    above = min(below + 1, n - 1)
    err.partition(sorted({half - 1 if n % 2 == 0 else half, half, below, above}))
    median = (err[half - 1] + err[half]) / 2 if n % 2 == 0 else err[half]  # np.median: the mean of the middle two
    a, b = err[below], err[above]
    t = virtual - below
    p90 = b - (b - a) * (1 - t) if t >= 0.5 else a + (b - a) * t  # NumPy's _lerp
    return {"samples": int(n), "median_relative_error": float(median), "p90_relative_error": float(p90)}


def sample_regions(data: Measurement, peak_deg: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Which samples are ``grazing`` and which near the ``peak`` (boolean, one per sample), from
    their direction pairs (``data.directions()``): computed per pair, then spread to the samples,
    so that no per-sample angle is held (a MERL table has 3.3 million samples)."""
    pairs, index = data.directions()
    grazing = np.maximum(pairs[:, 0], pairs[:, 2]) >= GRAZING_DEG
    peak = ~grazing & (pair_half_angle_deg(pairs) <= peak_deg) if peak_deg is not None else np.zeros_like(grazing)
    return grazing[index], peak[index]


def quality_in_regions(err: np.ndarray, grazing: np.ndarray, peak: np.ndarray, peak_deg: float | None) -> dict:
    """The ``quality`` section from per-sample relative errors |f − y|/y (NaN where y ≤ 0: left
    out) and the samples' regions (:func:`sample_regions`)."""
    err = np.asarray(err, dtype=float).reshape(-1)
    ok = np.isfinite(err)
    out = _summary(err[ok])
    out["regions"] = {
        "peak": _summary(err[ok & peak]),
        "off_peak": _summary(err[ok & ~peak & ~grazing]),
        "grazing": _summary(err[ok & grazing]),
    }
    out["peak_width_deg"] = peak_deg
    return out


def errors_below_uncertainty(err: np.ndarray, y: np.ndarray, sigma: ArrayLike | None) -> int:
    """``err`` (|f − y|/y per sample, changed in place) where the sample's value ``y`` is below its
    uncertainty ``sigma`` (None: no change): such a value is known only as 0 ± σ, and says nothing
    of a relative error. It is left out (NaN) where the model is within σ of it, and counts as
    |f − y|/σ (a miss, above 1) where not. Returns how many were left out.

    A simulated copper's Beckmann tail (y = 10⁻¹³⁷ sr⁻¹, σ = 1.5·10⁻⁶) under a model of 10⁻¹³⁰ read
    "a tenth of the samples are off by 98,803,562 %" and "the model does not represent this
    material", for data the model itself made. (Taken as |f − y|/σ ≈ 0 instead, those samples
    would read as exact: a third of a 5 %-noise gold's, and its median 1.6 %.)

    >>> err = np.array([0.02, 1e6, 5e9])
    >>> errors_below_uncertainty(err, np.array([1.0, 1e-12, 1e-12]), np.array([0.02, 1e-3, 1e-3])), err
    (1, array([0.02, nan, 5.  ]))
    """
    if sigma is None:
        return 0
    sigma = np.asarray(sigma, dtype=float)
    below = np.flatnonzero((sigma > y) & (y > 0))
    miss = err[below] * (y[below] / sigma[below])  # |f − y|/σ
    err[below] = np.where(miss > 1, miss, np.nan)
    return int(np.sum(miss <= 1))


def quality_from_residuals(data: Measurement, rel: np.ndarray, floor: float, structure: Structure, params: Params) -> dict:
    """The ``quality`` section of a fit from its relative residuals (f − y)/max(|y|, floor) per
    sample (float32, as the fit's report keeps them): |f − y|/y computed in place, with one
    temporary (a MERL table has 3.3 million samples); inf where it lies beyond float64's range (a
    value of 1e-310 where the model is bright). A sample far below the floor whose residual is 0
    in float32 (|f − y| under 10⁻³⁸ of the floor: a model value of 10⁻¹⁰³ against 1.3·10⁻¹⁰³)
    has its error from the model itself (:func:`_lost_errors`): read as 0, such samples made the
    median of a fit of copper 4.5 % where it is 4.8 %."""
    y = np.asarray(data.brdf, dtype=float)
    positive = y > 0
    err = np.abs(rel, dtype=float)
    lost = np.flatnonzero(positive & (err == 0) & (y < floor))
    scale = np.abs(y)
    err *= np.maximum(scale, floor, out=scale)
    del scale
    with np.errstate(over="ignore"):  # a subnormal y (1e-310) under a bright model: an error past float's range, inf
        np.divide(err, y, out=err, where=positive)
    err[~positive] = np.nan
    if lost.size:
        err[lost] = _lost_errors(data, lost, structure, params)
    below = errors_below_uncertainty(err, y, data.sigma)
    peak_deg = peak_width_deg(structure, params)
    return _with_below(quality_in_regions(err, *sample_regions(data, peak_deg), peak_deg), below)


def _with_below(quality: dict, below: int) -> dict:
    """``quality`` with ``below_sigma``: the samples left out, a value below its σ that the model
    meets within σ (:func:`errors_below_uncertainty`), where some are."""
    if below:
        quality["below_sigma"] = below
    return quality


def _lost_errors(data: Measurement, samples: np.ndarray, structure: Structure, params: Params) -> np.ndarray:
    """|f − y|/y at the ``samples`` (indices) of ``data``, f the model evaluated on the host in
    float64 (``brdf(..., xp=numpy)``: no program) at their direction pairs only."""
    from .._model import brdf
    from .problem import geometry_deg

    pairs, index = data.directions()
    used, which = np.unique(index[samples], return_inverse=True)
    host = jax.tree.map(lambda a: np.asarray(a, dtype=np.float64), params)
    with np.errstate(all="ignore"):  # the guards' unselected branches (double-where), as in JAX
        values = brdf(structure, host, geometry_deg(np.asarray(pairs[used], dtype=np.float64), on_host=True), xp=np)
    f = np.asarray(values)[which.reshape(-1), np.asarray(data.band)[samples]]
    y = np.asarray(data.brdf, dtype=float)[samples]
    with np.errstate(over="ignore"):
        return np.abs(f - y) / y


def fit_quality(material: Material, data: Measurement, model: Float[ArrayLike, " samples"] | None = None) -> dict:
    """The ``quality`` section of a fit of ``material`` to ``data`` (``model``: the material's
    values at the samples, computed when not given).

    >>> import numpy as np, ctfit
    >>> gold = ctfit.Material(ctfit.Structure(), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.9])),
    ...                       wavelength_nm=np.array([550.0]))
    >>> data = ctfit.simulate(gold, n_pairs=400, noise=0.05, seed=1)
    >>> q = ctfit.fit_quality(gold, data)
    >>> 0.02 < q["median_relative_error"] < 0.05, sorted(q["regions"])  # 5 % noise: about 3.4 % typical
    (True, ['grazing', 'off_peak', 'peak'])
    """
    from .._model import evaluate

    y = np.asarray(data.brdf, dtype=float)
    f = np.asarray(evaluate(material, data) if model is None else model, dtype=float)
    err = np.where(y > 0, np.abs(f - y) / np.where(y > 0, y, 1.0), np.nan)
    below = errors_below_uncertainty(err, y, data.sigma)
    peak_deg = peak_width_deg(material.structure, material.params)
    return _with_below(quality_in_regions(err, *sample_regions(data, peak_deg), peak_deg), below)


def zeros_hint(brdf: ArrayLike) -> str:
    """"; k % of the samples are exactly 0: …" where at least :data:`ZEROS_HINT` of ``brdf`` is 0,
    else "": values not measured, written as 0, each count as a miss under a bright model, and
    from about one sample in five a model that is 0 everywhere is the cheaper fit (docs/fitting.md).

    >>> zeros_hint([0.0, 0.0, 1.0, 2.0])[:44]
    '; 50% of the samples are exactly 0: if those'
    """
    zeros = float(np.mean(np.asarray(brdf) == 0)) if np.size(brdf) else 0.0
    if zeros < ZEROS_HINT:
        return ""
    return f"; {zeros:.0%} of the samples are exactly 0: if those are values that were not measured, leave them out of the file (each counts as a miss)"


def quality_warning(quality: dict, brdf: ArrayLike | None = None) -> FitWarning | None:
    """One line when the median relative error is above :data:`MODEL_LIMIT` or its 90th percentile
    above :data:`TAIL_LIMIT`, naming the worst region (and, given the data's ``brdf``,
    :func:`zeros_hint`'s share of zeros)."""
    median, tail = quality.get("median_relative_error"), quality.get("p90_relative_error")
    if median is None or tail is None or (median <= MODEL_LIMIT and tail <= TAIL_LIMIT):
        return None
    hint = "" if brdf is None else zeros_hint(brdf)
    names = {"peak": "near the specular peak", "off_peak": "off the peak", "grazing": "at grazing angles"}
    regions = [(r["median_relative_error"], k) for k, r in quality["regions"].items() if r["median_relative_error"] is not None]
    worst = max(regions)[1] if regions else None
    where = f"; it fails most {names[worst]} (median {max(regions)[0]:.0%})" if worst else ""
    region = names[worst] if worst else None
    if median > MODEL_LIMIT:
        return FitWarning(f"the Cook–Torrance model does not represent this material: the typical sample is off by {median:.0%} "
                          f"at the best fit its seeds found{where}{hint}", "not_represented", region=region)
    return FitWarning(f"the Cook–Torrance model does not represent this material: a tenth of the samples are off by {tail:.0%} or more "
                      f"at the best fit its seeds found (the typical one by {median:.0%}){where}{hint}", "not_represented", region=region)
