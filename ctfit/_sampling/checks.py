"""Is the posterior usable? Three checks, each one plain line when it fails.

- **left the fit**: the fit's optimum lies outside the posterior's 99 % highest-density region
  (more than 99 % of the draws have a higher posterior density in θ than the optimum), *and*
  further from the posterior than the fit's own uncertainty explains: D² = dᵀ (Σ_post +
  Σ_fit)⁻¹ d above the χ² 99 % point, with d the fit's optimum less the posterior median in the
  sampled coordinates, Σ_post the draws' covariance (winsorised at 0.5/99.5 %) and Σ_fit the
  fit's Laplace covariance. (Where the fit's loss is not the likelihood — the relative loss —
  the two optima differ by the fit's noise even for data the model describes; only a larger
  gap counts.) The least-squares fit and the likelihood then disagree: the noise model, or the
  Cook–Torrance model itself, does not describe the data.
- **at a prior bound**: a parameter's 95 % range reaches a bound of its prior (the distance from
  the 2.5 % or 97.5 % quantile to the bound is under a quarter of the 16–84 % width, read in
  log θ for m and σ_noise): the interval is the prior's cut, not the data's.
- **not constrained**: a parameter's 95 % range covers more than half of its prior's range, or
  JᵀJ at the optimum has no curvature along it (:func:`ctfit._fitting.fit_report.undetermined`).

A run with any of them is not a usable posterior (``SampleResult.usable`` False; the ``ctfit
sample`` exit status 1).
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2

from .._model import PARAMETERS
from .priors import prior_bounds, public_name

__all__ = ["HPD_LEVEL", "check_posterior", "fit_distance"]

HPD_LEVEL = 0.99
BOUND_FRACTION = 0.25
UNCONSTRAINED_FRACTION = 0.5


def _log_scale(name: str) -> bool:
    return name == "sigma_noise" or PARAMETERS[name].log_scale


def _columns(chain: dict, name: str) -> tuple[list[str], np.ndarray]:
    """Labels and draws (n, entries) of one sampled parameter's values."""
    pub = public_name(name)
    a = np.asarray(chain[pub], dtype=float)
    if a.ndim == 1:
        return [pub], a[:, None]
    return [f"{pub}[{i}]" for i in range(a.shape[1])], a


def _bound_and_spread(name: str, kind: str, args: tuple, fresnel: str, draws: np.ndarray):
    """Per entry: runs to the lower bound, to the upper bound, and the fraction of the prior's
    range that the 95 % interval covers (in the scale the prior is read in)."""
    lo, hi = prior_bounds(name, kind, args, fresnel)
    lo, hi = np.broadcast_to(lo, draws.shape[1:]), np.broadcast_to(hi, draws.shape[1:])
    g = np.log if _log_scale(name) else (lambda v: v)
    with np.errstate(divide="ignore", invalid="ignore"):
        q = g(np.percentile(draws, [2.5, 16, 84, 97.5], axis=0))
        glo, ghi = g(lo), g(hi)
    width = q[2] - q[1]
    varies = width > 0
    low = varies & (q[0] - glo < BOUND_FRACTION * width)
    high = varies & (ghi - q[3] < BOUND_FRACTION * width)
    with np.errstate(divide="ignore", invalid="ignore"):
        cover = np.where(np.isfinite(ghi - glo), (q[3] - q[0]) / (ghi - glo), 0.0)
    return low, high, cover, lo, hi


def _fmt(v) -> str:
    return f"{float(v):.3g}"


def fit_distance(u_draws: np.ndarray, x_fit: np.ndarray, fit_cov: np.ndarray) -> tuple[float, float]:
    """D² of the fit's optimum ``x_fit`` from the posterior median of ``u_draws`` (n, P) against
    Σ_post + ``fit_cov``, and the χ²_P 99 % point it is compared with."""
    lo, hi = np.percentile(u_draws, [0.5, 99.5], axis=0)
    cov = np.atleast_2d(np.cov(np.clip(u_draws, lo, hi), rowvar=False)) + fit_cov
    d = np.asarray(x_fit, dtype=float) - np.median(u_draws, axis=0)
    return float(d @ np.linalg.pinv(cov, hermitian=True) @ d), float(chi2.ppf(HPD_LEVEL, d.size))


def _left_fit_line(frac: float, d2: float, limit: float, chain: dict, optimum: dict) -> str:
    keys = [k for k in ("s", "m", "F0", "Rd") if k in chain and k in optimum][:3]
    post = ", ".join(f"{k} {_fmt(np.median(np.asarray(chain[k]).reshape(len(chain[k]), -1)[:, 0]))}" for k in keys)
    fit = ", ".join(f"{k} {_fmt(np.ravel(optimum[k])[0])}" for k in keys)
    return (
        f"left the fit: the fit's optimum lies outside the posterior's {HPD_LEVEL:.0%} region ({frac:.1%} of the draws have a "
        f"higher posterior density), further than the fit's own uncertainty explains (D² = {d2:.3g} > {limit:.3g}); the posterior "
        f"(median {post}) is not the fit ({fit}): the model or the noise model does not describe these data "
        "(try another --loss, or read the fit's residual warnings)"
    )


def check_posterior(chain: dict, prior: tuple, fresnel: str, lp_draws, lp_optimum: float, optimum: dict, distance=(np.inf, 0.0),
                    undetermined_labels=()) -> dict:
    """The three checks (module docstring) on the constrained draws ``chain``; ``lp_draws`` and
    ``lp_optimum``: the posterior log-density in θ of the draws and of the fit's optimum;
    ``distance``: (D², its limit) from :func:`fit_distance`.
    Returns {"usable", "problems" (one line per failed check), "left_fit", "at_bound", "not_constrained"}."""
    higher = float(np.mean(np.asarray(lp_draws) > lp_optimum)) if np.isfinite(lp_optimum) else 1.0
    d2, limit = distance
    left = higher > HPD_LEVEL and d2 > limit
    at_bound, loose = [], list(undetermined_labels)
    for name, kind, args in prior:
        labels, draws = _columns(chain, name)
        low, high, cover, lo, hi = _bound_and_spread(name, kind, args, fresnel, draws)
        for i, lab in enumerate(labels):
            if low[i]:
                at_bound.append(f"{lab} runs to {_fmt(lo[i])}")
            if high[i]:
                at_bound.append(f"{lab} runs to {_fmt(hi[i])}")
            if cover[i] > UNCONSTRAINED_FRACTION and lab not in loose:
                loose.append(lab)
    problems = []
    if left:
        problems.append(_left_fit_line(higher, d2, limit, chain, optimum))
    if at_bound:
        problems.append(f"at a prior bound: {', '.join(at_bound)} (the 95 % range reaches the prior's limit): these intervals are the prior's cut, not the data's")
    if loose:
        problems.append(f"not constrained: the data cannot pin down {', '.join(loose)} (95 % range over half the prior's, or no curvature of the fit there)")
    return {
        "usable": not problems,
        "problems": problems,
        "left_fit": {"flag": bool(left), "draws_denser_than_optimum": higher, "level": HPD_LEVEL, "distance2": d2, "distance2_limit": limit},
        "at_bound": at_bound,
        "not_constrained": loose,
    }
