"""Is the posterior usable? Six checks, each one plain line when it fails.

- **not mixed**: the walkers have not run long enough for their draws to stand for the
  posterior. Any of: ArviZ's rank-normalised split-R̂ above :data:`R_HAT_LIMIT` (1.05), its
  bulk or tail effective sample size below :data:`ESS_LIMIT` (400) for some reported quantity
  (each walker a chain), or fewer steps after burn-in than :data:`TAU_RUNS` (50) of emcee's
  autocorrelation times τ_max (its "50 τ" rule). The line says how many steps in all would do
  (:func:`steps_needed`). The ESS limit is Vehtari et al. (2021)'s; their R̂ limit, 1.01, is
  for a few long independent chains. An ensemble's 32 or more walkers are many short chains
  (draws per walker: steps kept / τ), and split-R̂ scatters above 1 by about 1/(steps kept / τ)
  even when they have mixed: 1.02–1.04 at 40–65 τ on synthetic data of the model.

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
- **sigma misfit** (the data's sigma column as the noise): χ²/dof at the fit above
  :data:`CHI2_LIMIT` and noise (:func:`sigma_misfit`): the column does not explain the
  residuals, and the intervals, which assume it does, are too narrow.
- **noise scale** (σ_noise sampled: no sigma column): the likelihood's residuals at its best
  draw have an rms that varies more than :data:`SPREAD_LIMIT` times between the lowest and
  highest quarter of the data by value (:func:`noise_scale_misfit`): one σ_noise does not
  describe them, and the intervals are too narrow where they are larger.

A run with any of them is not a usable posterior (``SampleResult.usable`` False; the ``ctfit
sample`` exit status 1).

References: Vehtari, A., Gelman, A., Simpson, D., Carpenter, B., Bürkner, P.-C. (2021).
Rank-normalization, folding, and localization: an improved R̂ for assessing convergence of
MCMC. Bayesian Analysis 16(2), 667–718. doi:10.1214/20-BA1221
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2, f as f_dist

from .._model import PARAMETERS
from .priors import prior_bounds, public_name
from .table import number_text

__all__ = ["CHI2_LIMIT", "ESS_LIMIT", "HPD_LEVEL", "R_HAT_LIMIT", "SPREAD_LIMIT", "TAU_RUNS", "check_mixing", "check_posterior", "fit_distance",
           "noise_scale_misfit", "sigma_misfit", "steps_needed"]

HPD_LEVEL = 0.99
R_HAT_LIMIT = 1.05
"""The largest split-R̂ of a mixed ensemble (module docstring: why not Vehtari et al.'s 1.01)."""
ESS_LIMIT = 400
"""The smallest bulk and tail effective sample size of a mixed chain, in draws (Vehtari et al. 2021)."""
TAU_RUNS = 50
"""Steps after burn-in per autocorrelation time τ_max that a mixed chain has (emcee's rule)."""
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
        "(try another loss=, or read the fit's residual warnings)"
    )


CHI2_LIMIT = 1.5
"""With the data's sigma column as the noise (loss "sigma"), a χ²/dof at the fit above this (and
five of its standard deviations, √(2/dof), above 1) fails the posterior (:func:`sigma_misfit`)."""


def sigma_misfit(chi_square: float, dof: int) -> str | None:
    """The problem line when a sigma column does not explain the fit's residuals (χ² = Σ r², r the
    residuals over sigma, ``dof`` = N − P): the intervals assume it does, so they are too narrow by
    about √(χ²/dof) (a column three times too small: 4 of 8 intervals missed the truth, "usable").
    None where χ²/dof is within :data:`CHI2_LIMIT` and noise.

    >>> sigma_misfit(7880.5, 1993)[:69]
    'the sigma column does not explain the residuals: χ²/dof = 3.95 at the'
    >>> sigma_misfit(2050.0, 1993) is None
    True
    """
    if dof <= 0 or not np.isfinite(chi_square):
        return None
    ratio = chi_square / dof
    if ratio <= max(CHI2_LIMIT, 1 + 5 * np.sqrt(2 / dof)):
        return None
    return (f"the sigma column does not explain the residuals: χ²/dof = {ratio:.3g} at the fit ({dof} degrees of freedom, 1 expected): the sigma are "
            f"too small, or the model misses the data, and the intervals are about {np.sqrt(ratio):.2g}× too narrow")


