"""The losses: each sample's residual from the model's value and the measurement, and the floors
of the relative ones (docs/fitting.md, "The loss").

:data:`LOSSES` names them; :data:`RESIDUALS` is the table that computes each (one function per
name, called as ``RESIDUALS[loss](problem, values, y)``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax.numpy as jnp
import numpy as np

if TYPE_CHECKING:
    from .problem import Problem

__all__ = ["LOSSES", "RESIDUALS", "LOG_RATIO_FLOOR", "RELATIVE_FLOOR", "FLOOR_OF_PEAK", "SEED_FLOOR", "ROBUST_CAP", "ROBUST_SCALE", "loss_floor",
           "default_loss", "row_floors", "loss_residuals", "zero_model_cost"]

LOSSES = ("absolute", "relative", "robust-relative", "sigma", "cosine", "log", "log-ratio")
RELATIVE_FLOOR = 0.1
"""The relative loss's floor, a fraction of the median positive sample (:func:`loss_floor`;
chosen by measurement, docs/fitting.md)."""
ROBUST_SCALE = 0.05
"""The "robust-relative" loss's scale c: relative residuals well below it count as in "relative",
larger ones grow as √(2|r|c) (SciPy's ``soft_l1``), so a region the model cannot follow (a
retro-reflection, the grazing fringe) does not pull the rest of the fit (docs/fitting.md)."""
ROBUST_CAP = 2.0
"""The "robust-relative" loss counts a model value more than this many times a *dark* sample (one
below the floor, a tenth of the typical sample) as about this many times off: there its relative
residual is (f − y)/max(floor, f/ROBUST_CAP), below ROBUST_CAP however small y is. One stray value
near 0 where the model is bright (a dropped sample at the specular peak: y = 1e-310 against
f = 50) had a residual of 5,000 and a soft-L1 cost of some 500, more than the 5.0 that setting its
band's F0 to 0 cost, which the fit did (F0(400 nm) 0.50 → 6·10⁻¹⁵, reported converged). At the cap
its gradient vanishes and it costs about ρ(2) = 0.2, twice what a bright sample costs where the
model gives 0 (r = −1, ρ = 0.095). The cap was 10 (ρ = 1, ten such samples): then one sample in
ten dropped to 0 made a model that is 0 everywhere the cheaper fit (rubber, 10 % zeros: median
error 100 %, against 1.3 % at 2; 2 % zeros: 1.46 % against 1.33 %). Samples at or above the
floor are not capped: a lobe whose peak overshot them cheaply hid between them (a smooth plastic
fitted with s = 0.46 and m = 0.0007 instead of s = 0). The default fits of ``measurements/``
(``ctfit fit FILE``) are the same at 2 as at 10 but for the yellow retro-reflective sheet: median
15.09 % against 15.07 %, 90th percentile 95.25 % against 95.26 % (docs/fitting.md)."""
FLOOR_OF_PEAK = 1e-6
"""The relative loss's floor is never below this fraction of the largest sample."""
SEED_FLOOR = 1e-3
"""For the losses without a floor of their own (sigma, absolute, cosine, log): the floor, × the
largest value, of the relative weights the seeds are scored with (and of ``rel_rmse``). From the
peak, as before the relative losses' floor moved to the typical sample: with the typical sample's
floor the seeds of σ-weighted synthetic fits fell into wrong basins (docs/stability.md: a
conductor with n(λ) crossing 1; s = 1 in float32)."""
LOG_RATIO_FLOOR = 0.01
"""The "log-ratio" loss's ε as a fraction of the median positive measured value (docs/fitting.md)."""


def loss_floor(y, loss: str) -> float:
    """The floor of the relative losses, from the typical sample (the median positive value), not
    the peak: for "relative", :data:`RELATIVE_FLOOR` × the median (every sample within a decade
    below it is weighed by its relative error, however high the peak; darker ones — the
    instrument's noise floor, stray zeros — by their absolute error over the floor), never below
    :data:`FLOOR_OF_PEAK` × the largest value (so that relative residuals stay representable);
    for "log-ratio", :data:`LOG_RATIO_FLOOR` × the median. "robust-relative" has the relative floor.
    The other losses have no floor in their residuals; theirs (:data:`SEED_FLOOR` × the largest
    value) weighs the seeds' relative scores and defines their ``rel_rmse``. 1 without a positive value."""
    return float(row_floors(np.asarray(y, dtype=float).reshape(1, -1), loss)[0])


