"""The chain in ArviZ: an ``InferenceData`` of the posterior draws, and ArviZ's diagnostics.

Each walker is one chain (as ArviZ's own ``from_emcee`` reads an emcee run). The diagnostics
are ArviZ's: bulk and tail effective sample size and rank-normalised split-R̂ (Vehtari et al.
2021), per reported quantity and entry.

References
----------
- Vehtari, A., Gelman, A., Simpson, D., Carpenter, B., Bürkner, P.-C. (2021). Rank-normalization,
  folding, and localization: an improved R̂ for assessing convergence of MCMC. Bayesian Analysis
  16(2), 667–718. doi:10.1214/20-BA1221
- Kumar, R., Carroll, C., Hartikainen, A., Martin, O. (2019). ArviZ a unified library for
  exploratory analysis of Bayesian models in Python. JOSS 4(33), 1143. doi:10.21105/joss.01143
"""

from __future__ import annotations

import logging
import warnings

import numpy as np

from .._model import PARAMETER_AXES
from .chain_diagnostics import quiet_log

__all__ = ["arviz", "inference_data", "diagnostics"]


def arviz():
    """The ``arviz`` module (its import-time notice of the coming 1.x API silenced; the
    "posterior" extra: one line naming it when missing)."""
    from .._runtime import need

    need("posterior", "the chain's ESS and R̂ (ArviZ)")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        import arviz as az
    return az


def _by_walker(a: np.ndarray, walkers: int) -> np.ndarray:
    """emcee's flat draws (step-major: index = step · walkers + walker) as (walker, step, ...)."""
    a = np.asarray(a)
    return a.reshape(a.shape[0] // walkers, walkers, *a.shape[1:]).swapaxes(0, 1)


def inference_data(chain: dict, log_prob: np.ndarray, walkers: int, bands: list, attrs: dict | None = None):
    """``arviz.InferenceData`` with groups posterior (``chain``'s quantities, dims lobe/band) and
    sample_stats (``lp``: the log-posterior in the sampled coordinates)."""
    az = arviz()
    posterior = {k: _by_walker(v, walkers) for k, v in chain.items()}
    dims = {k: [PARAMETER_AXES[k]] for k, v in posterior.items() if PARAMETER_AXES.get(k) and v.ndim == 3}
    lobes = max((posterior[k].shape[2] for k in ("m", "weight") if k in dims), default=0)
    coords = {"band": list(bands)} if any(d == ["band"] for d in dims.values()) else {}
    if lobes:
        coords["lobe"] = list(range(lobes))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        warnings.filterwarnings("ignore", "More chains", UserWarning)  # a short run: fewer draws than walkers, as laid out here on purpose
        return az.from_dict(posterior=posterior, sample_stats={"lp": _by_walker(log_prob, walkers)}, dims=dims, coords=coords, attrs=attrs or {})


def diagnostics(idata) -> dict:
    """{label: {"ess_bulk", "ess_tail", "r_hat"}} per entry of every posterior quantity that varies."""
    az = arviz()
    post = idata.posterior
    # (ArviZ logs through a ``Logger("arviz")`` of its own, not the one ``logging.getLogger`` names.)
    with warnings.catch_warnings(), np.errstate(invalid="ignore", divide="ignore"), quiet_log(getattr(az, "_log", None) or logging.getLogger("arviz")):
        warnings.simplefilter("ignore", RuntimeWarning)
        bulk, tail, rhat = az.ess(post, method="bulk"), az.ess(post, method="tail"), az.rhat(post)
    out = {}
    for name in post.data_vars:
        values = np.asarray(post[name])
        flat = values.reshape(values.shape[0], values.shape[1], -1)
        b, t, r = (np.atleast_1d(np.asarray(d[name], dtype=float)).reshape(-1) for d in (bulk, tail, rhat))
        for i in range(flat.shape[2]):
            if np.ptp(flat[:, :, i]) == 0:
                continue  # a constant (one lobe's weight): nothing to diagnose
            label = name if values.ndim == 2 else f"{name}[{i}]"
            out[label] = {"ess_bulk": float(b[i]), "ess_tail": float(t[i]), "r_hat": float(r[i])}
    return out
