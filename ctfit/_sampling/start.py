"""Where the walkers start: the least-squares fit's optimum, spread by its Laplace covariance.

The optimum is the fit's (:func:`ctfit.fit`): a :class:`~ctfit.FitResult`, or a material saved
from a fit with the same loss, is taken as it is; anything else (a material with other values,
another loss) is fitted first, from its values. There is no second optimiser: the covariance
is (JᵀJ)⁻¹ of the fit's normal equations (:func:`ctfit._fitting.jacobian.normal_equations`) at that
optimum, in the sampler's coordinates, scaled by the residual variance unless the loss is
sigma-weighted, and used only where the fit would report standard errors (cond(JᵀJ) ≤ 1e12 on
the coordinates the data determine, :func:`ctfit._fitting.fit_report.standard_errors`); elsewhere the walkers start in
a small ball and the burn-in finds the scale.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from .._fitting import LOSSES, FitResult, standard_errors, undetermined
from .._model import Material, Params, x64_enabled

__all__ = ["check_fitted_loss", "start_params", "on_data_bands", "resolve_fit", "optimum_point", "laplace_start", "fit_covariance", "start_walkers"]

BALL_SD = 1e-2
"""Spread (in u) of a coordinate without a usable Laplace variance."""


def _fitted_loss(target) -> str | None:
    if isinstance(target, FitResult):
        return target.loss
    fit = target.meta.get("fit") if isinstance(target, Material) else None
    return fit.get("loss") if isinstance(fit, dict) else None


def check_fitted_loss(target) -> None:
    """Refuse (``ValueError``, naming the key) a material whose ``fit.loss`` is no loss of ctfit:
    it was refused as if given as the argument ("loss must be one of …, got 'banana'"), which
    the command showed as its ``--loss`` though none was given."""
    fitted = _fitted_loss(target)
    if fitted is not None and fitted not in LOSSES:
        raise ValueError(f"key 'fit.loss': {fitted!r} is not a loss of ctfit ({', '.join(LOSSES)}); choose the likelihood with loss=")


def start_params(material: Material, data) -> Params:
    """The material's parameters on the data's bands (F0 from n where only n is given)."""
    start = material.params_at(data.wavelength_nm if data.channels is None else None, data.channels)
    st = material.structure
    if st.needs_fresnel_params and st.fresnel == "f0" and start.f0 is None and start.n is not None:
        from .._model import f0_from_n

        start = dataclasses.replace(start, f0=np.asarray(f0_from_n(start.n)))
    return start


def on_data_bands(material: Material, data) -> tuple[Material, str | None]:
    """The material on the data's bands (its parameters by :func:`start_params`), and a note,
    where the two differ (a fit of 7 bands sampled on data of 4): what is sampled, and reported,
    is per band of the data. Otherwise the material as it is, and None."""
    if material.wavelength_nm is None and material.channels is None:
        return material, None
    same = (material.channels == data.channels if data.channels is not None
            else material.wavelength_nm is not None and np.array_equal(material.wavelength_nm, data.wavelength_nm))
    if same:
        return material, None
    bands = ", ".join(data.band_labels)
    resampled = dataclasses.replace(material, params=start_params(material, data), wavelength_nm=data.wavelength_nm, channels=data.channels,
                                    band_unknown=data.band_unknown)
    return resampled, f"sampled on the data's {len(data.band_labels)} band{'s' * (len(data.band_labels) != 1)} ({bands}), the material's values taken there"


def resolve_fit(target, data, loss: str | None, fixed: tuple[str, ...] | None):
    """(material, loss, fixed, note): the fitted material the sampler starts from, and a note when
    the fit had to be run.

    ``target``: a FitResult or a Material. ``loss`` None: the fit's (a "robust-relative" fit is sampled with
    the "relative" likelihood, multiplicative noise), else sigma/relative by the data. The fit is run
    (from the material's values) unless ``target`` already is one with this loss.
    """
    from .._fitting import fit

    material = getattr(target, "material", target)
    if not isinstance(material, Material):
        raise TypeError(f"sample() takes a FitResult or a Material, got {type(target).__name__}")
    if loss is None:
        check_fitted_loss(target)
    fitted = _fitted_loss(target)
    loss = loss or fitted or ("sigma" if data.sigma is not None else "relative")
    if loss == "robust-relative":
        loss = "relative"  # its likelihood: relative noise (a robust fit damps outliers; a likelihood has none to damp)
    fixed = tuple(material.meta.get("fixed", ())) if fixed is None else tuple(fixed)
    if fitted == loss or (fitted, loss) == ("robust-relative", "relative"):
        return material, loss, fixed, None
    dtype = jax.numpy.float64 if x64_enabled() else jax.numpy.float32
    res = fit(data, material.structure, start=start_params(material, data), fixed=fixed, loss=loss, dtype=dtype)
    why = (f"fitted with loss {loss!r} first (the material was fitted with "
           f"{fitted!r})") if fitted else f"fitted with loss {loss!r} first, from the material's values"
    if not res.converged:
        why += "; that fit did not converge (" + "; ".join(res.warnings[:1] or ["no minimum"]) + "), so the walkers start from where it stopped"
    return res.material, loss, fixed, why


def _observed(engine) -> int:
    """N, the measured samples (at least 1)."""
    return max(int(np.sum(np.asarray(engine.problem.mask))), 1)


def _residual_variance(engine, cost: float, n_free: int) -> float:
    """2·cost/(N − p) where the noise scale is sampled; 1 for σ-weighted residuals."""
    return 2 * cost / max(_observed(engine) - n_free, 1) if engine.layout.noise else 1.0


def optimum_point(engine, x_u: np.ndarray, cost: float | None = None) -> np.ndarray:
    """The fit's optimum in the sampled coordinates: the flat optimum ``x_u`` and, with a sampled
    noise scale, log σ̂ (σ̂² = 2·cost/N; ``cost``, ½ Σ r² of the likelihood's residual at
    ``x_u``, is computed when not given)."""
    if not engine.layout.noise:
        return np.asarray(x_u, float)
    cost = engine.normal(x_u)[0] if cost is None else cost
    return np.concatenate([x_u, [0.5 * np.log(max(2 * cost / _observed(engine), 1e-300))]])


def laplace_start(engine, x_u: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict | None]:
    """(x0, cov, Laplace standard errors or None) at the flat optimum ``x_u``: x0 is
    :func:`optimum_point`, σ̂'s variance (with a sampled noise scale) 1/(2N)."""
    layout = engine.layout
    cost, _, hess = engine.normal(x_u)
    scale2 = _residual_variance(engine, cost, x_u.size)
    x0 = optimum_point(engine, x_u, cost)
    cov = np.zeros((layout.ndim, layout.ndim))
    if layout.noise:
        cov[-1, -1] = 1.0 / (2 * _observed(engine))
    stderr, cov_u = None, None
    if np.all(np.isfinite(hess)) and np.isfinite(scale2):
        free = ~undetermined(hess)
        jac = engine.constrained_jac(x0)
        jt = {k: v[..., : layout.n_u] for k, v in jac.items() if k != "sigma_noise"}
        stderr = standard_errors(hess, jt, scale2, None, free)
        if stderr is not None:
            cov_u = np.diag(np.full(x_u.size, BALL_SD**2))
            cov_u[np.ix_(free, free)] = np.linalg.inv(hess[np.ix_(free, free)]) * scale2
    if cov_u is None:  # no usable curvature: a small ball, wider where the diagonal says so
        d = np.diag(hess) if np.all(np.isfinite(np.diag(hess))) else np.zeros(x_u.size)
        var = np.where(d > 0, scale2 / np.where(d > 0, d, 1.0), BALL_SD**2)
        cov_u = np.diag(np.minimum(np.where(np.isfinite(var), var, BALL_SD**2), BALL_SD**2))
    cov[: x_u.size, : x_u.size] = cov_u
    return x0, cov, stderr


def fit_covariance(engine, x_u: np.ndarray) -> np.ndarray:
    """The fit's own Laplace covariance at its optimum, in the sampled coordinates: (JᵀJ)⁺ · s² of
    the fit's loss (for the relative loss: divided by max(y, floor), not by the model). Zero where
    JᵀJ is not finite. How far the fit may lie from the posterior by its own noise."""
    cost, _, hess = engine.normal(x_u, likelihood=False)
    if not (np.all(np.isfinite(hess)) and np.isfinite(cost)):
        return np.zeros_like(hess)
    scale2 = _residual_variance(engine, cost, x_u.size)
    return np.linalg.pinv(0.5 * (hess + hess.T), rcond=1e-12, hermitian=True) * scale2


def _root(cov: np.ndarray) -> np.ndarray:
    """A square root of ``cov`` (Cholesky, else the diagonal's), rows scaled to sd ≤ 1 in u."""
    cov = 0.5 * (cov + cov.T)
    try:
        root = np.linalg.cholesky(cov + 1e-300 * np.eye(len(cov)))
    except np.linalg.LinAlgError:
        root = np.diag(np.sqrt(np.clip(np.diag(cov), 0, None)))
    sd = np.sqrt(np.sum(root**2, axis=1))
    return root * np.minimum(1.0, 1.0 / np.maximum(sd, 1e-300))[:, None]


def start_walkers(logp, x0: np.ndarray, cov: np.ndarray, nwalkers: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Walkers from N(x0, cov) (sd capped at 1 in u); draws without a finite log-probability are
    drawn again, closer. ValueError when the optimum itself has none."""
    if not np.isfinite(logp(x0[None])[0]):
        raise ValueError(
            "the posterior density is 0 at the fit's optimum (a value outside the priors' range, lobes with equal m, "
            "or, with the relative likelihood, a model that is 0 where the data are not); check the fit, the priors, or choose another loss="
        )
    root = _root(cov)
    coords = x0 + rng.standard_normal((nwalkers, x0.size)) @ root.T
    lp = logp(coords)
    scale = 1.0
    for attempt in range(60):
        bad = ~np.isfinite(lp)
        if not bad.any():
            return coords, lp
        if attempt % 6 == 5:
            scale *= 0.5
        coords[bad] = x0 + scale * rng.standard_normal((int(bad.sum()), x0.size)) @ root.T
        lp[bad] = logp(coords[bad])
    raise ValueError("could not start every walker with a finite posterior density near the fit's optimum")