def default_loss(data) -> str:
    """The loss of ``loss="auto"``: "sigma" when the data has a sigma column, else "robust-relative"
    (chosen by measurement on data the model cannot represent, docs/fitting.md)."""
    return "sigma" if getattr(data, "sigma", None) is not None else "robust-relative"


def row_floors(block: np.ndarray, loss: str) -> np.ndarray:
    """:func:`loss_floor` of each row of ``block`` (e.g. texels × samples)."""
    block = np.asarray(block, dtype=float)
    has = np.any(block > 0, axis=1)  # rows without a positive value: floor 1 (no all-NaN slice: fits run in threads, so no warning filters)
    floors = np.ones(block.shape[0])
    if has.any():
        pos = np.where(block[has] > 0, block[has], np.nan)
        peak = np.nanmax(pos, axis=1)
        if loss == "log-ratio":
            floors[has] = LOG_RATIO_FLOOR * np.nanmedian(pos, axis=1)
        elif loss in ("relative", "robust-relative"):
            floors[has] = np.maximum(RELATIVE_FLOOR * np.nanmedian(pos, axis=1), FLOOR_OF_PEAK * peak)
        else:
            floors[has] = SEED_FLOOR * peak
    return np.where(np.isfinite(floors), floors, 1.0)



def _absolute(problem: Problem, values, y):
    return values - y


def _relative(problem: Problem, values, y):
    return (values - y) / jnp.maximum(y, problem.floor)


def _robust_relative(problem: Problem, values, y):
    """soft-L1 of the relative residual: ρ(r) = 2c²(√(1 + (r/c)²) − 1) = r'², with the model's
    value over :data:`ROBUST_CAP` as a further floor of the denominator of a sample below the
    floor (there r < ROBUST_CAP)."""
    dark = y < problem.floor  # below a tenth of the typical sample: a stray zero can only be one of these
    r = (values - y) / jnp.maximum(jnp.maximum(y, problem.floor), jnp.where(dark, values / ROBUST_CAP, 0.0))
    return r * jnp.sqrt(2.0 / (jnp.hypot(1.0, r / ROBUST_SCALE) + 1.0))  # = sign(r)·√ρ(r), smooth at 0 (no cancellation)


def _sigma(problem: Problem, values, y):
    return (values - y) / problem.sigma


def _cosine(problem: Problem, values, y):
    return (values - y) * problem.cos_i


def _log(problem: Problem, values, y):
    """Löw et al. 2012: ln(1 + f cos θ_i) − ln(1 + y cos θ_i)."""
    return jnp.log1p(values * problem.cos_i) - jnp.log1p(y * problem.cos_i)


def _log_ratio(problem: Problem, values, y):
    """ln((f + ε)/(y + ε)): the relative error where y ≫ ε (ε: :func:`loss_floor`)."""
    eps = problem.floor
    return jnp.log(jnp.maximum(values, 0) + eps) - jnp.log(jnp.maximum(y, 0) + eps)


RESIDUALS = {"absolute": _absolute, "relative": _relative, "robust-relative": _robust_relative, "sigma": _sigma, "cosine": _cosine,
             "log": _log, "log-ratio": _log_ratio}
"""Each loss's residual ``(problem, values, y) -> r`` in the problem's layout (before the mask);
its keys are :data:`LOSSES`."""


def zero_model_cost(part: Problem):
    """½‖r‖² of a model that is 0 everywhere, over ``part`` (summable over chunks): the scale of a
    fit's cost (a cost below the dtype's ε times it is rounding: an exact fit)."""
    return 0.5 * jnp.sum(loss_residuals(part, jnp.zeros_like(part.y), part.y) ** 2)


def loss_residuals(problem: Problem, values, y, flat: bool = True):
    """Residuals in the problem's layout for the selected weighting (:data:`RESIDUALS`; missing cells give 0)."""
    r = RESIDUALS[problem.spec.loss](problem, values, y) * problem.mask
    return r.reshape(-1) if flat else r
