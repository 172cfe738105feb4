"""How the run went: burn-in, emcee's autocorrelation time, ArviZ's ESS and R̂, and plain notes.

emcee's integrated autocorrelation time τ (Sokal 1997; the "50 τ" rule) sets the default
burn-in and says whether the chain is long enough; ArviZ's bulk/tail ESS and split-R̂
(:mod:`ctfit._sampling.arviz_export`) are reported per quantity beside it.
"""

from __future__ import annotations

import contextlib
import logging
import math
from collections.abc import Iterator

import numpy as np

__all__ = ["ChainTooShortWarning", "default_burn", "quiet_log", "run_notes", "residual_spread", "likelihood_description"]


class ChainTooShortWarning(UserWarning):
    """The chain (after burn-in) is shorter than 50 integrated autocorrelation times."""


@contextlib.contextmanager
def quiet_log(logger: logging.Logger) -> Iterator[None]:
    """``logger`` below errors for the block, its level as it was after: emcee logs its own "chain
    too short" message, where ctfit raises :class:`ChainTooShortWarning`; ArviZ its "Shape
    validation failed" on a chain of fewer than four draws per walker, where its ESS and R̂ are NaN
    (reported as not computed)."""
    old = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(old)


def autocorr_time(chain_u: np.ndarray) -> np.ndarray:
    """emcee's τ per sampled coordinate of a (steps, walkers, ndim) chain (quiet when short)."""
    import emcee

    with quiet_log(logging.getLogger("emcee")), np.errstate(invalid="ignore", divide="ignore"):  # a coordinate no walker moved: τ is NaN
        return np.asarray(emcee.autocorr.integrated_time(chain_u, quiet=True), dtype=float)


def default_burn(chain_u: np.ndarray, thin: int = 1) -> int:
    """max(2 τ_max, steps/10), at most steps/2 and steps − ``thin`` (τ from the second half of the
    chain): every walker keeps a draw. (A ``thin`` above steps − steps/10 was refused once the
    chain had run, and the run was lost.)"""
    n = chain_u.shape[0]
    tau = autocorr_time(chain_u[n // 2 :])
    tau_max = float(np.max(tau)) if np.all(np.isfinite(tau)) else float(n)
    return int(min(n // 2, n - thin, max(math.ceil(2 * tau_max), n // 10)))


def run_notes(kept: int, tau: np.ndarray, labels: list[str], acceptance: np.ndarray) -> list[str]:
    """Plain notes on the run: chain shorter than 50 τ, acceptance outside 0.15–0.7."""
    notes = []
    tau_max = float(np.max(tau))
    if not np.all(np.isfinite(tau)):  # too few steps (or a coordinate no walker moved) for emcee's τ
        notes.append(f"the chain is too short for reliable intervals: {kept} steps after burn-in are too few to estimate the "
                     "autocorrelation time τ (reliable intervals need 50 τ, usually thousands of steps); run more steps")
    elif kept < 50 * tau_max:
        notes.append(
            f"the chain is too short for reliable intervals: {kept} steps after burn-in < 50 τ_max = "
            f"{50 * tau_max:.0f} (τ_max = {tau_max:.1f} steps, for {labels[int(np.argmax(tau))]}); run more steps"
        )
    if not 0.15 <= np.mean(acceptance) <= 0.7:
        notes.append(f"mean acceptance fraction {np.mean(acceptance):.2f} is outside 0.15–0.7: the posterior may be multimodal or badly scaled")
    return notes


def residual_spread(r: np.ndarray, y: np.ndarray) -> float | None:
    """rms residual of the quarter of the samples (sorted by ``y``, the model's values) where it
    is largest, over the quarter where it is smallest: ≈ 1 when one noise scale fits every
    residual (None: < 40 samples). By the model's values, not the data's: the data's quarters
    select on the noise (the lowest values are those with the most negative noise, or clipped
    at 0), and one scale of noise read as ×3–4 from one quarter to another."""
    if r.size < 40:
        return None
    groups = np.array_split(np.argsort(y, kind="stable"), 4)
    rms = np.array([np.sqrt(np.mean(r[g] ** 2)) for g in groups])
    return float(np.max(rms) / np.min(rms)) if np.min(rms) > 0 else float("inf")


_RESIDUAL = {
    "sigma": "r_i = (R_i − y_i)/sigma_i",
    "absolute": "r_i = R_i − y_i",
    "relative": "r_i = (R_i − y_i)/R_i, R_i the model at θ (max(R_i, tiny))",
    "cosine": "r_i = (R_i − y_i) cos θ_i",
    "log": "r_i = log(1 + R_i cos θ_i) − log(1 + y_i cos θ_i)",
    "log-ratio": "r_i = log(max(R_i, 0) + ε) − log(max(y_i, 0) + ε), ε the loss's floor",
}


def likelihood_description(loss: str, n_obs: int, floor: float) -> dict:
    """The ``likelihood`` section of the JSON."""
    out = {"model": "gaussian", "loss": loss, "residual": _RESIDUAL[loss], "n_samples": n_obs}
    if loss == "sigma":
        return {**out, "log_likelihood": "−½ Σ r_i² + const", "noise": "the data's sigma column"}
    out.update(log_likelihood="−N log σ_noise − ½ Σ r_i²/σ_noise² + const",
               noise="σ_noise sampled (parameter sigma_noise); prior as in priors.parameters.sigma_noise")
    if loss == "relative":
        out.update(
            log_likelihood="−Σ log R_i − N log σ_noise − ½ Σ r_i²/σ_noise² + const",
            noise=("proportional to the model: y_i ~ N(R_i, (σ_noise R_i)²), σ_noise (a relative noise) sampled "
                   "(parameter sigma_noise); prior as in priors.parameters.sigma_noise"),
            note=(f"the fit's relative loss divides by max(y_i, floor) (floor = {floor:.6g}); the likelihood divides by the "
                  "model, without a floor, so its mode is near, not at, the fit's optimum, and samples far below the peak "
                  "count with their relative noise"),
        )
    return out
