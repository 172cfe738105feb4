"""Posterior sampling of the Cook–Torrance parameters with emcee (Foreman-Mackey et al. 2013),
built on the least-squares fit.

``sample(fit_result_or_material, data, ...)`` → :class:`SampleResult`. The run:

1. the fit's optimum and its JᵀJ (:mod:`ctfit._sampling.start`; the fit is run first when the
   material is not a fit with this loss);
2. emcee's affine-invariant ensemble sampler on the log-posterior of
   :mod:`ctfit._sampling.logprob` (priors of :mod:`ctfit._sampling.priors`; laid out by
   :mod:`ctfit._sampling.posterior_density`, which also hands it out: :func:`ctfit.log_probability`), walkers started around the
   optimum with its Laplace covariance, the chain kept in an HDF5 file on request
   (:mod:`ctfit._sampling.backend`);
3. burn-in, emcee's τ and ArviZ's ESS and R̂ (:mod:`ctfit._sampling.chain_diagnostics`,
   :mod:`ctfit._sampling.arviz_export`), the colour of the draws (:mod:`ctfit._sampling.draw_colours`), and the
   checks that say whether the posterior is usable (:mod:`ctfit._sampling.checks`).

References
----------
- Foreman-Mackey, D., Hogg, D. W., Lang, D., Goodman, J. (2013). emcee: The MCMC Hammer.
  PASP 125(925), 306. doi:10.1086/670067
- Goodman, J., Weare, J. (2010). Ensemble samplers with affine invariance. CAMCoS 5(1), 65–80.
  doi:10.2140/camcos.2010.5.65
- Sokal, A. (1997). Monte Carlo methods in statistical mechanics: foundations and new
  algorithms. In Functional Integration, 131–192.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import time
import warnings
from collections.abc import Iterable
from typing import Any

import numpy as np

from .._fitting import FitResult, undetermined
from .._model import Material, Measurement
from .backend import fingerprint, open_run
from .chain_diagnostics import ChainTooShortWarning, autocorr_time, default_burn, likelihood_description, residual_spread, run_notes
from .checks import check_mixing, check_posterior, fit_distance, noise_scale_misfit, sigma_misfit
from .draw_colours import colour_summary
from .posterior_density import PosteriorSetup, set_up_posterior
from .priors import describe_priors
from .result import SampleResult, summarise
from .run_limits import check_lengths
from .start import fit_covariance, laplace_start, start_walkers

__all__ = ["sample"]


def _run(
    s: PosteriorSetup, x0: np.ndarray, cov: np.ndarray, *, steps: int, seed: int, backend: Any, resume: bool,
    overwrite: bool,
    progress: bool | str,
) -> tuple[Any, int, int, float]:
    """Run (or continue) the chain: (sampler, steps run now, steps done before, seconds)."""
    import emcee

    labels = s.layout.labels()
    shape = (s.walkers, s.layout.ndim)
    be, done, new = open_run(backend, resume=resume, overwrite=overwrite, steps=steps, shape=shape,
                             fingerprint=fingerprint(s.engine.problem, s.loss, labels, s.prior), labels=labels, seed=seed)
    try:
        sampler = emcee.EnsembleSampler(s.walkers, s.layout.ndim, s.engine, vectorize=True, backend=be)
        state, todo = None, steps - done  # resumed: the backend's last sample and random state
        if done == 0:
            coords, lp = start_walkers(s.engine, x0, cov, s.walkers, np.random.default_rng(seed))
            sampler.random_state = np.random.RandomState(seed).get_state()
            state = emcee.State(coords, log_prob=lp)
        t = time.perf_counter()
        if todo > 0 and progress == "lines":
            from .._runtime import ProgressLines

            lines = ProgressLines(steps, desc="sampling", done=done)
            for _ in sampler.sample(state if state is not None else sampler.get_last_sample(), iterations=todo):
                lines.update()
        elif todo > 0:
            sampler.run_mcmc(state, todo, progress=bool(progress))
    except KeyboardInterrupt:  # a library user's Ctrl-C: as the command's (backend.NewChain)
        if new is not None:
            new.stop()
        raise
    except BaseException:
        if new is not None:  # the run failed: the file keeps what it held
            new.abandon()
        raise
    if new is not None:  # the new chain is whole: it replaces what the file held
        new.commit()
    return sampler, todo, done, time.perf_counter() - t


def _checks(s: PosteriorSetup, x0: np.ndarray, flat: np.ndarray, draw_lp: np.ndarray, chain: dict, optimum: dict, spread: float | None) -> dict:
    """The usability checks, with the posterior density in θ (the density in u less log|∂θ/∂u|);
    ``spread``: :func:`_residual_spread`."""
    lp_theta = draw_lp - s.engine.log_jacobian(flat)
    lp_opt = float(s.engine(x0[None])[0] - s.engine.log_jacobian(x0[None])[0])
    distance = fit_distance(flat[:, : s.layout.n_u], s.x_u, fit_covariance(s.engine, s.x_u))
    labels = s.layout.labels()
    half_chi2, _, jtj = s.engine.normal(s.x_u)
    loose = [labels[i] for i in np.flatnonzero(undetermined(jtj))]
    observed = int(np.sum(np.asarray(s.engine.problem.mask)))
    misfit = sigma_misfit(2 * float(half_chi2), observed - s.layout.n_u) if s.loss == "sigma" else noise_scale_misfit(spread, s.loss, observed)
    return check_posterior(chain, s.prior, s.layout.fresnel, lp_theta, lp_opt, optimum, distance, loose, misfit)


def _diagnostics(
    s: PosteriorSetup, sampler: Any, *, burn: int, thin: int, todo: int, done: int, run_s: float, seed: int, backend: Any
) -> dict:
    chain_u = np.asarray(sampler.get_chain())
    n_steps = chain_u.shape[0]
    tau = autocorr_time(chain_u[burn:])
    acc = np.asarray(sampler.acceptance_fraction, dtype=float)
    labels = s.layout.labels()
    return {
        "walkers": s.walkers, "ndim": s.layout.ndim, "steps": n_steps, "steps_run_now": int(max(todo, 0)), "resumed_from": done,
        "burn": int(burn), "thin": int(thin), "seed": int(seed),
        "acceptance_fraction": {"mean": float(np.mean(acc)), "min": float(np.min(acc)), "max": float(np.max(acc))},
        "autocorr_time": dict(zip(labels, map(float, tau))), "autocorr_time_max": float(np.max(tau)),
        "ess_emcee": dict(zip(labels, map(float, s.walkers * (n_steps - burn) / np.maximum(tau, 1.0)))),
        "chain_long_enough": bool(n_steps - burn >= 50 * float(np.max(tau))),
        "sampling_time_s": run_s, "walker_steps_per_s": (s.walkers * todo / run_s) if run_s > 0 and todo > 0 else None,
        "backend": None if backend is None else str(backend),
        "autocorr_note": "τ in steps, per sampled coordinate (u of ctfit._model.parameters); ess_emcee = walkers · (steps − burn)/τ; "
                         "ess_bulk, ess_tail, r_hat: ArviZ's, per reported quantity (one chain per walker)",
    }


def sample(
    fit_result_or_material: FitResult | Material, data: Measurement, *, walkers: int | None = None, steps: int = 2000,
    burn: int | None = None, thin: int = 1, seed: int = 0, backend: str | os.PathLike[str] | None = None, resume: bool = False,
    overwrite: bool = False, progress: bool | str = False,
    priors: dict | None = None, loss: str | None = None, fixed: tuple[str, ...] | None = None, colour: bool = True,
) -> SampleResult:
    """Sample the posterior of the material's parameters given ``data``, starting from the fit.

    ``fit_result_or_material``: a :class:`~ctfit.FitResult`, or a :class:`~ctfit.Material` (a
    loaded fit JSON is used as the fit; other values, or another ``loss``, are fitted first).
    ``loss``: one of the fit's losses (default: the fit's, else "sigma" with a sigma column, else
    "relative"); ``fixed``: parameters held fixed (default: the material's ``fixed`` key);
    ``priors``: {name: (kind, *args)} (:mod:`ctfit._sampling.priors`). ``walkers`` (default
    :func:`~ctfit._sampling.posterior_density.default_walkers`), ``steps`` per walker (the total,
    also when resuming), ``burn`` (default max(2 τ_max, steps/10), at most steps/2 and
    steps − ``thin``), ``thin``; ``seed`` fixes the start and emcee's generator (each within
    :mod:`~ctfit._sampling.run_limits`' ranges). ``backend``: HDF5 file of the chain; ``resume`` continues a stored run to
    ``steps`` (bit-identical to an uninterrupted run), ``overwrite`` starts it again (written beside
    the file, which it replaces when it ends: :mod:`ctfit._sampling.backend`). A backend that
    another run is writing is refused (a ``ValueError`` naming it) before anything is read from it.
    ``colour``: also summarise the colour (sRGB, CIELAB) of the draws. ``progress``: True (or
    "bar"), a tqdm bar on stderr; "lines", a line on stderr every few seconds
    (:class:`~ctfit._runtime.progress.ProgressLines`: for a log file).

    Warns :class:`ChainTooShortWarning` when steps − burn < 50 τ_max. The result's ``usable``
    is False, and ``problems`` says why, when the walkers have not mixed (and how many steps
    would do), the posterior left the fit, runs to a prior bound or is not constrained by the
    data (:mod:`ctfit._sampling.checks`).

    >>> import warnings, numpy as np, ctfit
    >>> gold = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None),
    ...                       ctfit.Params(m=np.array([0.25]), w=np.array([1.0]), f0=np.array([0.6, 0.9])),
    ...                       wavelength_nm=np.array([450.0, 650.0]))
    >>> data = ctfit.simulate(gold, n_pairs=100, noise=0.02, seed=0)
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore", ctfit.ChainTooShortWarning)  # a short chain, for the example
    ...     post = ctfit.sample(ctfit.fit(data, gold.structure), data, steps=200, seed=0)
    >>> post.labels  # the sampled coordinates: logit F0, log m
    ['F0[0]', 'F0[1]', 'm[0]']
    >>> m = post.summary["m"][0]  # the rms slope's posterior: median, 68 % and 95 % intervals
    >>> bool(m["p2.5"] < m["p16"] < m["median"] < m["p84"] < m["p97.5"]), bool(m["p2.5"] < 0.25 < m["p97.5"])
    (True, True)
    """
    from .._runtime import need

    need("posterior", "posterior sampling")  # ArviZ's ESS and R̂ end every run: checked before it starts
    t0 = time.perf_counter()
    check_lengths(steps=steps, burn=burn, thin=thin, seed=seed, resume=resume, backend=backend, walkers=walkers)
    with contextlib.ExitStack() as hold:  # the backend's lock (check_backend), held until the chain is read back: one run writes it at a time
        if backend is not None:
            from .._io import check_backend

            check_backend(backend, resume=resume, overwrite=overwrite, flags=("resume=True", "overwrite=True"), option="backend", hold=hold)
        s = set_up_posterior(fit_result_or_material, data, loss=loss, fixed=fixed, priors=priors, walkers=walkers)
        x0, cov, laplace = laplace_start(s.engine, s.x_u)
        sampler, todo, done, run_s = _run(s, x0, cov, steps=steps, seed=seed, backend=backend, resume=resume, overwrite=overwrite, progress=progress)
        chain_u = np.asarray(sampler.get_chain())
        burn = default_burn(chain_u, thin) if burn is None else int(burn)
        if not 0 <= burn < chain_u.shape[0]:
            raise ValueError(f"burn must be in [0, steps), got {burn} with steps={chain_u.shape[0]}")
        if chain_u.shape[0] - burn < thin:
            raise ValueError(f"thin must be at most steps − burn = {chain_u.shape[0] - burn} to keep a draw, got thin={thin} (burn={burn})")
        flat = np.asarray(sampler.get_chain(discard=burn, thin=thin, flat=True))
        draw_lp = np.asarray(sampler.get_log_prob(discard=burn, thin=thin, flat=True))
        chain = s.engine.constrained(flat)
        optimum = {k: v[0] for k, v in s.engine.constrained(x0[None]).items()}
        d = _diagnostics(s, sampler, burn=burn, thin=thin, todo=todo, done=done, run_s=run_s, seed=seed, backend=backend)
        d["residual_scale_ratio"] = _residual_spread(s, flat, draw_lp)
        checks = _checks(s, x0, flat, draw_lp, chain, optimum, d["residual_scale_ratio"])
        return _result(s, sampler, chain, flat, draw_lp, optimum, laplace, checks, d, colour, t0)  # (it reads the chain file too)


def _residual_spread(s: PosteriorSetup, flat: np.ndarray, draw_lp: np.ndarray) -> float | None:
    """:func:`residual_spread` of the likelihood's residuals at its own best draw (the fit's
    optimum is another loss's), where the noise scale is sampled; else None."""
    if not s.layout.noise:
        return None
    keep = np.asarray(s.engine.problem.mask).reshape(-1) > 0
    best = flat[int(np.argmax(draw_lp)), : s.layout.n_u]
    r, values = s.engine.residuals(best)
    return residual_spread(r[keep], values[keep])


