"""The log-posterior of a fit's parameters, laid out for emcee: what :func:`ctfit.sample` samples,
and, for scripts that evaluate it themselves, :func:`log_probability`.

:func:`set_up_posterior` resolves the fit the walkers start from (:mod:`ctfit._sampling.start`),
lays out the sampled coordinates (:class:`~ctfit._sampling.logprob.Layout`), the priors
(:mod:`ctfit._sampling.priors`) and the compiled functions (:class:`~ctfit._sampling.engine.Engine`).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree
from jaxtyping import ArrayLike, Float

from .._fitting import LOSSES, FitResult, from_params, make_problem
from .._model import Material, Measurement, x64_enabled
from .engine import Engine
from .logprob import Layout
from .priors import normalise_priors
from .start import on_data_bands, optimum_point, resolve_fit, start_params

__all__ = ["default_walkers", "PosteriorSetup", "set_up_posterior", "LogProbability", "log_probability"]


def default_walkers(ndim: int) -> int:
    """max(2·ndim + 2, 32), rounded up to an even number (emcee's stretch move splits in halves)."""
    n = max(2 * ndim + 2, 32)
    return n + (n % 2)


@dataclasses.dataclass
class PosteriorSetup:
    """One sampling problem, laid out: the fit it starts from and the compiled log-probability."""

    material: Material
    loss: str
    fixed: tuple[str, ...]
    note: str | None  # why the fit was run first, if it was
    layout: Layout
    prior: tuple
    engine: Engine
    x_u: np.ndarray  # the fit's optimum, flat, in the sampled coordinates
    walkers: int


def set_up_posterior(
    target: FitResult | Material, data: Measurement, *, loss: str | None = None, fixed: tuple[str, ...] | None = None,
    priors: dict | None = None, walkers: int | None = None,
) -> PosteriorSetup:
    """The sampling problem of ``target`` (a FitResult or a Material) on ``data``; the arguments
    are :func:`ctfit.sample`'s."""
    if not isinstance(data, Measurement):
        raise TypeError(f"data must be a ctfit.Measurement (the data the material was fitted to), got {type(data).__name__}")
    if loss is not None and loss not in LOSSES:
        raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
    material, loss, fixed, note = resolve_fit(target, data, loss, fixed)
    material, bands_note = on_data_bands(material, data)
    note = "; ".join(n for n in (bands_note, note) if n) or None
    st = material.structure
    dtype = jnp.float64 if x64_enabled() else jnp.float32
    start = start_params(material, data)
    problem = make_problem(st, data, fixed_params=start, fixed=fixed, loss=loss, dtype=dtype, space="unconstrained")
    u0 = {k: jnp.asarray(v, dtype=dtype) for k, v in from_params(problem.spec, start).items()}
    if not u0:
        raise ValueError("nothing to sample: every parameter of the material is fixed")
    names = tuple(sorted(u0))
    layout = Layout(names, tuple(tuple(np.shape(u0[k])) for k in names), noise=loss != "sigma", conductor=st.fresnel == "conductor",
                    order_lobes=st.lobes > 1 and "m" in u0, relative=loss == "relative", plastic=st.shared_index)
    prior = normalise_priors(priors, names, layout.noise)
    nwalkers = default_walkers(layout.ndim) if walkers is None else int(walkers)
    if nwalkers < 2 * layout.ndim or nwalkers % 2:
        raise ValueError(f"walkers must be even and ≥ 2·ndim = {2 * layout.ndim}, got {nwalkers}")
    engine = Engine(problem, layout, prior, nwalkers // 2)
    x_u = np.asarray(ravel_pytree(u0)[0], dtype=float)
    return PosteriorSetup(material, loss, fixed, note, layout, prior, engine, x_u, nwalkers)


class LogProbability:
    """The log-posterior density (up to a constant) that :func:`ctfit.sample` hands to emcee.

    Called with sampling coordinates, an array (k, ndim), it returns the k log-densities
    (−inf outside the priors' support or with lobes out of order in m). The coordinates are
    unconstrained (log m, logit F0, ..., then log σ_noise where the noise scale is sampled;
    ``docs/uncertainty.md``), the density is in them (the priors' log-Jacobians included).

    - ``labels``: the ndim coordinates' names ("F0[0]", "m[0]", ..., "sigma_noise");
    - ``optimum``: the fit's optimum in these coordinates, where ``ctfit.sample`` starts its
      walkers (with a sampled noise scale: log σ̂, σ̂² the mean square residual);
    - ``material``: the fit; ``loss``: the likelihood's residual weighting.
    """

    def __init__(self, setup: PosteriorSetup):
        self.material, self.loss, self.labels = setup.material, setup.loss, setup.layout.labels()
        self.optimum = optimum_point(setup.engine, setup.x_u)
        self._engine = setup.engine

    @property
    def ndim(self) -> int:
        """The number of sampled coordinates."""
        return len(self.labels)

    def __call__(self, coords: Float[ArrayLike, "*batch dim"]) -> Float[np.ndarray, "*batch"]:
        return self._engine(coords)


def log_probability(target: FitResult | Material, data: Measurement, *, loss: str | None = None, fixed: tuple[str, ...] | None = None,
                    priors: dict | None = None, walkers: int | None = None) -> LogProbability:
    """The log-posterior of the parameters of ``target`` (a :class:`~ctfit.FitResult` or a
    :class:`~ctfit.Material`) given ``data``, the function :func:`ctfit.sample` hands to emcee.

    ``loss``, ``fixed``, ``priors`` and ``walkers`` are :func:`ctfit.sample`'s (a fit is run first
    where ``sample`` would run it); the function evaluates the rows of its argument in compiled
    blocks of ``walkers // 2``, the half ensemble emcee's stretch move moves at once, so arrays
    of that many rows are the fastest to evaluate. Returns a :class:`LogProbability`.

    >>> import numpy as np, ctfit
    >>> metal = ctfit.Material(ctfit.Structure(lobes=1), ctfit.Params(m=np.array([0.25]), w=np.array([1.0]),
    ...                        f0=np.array([0.6, 0.9])), wavelength_nm=np.array([450.0, 650.0]))
    >>> data = ctfit.simulate(metal, 100, noise=0.02, seed=0)
    >>> lp = ctfit.log_probability(ctfit.fit(data, metal.structure, starts=1), data)
    >>> lp.labels
    ['F0[0]', 'F0[1]', 'm[0]']
    >>> values = lp(np.stack([lp.optimum, lp.optimum + 0.01]))
    >>> values.shape, bool(np.all(np.isfinite(values))), bool(values[0] > values[1])
    ((2,), True, True)
    """
    return LogProbability(set_up_posterior(target, data, loss=loss, fixed=fixed, priors=priors, walkers=walkers))
