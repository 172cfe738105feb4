"""The result of a sampling run: posterior draws, their summaries, and the JSON section.

:class:`SampleResult` holds what :func:`ctfit.sample` found; :meth:`SampleResult.to_dict` is
the fit JSON's ``uncertainty`` section (``docs/uncertainty.md``) and
:meth:`SampleResult.to_inference_data` the same chain for ArviZ.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from .._io import jsonable
from .._model import Material

__all__ = ["SampleResult", "summarise"]

_QUANTILES = (("p2.5", 2.5), ("p16", 16.0), ("median", 50.0), ("p84", 84.0), ("p97.5", 97.5))


def summarise(a: np.ndarray) -> dict | list:
    """{"median", "p16", "p84", "p2.5", "p97.5", "mean", "std"} per entry of draws (n, ...)."""
    a = np.asarray(a, dtype=float)
    q = np.percentile(a, [p for _, p in _QUANTILES], axis=0)
    mean, std = np.mean(a, axis=0), np.std(a, axis=0)

    def one(idx: Any) -> dict[str, float]:
        d = {"median": float(q[2][idx]), "p16": float(q[1][idx]), "p84": float(q[3][idx])}
        d.update({"p2.5": float(q[0][idx]), "p97.5": float(q[4][idx]), "mean": float(mean[idx]), "std": float(std[idx])})
        return d

    if a.ndim == 1:
        return one(())
    return [one(i) for i in range(a.shape[1])]


@dataclasses.dataclass
class SampleResult:
    """Posterior draws and their summaries.

    - ``chain``: constrained draws after burn-in and thinning, all walkers flattened: a dict
      ``s`` (n,), ``m`` (n, J), ``weight`` (n, J), ``F0``/``n``/``k``/``Rd`` (n, W) (``Rd`` (n,)
      when constant), ``sigma_noise`` (n,) when the noise scale is sampled.
    - ``chain_u``: the raw chain (steps, walkers, ndim) in the sampled coordinates (``labels``);
      ``log_prob``: (steps, walkers).
    - ``summary``: per quantity ``{"median", "p16", "p84", "p2.5", "p97.5", "mean", "std"}``
      (lists over lobes/bands); ``colour``: the same for sRGB and CIELAB under D65 (or None).
    - ``diagnostics``: walkers, steps, burn, thin, draws, acceptance fraction, integrated
      autocorrelation time τ and effective sample size per sampled coordinate, ...
    - ``likelihood``, ``priors``: descriptions (also written to the JSON).
    - ``laplace_stderr``: the Laplace (JᵀJ)⁻¹ standard errors at the optimum (delta method),
      None when JᵀJ is ill conditioned; ``optimum``: the fit's constrained optimum the walkers
      started from; ``warnings``: plain-language notes (chain too short, low acceptance, ...).
    - ``usable``: whether the posterior passed the checks of :mod:`ctfit._sampling.checks`;
      ``problems``: one line per failed check (also among ``warnings``); ``checks``: their details.
    - ``draw_log_prob``: the log-posterior of each draw of ``chain``.

    >>> import warnings, numpy as np, ctfit
    >>> copper = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([0.3]), w=np.ones(1),
    ...                         f0=np.array([0.95, 0.64, 0.54])), channels=("R", "G", "B"))
    >>> data = ctfit.simulate(copper, n_pairs=100, noise=0.02, seed=1)
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore", ctfit.ChainTooShortWarning)  # a short chain, for the example
    ...     post = ctfit.sample(copper, data, steps=200, seed=0)  # copper's values are fitted first
    >>> sorted(post.chain), post.chain["F0"].shape[1]  # the reported quantities' draws, channels
    (['F0', 'm', 'n', 'weight'], 3)
    >>> section = post.to_dict()  # for the fit JSON
    >>> sorted(section["lobes"][0]), len(section["F0"]), section["colour"]["illuminant"]
    (['m', 'weight'], 3, 'sRGB white')
    """

    material: Material
    chain: dict
    chain_u: np.ndarray
    log_prob: np.ndarray
    labels: list[str]
    summary: dict
    colour: dict | None
    diagnostics: dict
    likelihood: dict
    priors: dict
    laplace_stderr: dict | None
    optimum: dict
    warnings: list[str]
    usable: bool = True
    problems: list[str] = dataclasses.field(default_factory=list)
    checks: dict = dataclasses.field(default_factory=dict)
    draw_log_prob: np.ndarray | None = None

    def to_dict(self) -> dict:
        """The fit JSON's ``uncertainty`` section (``docs/uncertainty.md``), JSON-ready."""
        out: dict = {"method": "emcee affine-invariant ensemble sampler (stretch move)"}
        sm = self.summary
        if "s" in sm:
            out["s"] = sm["s"]
        if "m" in sm:
            out["lobes"] = [{"m": sm["m"][j], "weight": sm["weight"][j]} for j in range(len(sm["m"]))]
        for key in ("F0", "n", "k", "Rd", "sigma_noise"):
            if key in sm:
                out[key] = sm[key]
        mat = self.material  # the data's bands, on which the per-band quantities were sampled
        if mat.channels is not None:
            out["channels"] = list(mat.channels)
        elif mat.wavelength_nm is not None:
            out["wavelength_nm"] = [float(w) for w in mat.wavelength_nm]
        if mat.band_unknown:
            out["band_unknown"] = True
        if self.colour is not None:
            out["colour"] = self.colour
        out["diagnostics"] = self.diagnostics
        out["likelihood"] = self.likelihood
        out["priors"] = self.priors
        out["warnings"] = list(self.warnings)
        out["usable"] = bool(self.usable)
        out["problems"] = list(self.problems)
        out["checks"] = self.checks
        return jsonable(out)

    def to_inference_data(self) -> Any:
        """The draws as an ``arviz.InferenceData`` (one chain per walker; groups posterior and
        sample_stats), for ``az.summary``, ``az.plot_trace``, ``az.plot_pair`` or ``to_netcdf``."""
        from .arviz_export import inference_data

        mat = self.material
        n = next(iter(self.chain.values())).shape[0]
        key = next((k for k in ("F0", "n", "k", "Rd") if k in self.chain and np.ndim(self.chain[k]) == 2), None)
        nb = 0 if key is None else self.chain[key].shape[1]
        bands = list(mat.channels) if mat.channels is not None else (list(map(float, mat.wavelength_nm)) if mat.wavelength_nm is not None else [])
        bands = bands if len(bands) == nb else list(range(nb))
        lp = self.draw_log_prob if self.draw_log_prob is not None else np.full(n, np.nan)
        attrs = {"sampler": "emcee", "loss": self.likelihood.get("loss", ""), "usable": int(self.usable)}
        return inference_data(self.chain, lp, int(self.diagnostics["walkers"]), bands, attrs)