def _result(
    s: PosteriorSetup, sampler: Any, chain: dict, flat: np.ndarray, draw_lp: np.ndarray, optimum: dict, laplace: Any,
    checks: dict, d: dict, colour: bool, t0: float,
) -> SampleResult:
    """The :class:`SampleResult`: summaries, ArviZ's diagnostics, notes and warnings."""
    problem = s.engine.problem
    keep = np.asarray(problem.mask).reshape(-1) > 0
    tau = np.asarray(list(d["autocorr_time"].values()))
    run = run_notes(d["steps"] - d["burn"], tau, s.layout.labels(), sampler.acceptance_fraction)
    short = run[0] if not d["chain_long_enough"] else None  # run_notes says so first
    if short is not None:
        warnings.warn(short, ChainTooShortWarning, stacklevel=3)
    notes = ([s.note] if s.note else []) + run
    if laplace is None:
        notes.append("Laplace standard errors not computed: JᵀJ is singular or ill conditioned (cond > 1e12), as in the fit")
    col = None
    if colour:
        col, note = colour_summary(s.material, chain)
        notes += [note] if note else []
    res = SampleResult(
        material=s.material, chain=chain, chain_u=np.asarray(sampler.get_chain()), log_prob=np.asarray(sampler.get_log_prob()),
        labels=s.layout.labels(), summary={k: summarise(v) for k, v in chain.items()}, colour=col, diagnostics=d,
        likelihood=likelihood_description(s.loss, int(np.sum(keep)), float(problem.floor)),
        priors=describe_priors(s.prior, s.fixed, s.layout.fresnel, s.layout.order_lobes), laplace_stderr=laplace, optimum=optimum,
        warnings=checks["problems"] + notes, usable=checks["usable"], problems=checks["problems"],
        checks={k: v for k, v in checks.items() if k not in ("usable", "problems")}, draw_log_prob=draw_lp,
    )
    from .arviz_export import diagnostics

    per = diagnostics(res.to_inference_data())
    d.update(draws=int(flat.shape[0]), ess_bulk={k: v["ess_bulk"] for k, v in per.items()}, ess_tail={k: v["ess_tail"] for k, v in per.items()},
             r_hat={k: v["r_hat"] for k, v in per.items()}, time_s=time.perf_counter() - t0)
    d.update(ess_min=_least(d["ess_bulk"].values()), ess_tail_min=_least(d["ess_tail"].values()), r_hat_max=-_least(-r for r in d["r_hat"].values()))
    return _with_mixing(res, check_mixing(d), short)


def _least(values: Iterable[float]) -> float:
    """The smallest value, NaN when there is none or one is NaN (a quantity too short to read)."""
    v = np.asarray(list(values), dtype=np.float64)
    return float(np.min(v)) if v.size else float("nan")


def _with_mixing(res: SampleResult, mixing: dict, short: str | None) -> SampleResult:
    """``res`` with the mixing check (:func:`~ctfit._sampling.checks.check_mixing`) in its
    checks; when it fails, its line first among the problems (and the warnings, in place of
    ``short``, the note on a short chain, which the line says again) and the posterior not usable."""
    checks = {"mixing": {k: v for k, v in mixing.items() if k != "line"}, **res.checks}
    if not mixing["flag"]:
        return dataclasses.replace(res, checks=checks)
    line = mixing["line"]
    rest = [w for w in res.warnings if w != short]
    return dataclasses.replace(res, usable=False, problems=[line, *res.problems], warnings=[line, *rest], checks=checks)
