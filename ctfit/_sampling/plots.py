"""The posterior's plots: the corner plot of the global parameters and the spectral bands.

:func:`plot_corner` shows s, the lobes' m and weights and σ_noise (F0 at three bands, or R_d,
when there is less to show); :func:`plot_spectra` the per-band quantities with their 68 % and
95 % intervals. Both write the figure atomically (:func:`ctfit._io.files.atomic_save`).
"""

from __future__ import annotations

import os
import pathlib
from typing import Any

import numpy as np

from .._model import band_labels
from .result import SampleResult

__all__ = ["plot_corner", "plot_spectra", "CORNER_QUANTILES"]


def _pyplot() -> Any:
    from .._runtime import need

    need("plots", "a plot of a posterior")
    import matplotlib

    if "MPLBACKEND" not in os.environ and matplotlib.get_backend().lower() not in ("agg", "pdf", "svg"):
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save_figure(fig: Any, path: pathlib.Path, **options: Any) -> None:
    """``fig.savefig`` through an atomic write (the format from the file's suffix, PNG without one)."""
    from .._io import atomic_save, plot_metadata

    fmt = path.suffix[1:].lower() or "png"
    atomic_save(path, lambda buffer: fig.savefig(buffer, format=fmt, dpi=110, metadata=plot_metadata(fmt), **options))