SPREAD_LIMIT = 2.0
"""Where the noise scale is sampled (one σ_noise for every residual), a ratio above this of the
residuals' rms between the quarters of the data (by value) where it is largest and smallest
fails the posterior (:func:`noise_scale_misfit`), where one scale would give it by chance with
probability below 10⁻⁴ (few samples: a higher limit)."""

_OTHER_LOSS = {"relative": "'absolute' (noise of one size)"}


def noise_scale_misfit(spread: float | None, loss: str, samples: int) -> str | None:
    """The problem line when one noise scale does not fit the likelihood's residuals: their rms
    varies by ``spread`` (:func:`~ctfit._sampling.chain_diagnostics.residual_spread`) between the
    quarters of the ``samples`` by value, more than :data:`SPREAD_LIMIT` and more than one scale
    gives by chance (the F distribution's 1 − 10⁻⁴ point for two quarters, as an rms ratio:
    3.9 for 40 samples, 1.2 for 2,000). The intervals assume one σ_noise: too narrow where the
    residuals are larger (an 'absolute' likelihood on noise that grows with the value read
    usable, with a note). None where it fits, or no scale is sampled.

    >>> print(noise_scale_misfit(7.4, "absolute", 2000)[:60])
    one noise scale does not fit: the residuals' rms varies ×7.4
    >>> noise_scale_misfit(2.5, "absolute", 40) is None  # 10 samples a quarter: no evidence
    True
    """
    quarter = max(samples // 4, 1)
    if spread is None or not spread > max(SPREAD_LIMIT, float(np.sqrt(f_dist.ppf(1 - 1e-4, quarter, quarter)))):
        return None
    other = _OTHER_LOSS.get(loss, "'relative' (noise proportional to the value)")
    return (f"one noise scale does not fit: the residuals' rms varies ×{spread:.3g} between the lowest and highest quarter of the data (by value), "
            f"where loss {loss!r} assumes one σ_noise for all; the intervals are too narrow where the residuals are larger: give the data a sigma "
            f"column (loss 'sigma'), or sample with a loss whose residuals have one scale, e.g. {other}")


def check_posterior(chain: dict, prior: tuple, fresnel: str, lp_draws, lp_optimum: float, optimum: dict, distance=(np.inf, 0.0),
                    undetermined_labels=(), misfit: str | None = None) -> dict:
    """The checks but mixing (module docstring) on the constrained draws ``chain``; ``lp_draws`` and
    ``lp_optimum``: the posterior log-density in θ of the draws and of the fit's optimum;
    ``distance``: (D², its limit) from :func:`fit_distance`; ``misfit``: :func:`sigma_misfit`'s or :func:`noise_scale_misfit`'s line, a failed check too.
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
        problems.append(f"at a prior bound: {', '.join(at_bound)} (the 95 % range reaches the prior's limit): these intervals are the prior's cut, not the "
                        "data's")
    if loose:
        problems.append(f"not constrained: the data cannot pin down {', '.join(loose)} (95 % range over half the prior's, or no curvature of the fit there)")
    if misfit:
        problems.append(misfit)
    return {
        "usable": not problems,
        "problems": problems,
        "left_fit": {"flag": bool(left), "draws_denser_than_optimum": higher, "level": HPD_LEVEL, "distance2": d2, "distance2_limit": limit},
        "at_bound": at_bound,
        "not_constrained": loose,
    }


def steps_needed(steps: int, burn: int, tau_max: float, ess_min: float) -> int:
    """Steps in all (burn-in included) after which the chain would pass the mixing check, as far
    as this chain tells (τ read on a short chain tends to grow with it: a lower bound): the
    steps kept after burn-in grow to :data:`TAU_RUNS` τ_max and to what brings the smallest ESS
    to :data:`ESS_LIMIT` (ESS grows in proportion to them), twice the steps kept where neither
    falls short (only R̂ does); the default burn-in, max(2 τ_max, steps/10), or this run's
    ``burn`` where it is longer (a ``--burn`` given), on top. Rounded up to two significant digits. τ is at least 1 (a draw is worth one step at most): where it
    cannot be read (a chain of a few steps), or reads below 1, the steps kept grow to
    :data:`TAU_RUNS` at least.

    >>> steps_needed(2000, 200, 60.0, 100.0)  # ESS 100 of 400: four times the 1800 steps kept, and a tenth to burn
    8000
    >>> steps_needed(5, 1, float("nan"), float("nan"))  # no τ read: 50 steps kept at least, not twice the 4 kept
    56
    >>> steps_needed(400, 399, float("nan"), float("nan"))  # a burn-in of 399 asked for: 50 steps kept after it
    450
    """
    kept = max(steps - burn, 1)
    tau_max = max(tau_max, 1.0) if np.isfinite(tau_max) else 1.0
    wants = [TAU_RUNS * tau_max]
    if np.isfinite(ess_min) and ess_min > 0:
        wants.append(kept * ESS_LIMIT / ess_min)
    need = max(wants)
    if need <= kept:
        need = 2 * kept
    total = max(need + 2 * tau_max, need / 0.9, need + burn, steps + 1)
    digits = 10 ** max(int(np.floor(np.log10(total))) - 1, 0)
    return int(np.ceil(total / digits) * digits)


def check_mixing(diagnostics: dict) -> dict:
    """The mixing check (module docstring) on a run's ``diagnostics`` (``SampleResult.diagnostics``:
    ``r_hat_max``, ``ess_min``, ``ess_tail_min``, ``autocorr_time_max``, ``steps``, ``burn``).
    Returns {"flag", "line" (None when mixed), "r_hat_max", "ess_bulk_min", "ess_tail_min",
    "steps_after_burn", "tau_runs", "steps_needed" (None when mixed), and the limits}."""
    d = diagnostics
    r_hat, bulk, tail, tau = (float(d.get(k, np.nan)) for k in ("r_hat_max", "ess_min", "ess_tail_min", "autocorr_time_max"))
    steps, burn = int(d["steps"]), int(d["burn"])
    kept = steps - burn
    runs = kept / tau if np.isfinite(tau) and tau > 0 else np.nan
    failed = []
    if not (r_hat <= R_HAT_LIMIT):
        failed.append(f"R̂_max {number_text(r_hat, '.3f')} (a mixed chain has ≤ {R_HAT_LIMIT})")
    if not (min(bulk, tail) >= ESS_LIMIT):
        failed.append(f"ESS_min {number_text(bulk, '.0f')} bulk, {number_text(tail, '.0f')} tail (a mixed chain has ≥ {ESS_LIMIT} each)")
    if not (runs >= TAU_RUNS):
        failed.append(f"{kept} steps after burn-in = {number_text(runs, '.1f')} τ_max (≥ {TAU_RUNS} τ needed)")
    need = steps_needed(steps, burn, tau, min(bulk, tail)) if failed else None
    line = None
    if failed:
        line = f"not mixed: {'; '.join(failed)}; run at least {need:,} steps in all (τ read on a short chain is often too small)"
    return {
        "flag": bool(failed), "line": line, "r_hat_max": r_hat, "ess_bulk_min": bulk, "ess_tail_min": tail,
        "steps_after_burn": kept, "tau_runs": runs, "steps_needed": need,
        "r_hat_limit": R_HAT_LIMIT, "ess_limit": ESS_LIMIT, "tau_runs_limit": TAU_RUNS,
    }