def _global_columns(result: SampleResult) -> tuple[np.ndarray, list[str], list[float]]:
    """Draws (n, p), labels and optimum values of s, m_j, w_j (with F0 at the first, middle and
    last bands when there is only one of them; R_d bands for a diffuse-only material)."""
    ch, opt, mat = result.chain, result.optimum, result.material
    bands = band_labels(mat.wavelength_nm, mat.channels, mat.band_unknown)  # empty without wavelengths or channels: indices
    cols, labels, truths = [], [], []
    if "s" in ch:
        cols.append(ch["s"])
        labels.append("s")
        truths.append(float(opt["s"]))
    if "m" in ch:
        nl = ch["m"].shape[1]
        for j in range(nl):
            cols.append(ch["m"][:, j])
            labels.append(f"$m_{j + 1}$" if nl > 1 else "m")
            truths.append(float(opt["m"][j]))
        if nl > 1:  # w_J = 1 − Σ the others: its panels would only repeat theirs
            for j in range(nl - 1):
                cols.append(ch["weight"][:, j])
                labels.append(f"$w_{j + 1}$")
                truths.append(float(opt["weight"][j]))
    if len(cols) < 2 and "F0" in ch:  # one global parameter: show its correlation with F0
        nb = ch["F0"].shape[1]
        for i in sorted({0, nb // 2, nb - 1}):
            cols.append(ch["F0"][:, i])
            labels.append(f"$F_0$[{bands[i] if bands else i}]")
            truths.append(float(opt["F0"][i]))
    if not cols and "Rd" in ch:
        rd = ch["Rd"] if ch["Rd"].ndim == 2 else ch["Rd"][:, None]
        for i in range(min(rd.shape[1], 6)):
            cols.append(rd[:, i])
            labels.append(f"$R_d$[{bands[i] if bands else i}]")
            truths.append(float(np.ravel(opt["Rd"])[i]))
    if "sigma_noise" in ch and len(cols) < 6:
        cols.append(ch["sigma_noise"])
        labels.append(r"$\sigma_{noise}$")
        truths.append(float(opt["sigma_noise"]))
    keep = [i for i, c in enumerate(cols) if np.std(c) > 0]
    return np.stack([cols[i] for i in keep], axis=1), [labels[i] for i in keep], [truths[i] for i in keep]


CORNER_QUANTILES = (0.5, 99.5)
"""Percentiles of each quantity that the corner plot's axes span (the tails beyond are noted)."""


def _central_ranges(data: np.ndarray) -> tuple[list[tuple[float, float]], float]:
    """Axis ranges of the corner plot from central quantiles, widened by 5 % (a constant column:
    ± a little), and the fraction of draws outside any of them."""
    lo, hi = np.percentile(data, CORNER_QUANTILES, axis=0)
    pad = 0.05 * (hi - lo)
    pad = np.where(pad > 0, pad, 1e-9 * np.maximum(np.abs(lo), 1.0))
    lo, hi = lo - pad, hi + pad
    outside = float(np.mean(np.any((data < lo) | (data > hi), axis=1)))
    return [(float(a), float(b)) for a, b in zip(lo, hi)], outside


def plot_corner(
    result: SampleResult, path: str | os.PathLike[str], *, truths: dict | None = None, title: str | None = None
) -> pathlib.Path:
    """Corner plot (``corner`` package) of the global parameters s, m_j, w_j (j < J: the last
    weight is 1 − the others) and σ_noise; with a single global parameter (one lobe, no diffuse
    part), F0 at three bands join it.

    Dashed lines: 16 %, 50 %, 84 % quantiles; blue lines: the least-squares optimum the walkers
    started from, or ``truths`` (a list, one value per panel) when given. The axes span the
    central 99 % of each quantity (:data:`CORNER_QUANTILES`), not the extremes; the title says
    which fraction of the draws lies outside.

    >>> import warnings, numpy as np, ctfit
    >>> warnings.simplefilter("ignore", ctfit.ChainTooShortWarning)  # a short chain, for the example
    >>> gold = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([0.25]), w=np.ones(1),
    ...                       f0=np.array([0.6, 0.9])), wavelength_nm=np.array([450.0, 650.0]))
    >>> post = ctfit.sample(gold, ctfit.simulate(gold, 100, noise=0.02), steps=200)  # gold's values, fitted first
    >>> ctfit.plot_corner(post, "corner.png").stat().st_size > 0  # one global parameter, m: F0 joins it
    True
    """
    import corner

    plt = _pyplot()
    data, labels, opt = _global_columns(result)
    if data.shape[1] == 0:
        raise ValueError("nothing to plot: no sampled global parameter varies")
    ranges, outside = _central_ranges(data)
    fig = corner.corner(
        data,
        range=ranges,
        labels=labels,
        quantiles=[0.16, 0.5, 0.84],
        show_titles=True,
        title_fmt=".4g",
        truths=truths if truths is not None else opt,
        truth_color="#1f77b4",
        label_kwargs={"fontsize": 12},
        title_kwargs={"fontsize": 10},
    )
    from matplotlib.ticker import ScalarFormatter

    for ax in fig.axes:  # absolute values on the ticks, no "+2e−1" offsets
        for axis in (ax.xaxis, ax.yaxis):
            fmt = axis.get_major_formatter()
            if isinstance(fmt, ScalarFormatter):
                fmt.set_useOffset(False)
    d = result.diagnostics
    fig.suptitle(
        title
        or f"posterior ({d['draws']} draws, {d['walkers']} walkers × {d['steps']} steps, burn {d['burn']}); "
        + ("blue: truth" if truths is not None else "blue: least-squares optimum")
        + (f"\naxes: central {CORNER_QUANTILES[1] - CORNER_QUANTILES[0]:g} % of each quantity; {outside:.1%} of the draws lie outside" if outside > 0 else ""),
        fontsize=10,
        y=1.02,
    )
    path = pathlib.Path(path)
    _save_figure(fig, path, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_spectra(
    result: SampleResult, path: str | os.PathLike[str], *, truth: dict | None = None, title: str | None = None
) -> pathlib.Path:
    """F0(λ) and n(λ) (and k(λ), R_d(λ) where sampled) with their 68 % and 95 % posterior bands.

    Left column: the values — line: posterior median; dark band: 16–84 %; light band:
    2.5–97.5 %; crosses: the least-squares optimum; ``truth`` ({"F0": [...], "n": [...]}) as a
    dashed line. Right column: the same minus the posterior median, so that bands much narrower
    than the spectrum's range stay visible.

    >>> import warnings, numpy as np, ctfit
    >>> silver = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None),
    ...                         ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.9, 0.95, 0.97])),
    ...                         wavelength_nm=np.array([450.0, 550.0, 650.0]))
    >>> data = ctfit.simulate(silver, n_pairs=80, noise=0.02, seed=2)
    >>> with warnings.catch_warnings(action="ignore", category=ctfit.ChainTooShortWarning):  # a short chain
    ...     post = ctfit.sample(ctfit.fit(data, silver.structure), data, steps=300, seed=1)
    >>> ctfit.plot_spectra(post, "spectra.png", truth={"F0": silver.params.f0}).stat().st_size > 0
    True
    """
    plt = _pyplot()
    mat = result.material
    keys = [k for k in ("F0", "n", "k") if k in result.chain and result.chain[k].ndim == 2]
    if "Rd" in result.chain and result.chain["Rd"].ndim == 2 and mat.structure.diffuse in ("spectrum", "transmitted"):
        keys.append("Rd")
    if not keys:
        raise ValueError("nothing to plot: no per-band quantity was sampled")
    n_bands = result.chain[keys[0]].shape[1]
    rgb = mat.channels is not None or mat.wavelength_nm is None or mat.band_unknown  # bands by label, not on a wavelength axis
    x = np.arange(n_bands, dtype=float) if rgb else np.asarray(mat.wavelength_nm, dtype=float)
    names = {
        "F0": "$F_0$",
        "n": "n (effective)" if mat.structure.fresnel == "f0" else "n",
        "k": "k",
        "Rd": r"$R_d$ (sr$^{-1}$)",
    }
    marker = "o" if n_bands < 12 else None
    fig, axes = plt.subplots(len(keys), 2, figsize=(10, 2.5 * len(keys) + 0.6), sharex=True, squeeze=False)
    for row, key in enumerate(keys):
        q = np.percentile(result.chain[key], [2.5, 16, 50, 84, 97.5], axis=0)
        opt = np.ravel(result.optimum[key])
        tru = None if truth is None or key not in truth else np.ravel(np.asarray(truth[key], dtype=float))
        for col, ref in ((0, 0.0), (1, q[2])):
            ax = axes[row, col]
            ax.fill_between(x, q[0] - ref, q[4] - ref, color="#9ecae1", lw=0, label="95 %")
            ax.fill_between(x, q[1] - ref, q[3] - ref, color="#4292c6", lw=0, label="68 %")
            ax.plot(x, q[2] - ref, color="#08306b", lw=1.4, marker=marker, ms=3, label="median")
            ax.plot(x, opt - ref, "x", color="#d62728", ms=6, mew=1.5, label="least squares")
            if tru is not None:
                ax.plot(x, tru - ref, "--", color="k", lw=1, marker="s" if marker else None, ms=3, mfc="none", label="truth")
            ax.grid(alpha=0.3)
        axes[row, 0].set_ylabel(names[key])
        axes[row, 1].set_ylabel(f"{names[key]} − median")
        axes[row, 1].axhline(0, color="#08306b", lw=0.8)
    axes[0, 0].legend(fontsize=8, loc="best")
    for ax in axes[-1]:
        if rgb:
            ax.set_xticks(x)
            ax.set_xticklabels(band_labels(mat.wavelength_nm, mat.channels, mat.band_unknown) or [str(i) for i in range(n_bands)])
        else:
            ax.set_xlabel("wavelength (nm)")
    d = result.diagnostics
    fig.suptitle(title or f"posterior bands: median, 68 % and 95 % intervals ({d['draws']} draws)", fontsize=11)
    fig.tight_layout()
    path = pathlib.Path(path)
    _save_figure(fig, path)
    plt.close(fig)
    return path
