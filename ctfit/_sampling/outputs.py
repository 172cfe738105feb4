"""Posterior samples to and from the outside: the fit JSON's ``uncertainty`` section, a readable
table, the corner plot and the spectral-band plot, and the body of ``ctfit sample``.

The ``uncertainty`` section (``docs/uncertainty.md``) is :meth:`SampleResult.to_dict`:
``s``, ``lobes[j].m``, ``lobes[j].weight``, ``F0[i]``, ``n[i]`` (``k[i]``, ``Rd``,
``sigma_noise`` where sampled), each ``{"median", "p16", "p84", "p2.5", "p97.5", "mean",
"std"}``; ``colour`` (sRGB and CIELAB under D65); ``diagnostics``; ``likelihood``; ``priors``;
``usable``, ``problems`` and ``checks`` (:mod:`ctfit._sampling.checks`); ``warnings``; ``plots``
(the PNGs written, when asked); ``idata`` (the ArviZ netCDF file, when asked).
"""

from __future__ import annotations

import os
import pathlib

import numpy as np

from .._model import Material, band_labels

__all__ = [
    "uncertainty_section",
    "plot_corner",
    "plot_spectra",
    "format_uncertainty_table",
    "sample_command_body",
    "fit_sample_body",
]


def uncertainty_section(result) -> dict:
    """The ``uncertainty`` section of the fit JSON for a :class:`~ctfit.SampleResult`."""
    return result.to_dict()


# --- plots --------------------------------------------------------------------------------------


def _pyplot():
    import matplotlib

    if "MPLBACKEND" not in os.environ and matplotlib.get_backend().lower() not in ("agg", "pdf", "svg"):
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save_figure(fig, path: pathlib.Path, **options) -> None:
    """``fig.savefig`` through an atomic write (the format from the file's suffix, PNG without one)."""
    from .._io import atomic_save

    fmt = path.suffix[1:].lower() or "png"
    atomic_save(path, lambda buffer: fig.savefig(buffer, format=fmt, dpi=110, **options))


def _global_columns(result) -> tuple[np.ndarray, list[str], list[float]]:
    """Draws (n, p), labels and optimum values of s, m_j, w_j (with F0 at the first, middle and
    last bands when there is only one of them; R_d bands for a diffuse-only material)."""
    ch, opt = result.chain, result.optimum
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
            labels.append(f"$F_0$[{_band_labels(result.material, nb)[i]}]")
            truths.append(float(opt["F0"][i]))
    if not cols and "Rd" in ch:
        rd = ch["Rd"] if ch["Rd"].ndim == 2 else ch["Rd"][:, None]
        for i in range(min(rd.shape[1], 6)):
            cols.append(rd[:, i])
            labels.append(f"$R_d$[{_band_labels(result.material, rd.shape[1])[i]}]")
            truths.append(float(np.ravel(opt["Rd"])[i]))
    if "sigma_noise" in ch and len(cols) < 6:
        cols.append(ch["sigma_noise"])
        labels.append(r"$\sigma_{noise}$")
        truths.append(float(opt["sigma_noise"]))
    keep = [i for i, c in enumerate(cols) if np.std(c) > 0]
    return np.stack([cols[i] for i in keep], axis=1), [labels[i] for i in keep], [truths[i] for i in keep]


def _band_labels(material: Material, n: int) -> list[str]:
    if material.channels is not None or material.wavelength_nm is not None:
        return material.band_labels  # "450 nm", a channel, or "unknown band"
    return [str(i) for i in range(n)]


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


def plot_corner(result, path, *, truths=None, title: str | None = None) -> pathlib.Path:
    """Corner plot (``corner`` package) of the global parameters s, m_j, w_j (j < J: the last
    weight is 1 − the others) and σ_noise; with a single global parameter (one lobe, no diffuse
    part), F0 at three bands join it.

    Dashed lines: 16 %, 50 %, 84 % quantiles; blue lines: the least-squares optimum the walkers
    started from, or ``truths`` (a list, one value per panel) when given. The axes span the
    central 99 % of each quantity (:data:`CORNER_QUANTILES`), not the extremes; the title says
    which fraction of the draws lies outside.
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


def plot_spectra(result, path, *, truth: dict | None = None, title: str | None = None) -> pathlib.Path:
    """F0(λ) and n(λ) (and k(λ), R_d(λ) where sampled) with their 68 % and 95 % posterior bands.

    Left column: the values — line: posterior median; dark band: 16–84 %; light band:
    2.5–97.5 %; crosses: the least-squares optimum; ``truth`` ({"F0": [...], "n": [...]}) as a
    dashed line. Right column: the same minus the posterior median, so that bands much narrower
    than the spectrum's range stay visible.
    """
    plt = _pyplot()
    mat = result.material
    keys = [k for k in ("F0", "n", "k") if k in result.chain and result.chain[k].ndim == 2]
    if "Rd" in result.chain and result.chain["Rd"].ndim == 2 and mat.structure.diffuse == "spectrum":
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
            ax.set_xticklabels(_band_labels(mat, n_bands))
        else:
            ax.set_xlabel("wavelength (nm)")
    d = result.diagnostics
    fig.suptitle(title or f"posterior bands: median, 68 % and 95 % intervals ({d['draws']} draws)", fontsize=11)
    fig.tight_layout()
    path = pathlib.Path(path)
    _save_figure(fig, path)
    plt.close(fig)
    return path


# --- table --------------------------------------------------------------------------------------


def _fmt(s: dict | None) -> str:
    if not s or s.get("median") is None:
        return "—"
    med, lo, hi = s["median"], s["p16"], s["p84"]
    return f"{med:.6g} (+{hi - med:.2g} / −{med - lo:.2g})"


def format_uncertainty_table(doc: dict, label: str = "") -> str:
    """A plain-text table of an ``uncertainty`` section (or a whole fit JSON document holding one)."""
    u = doc.get("uncertainty", doc)
    lines = [f"posterior of {label}" if label else "posterior", "-" * 72, "  median (+p84 − median / −median − p16)"]
    if "s" in u:
        lines.append(f"  s = {_fmt(u['s'])}")
    for j, lobe in enumerate(u.get("lobes", [])):
        lines.append(f"  lobe {j}: m = {_fmt(lobe['m'])}   weight = {_fmt(lobe['weight'])}")
    band_keys = [k for k in ("F0", "n", "k", "Rd") if isinstance(u.get(k), list)]
    if band_keys:
        if doc.get("wavelength_nm") or doc.get("channels"):  # the material's labels: "450 nm", a channel, "unknown band"
            labels = band_labels(doc.get("wavelength_nm"), doc.get("channels"), bool(doc.get("band_unknown")))
        else:  # band indices, without a wavelength
            labels = [f"band {i}" for i in range(len(u[band_keys[0]]))]
        lines.append("  " + f"{'band':>12}" + "".join(f"  {k:>32}" for k in band_keys))
        for i, lab in enumerate(labels):
            lines.append("  " + f"{lab:>12}" + "".join(f"  {_fmt(u[k][i]):>32}" for k in band_keys))
    if isinstance(u.get("Rd"), dict):
        lines.append(f"  Rd = {_fmt(u['Rd'])}")
    if "sigma_noise" in u:
        lines.append(f"  sigma_noise = {_fmt(u['sigma_noise'])}   ({u['likelihood']['loss']} residuals)")
    col = u.get("colour")
    if col:
        srgb = ", ".join(f"{c['median']:.3f}" for c in col["sRGB"])
        lab = ", ".join(_fmt(c) for c in col["Lab"])
        lines.append(f"  colour ({col['illuminant']}): sRGB median ({srgb}) {col['sRGB_hex_median']}   Lab {lab}")
    d = u.get("diagnostics", {})
    if d:
        lines.append("-" * 72)
        acc = d["acceptance_fraction"]
        lines.append(
            f"  walkers: {d['walkers']}   steps: {d['steps']}   burn: {d['burn']}   thin: {d['thin']}   draws: {d['draws']}   "
            f"acceptance: {acc['mean']:.2f}"
        )
        lines.append(
            f"  τ_max: {d['autocorr_time_max']:.1f} steps   ESS_min (ArviZ, bulk): {d['ess_min']:.0f}   R̂_max: {d.get('r_hat_max', float('nan')):.3f}   "
            f"chain ≥ 50 τ: {d['chain_long_enough']}   time: {d['time_s']:.1f} s"
        )
        per = [f"{k} {d['ess_bulk'][k]:.0f}/{d['r_hat'][k]:.3f}" for k in d.get("ess_bulk", {})]
        if per:
            lines.append("  ESS (bulk) / R̂ per quantity: " + ", ".join(per))
    priors = u.get("priors", {}).get("parameters", {})
    if priors:
        lines.append("  priors: " + "; ".join(e["density"] for e in priors.values()))
    problems = list(u.get("problems", []))
    if "usable" in u:
        lines.append("  posterior: " + ("usable" if u["usable"] else "NOT usable: the problems below say why"))
    for w in problems:
        lines.append(f"  problem: {w}")
    for w in u.get("warnings", []):
        if w not in problems:
            lines.append(f"  warning: {w}")
    return "\n".join(lines)


# --- command bodies -----------------------------------------------------------------------------


def _read_data(path):
    from .._model import Measurement

    if isinstance(path, Measurement):
        return path
    from .._io import read_measurement

    return read_measurement(path)


def _plots(result, plot_dir, stem: str) -> list[str]:
    plot_dir = pathlib.Path(plot_dir)
    plot_dir.mkdir(parents=True, exist_ok=True)
    out = []
    try:
        out.append(str(plot_corner(result, plot_dir / f"{stem}.corner.png")))
    except ValueError:
        pass
    try:
        out.append(str(plot_spectra(result, plot_dir / f"{stem}.spectra.png")))
    except ValueError:
        pass
    return out


def _stem(path: pathlib.Path) -> str:
    name = path.name
    for suffix in (".json", ".toml"):
        if name.endswith(suffix):
            name = name[: -len(suffix)]
    return name


def _run(target, data, *, walkers, steps, burn, thin, seed, backend, resume, progress, priors, overwrite=False, loss=None):
    from .emcee_run import sample

    return sample(
        target,
        data,
        walkers=walkers,
        steps=steps,
        burn=burn,
        thin=thin,
        seed=seed,
        backend=None if backend is None else str(backend),
        resume=resume,
        overwrite=overwrite,
        progress=progress,
        priors=priors,
        loss=loss,
    )


def _write_idata(result, path) -> str:
    """The chain as ArviZ netCDF (``az.from_netcdf(path)``), written atomically."""
    import tempfile

    from .._io import atomic_write

    with tempfile.TemporaryDirectory() as folder:
        tmp = pathlib.Path(folder) / "run.nc"
        result.to_inference_data().to_netcdf(str(tmp))
        atomic_write(path, [tmp.read_bytes()])
    return str(path)


def sample_command_body(
    fit_json,
    data,
    walkers: int | None = None,
    steps: int = 2000,
    burn: int | None = None,
    thin: int = 1,
    seed: int = 0,
    backend=None,
    resume: bool = False,
    plot_dir=None,
    output=None,
    *,
    progress: bool = False,
    priors: dict | None = None,
    overwrite: bool = False,
    loss: str | None = None,
    idata=None,
) -> dict:
    """``ctfit sample FIT.json DATA``: sample, write the fit JSON with its ``uncertainty`` section.

    Reads the material (fit JSON or TOML) and the measurement (a path, or a
    :class:`~ctfit.Measurement` already read), samples (the loss recorded in
    the file's ``fit`` section, else sigma/relative), writes ``output`` (default: ``fit_json``
    itself, updated in place) atomically — every key of the input kept, ``uncertainty``
    replaced — and, with ``plot_dir``, ``<stem>.corner.png`` and ``<stem>.spectra.png``.
    ``overwrite``: start a new chain in an existing ``backend`` (see :func:`ctfit.sample`);
    ``loss``: the likelihood's residual weighting (another than the file's fits again first);
    ``idata``: also write the chain as ArviZ netCDF there. Returns the document written (JSON-ready).
    """
    from .._io import check_output, check_output_folder, load_material, material_to_dict, save_material_json

    fit_json = pathlib.Path(fit_json)
    material = load_material(fit_json)
    if str(fit_json).endswith(".toml") and output is None:
        raise ValueError(f"{fit_json}: a TOML material is not overwritten; pass an output JSON path")
    target = pathlib.Path(output) if output is not None else fit_json
    check_output(target, [data] if isinstance(data, (str, os.PathLike)) else [], option="-o" if output is not None else "")
    if plot_dir is not None:
        check_output_folder(plot_dir, "--plot")
    meas = _read_data(data)
    res = _run(
        material, meas, walkers=walkers, steps=steps, burn=burn, thin=thin, seed=seed, backend=backend, resume=resume,
        progress=progress, priors=priors, overwrite=overwrite, loss=loss,
    )  # fmt: skip
    unc = res.to_dict()
    if plot_dir is not None:
        unc["plots"] = _plots(res, plot_dir, _stem(target))
    if idata is not None:
        unc["idata"] = _write_idata(res, idata)
    extra = {"uncertainty": unc}
    save_material_json(material, target, extra=extra)
    return material_to_dict(material, extra=extra)


def fit_sample_body(
    fit_result,
    data,
    *,
    walkers: int | None = None,
    steps: int = 2000,
    burn: int | None = None,
    thin: int = 1,
    seed: int = 0,
    backend=None,
    resume: bool = False,
    plot_dir=None,
    output=None,
    progress: bool = False,
    priors: dict | None = None,
    plot_stem: str = "fit",
    overwrite: bool = False,
) -> dict:
    """``ctfit fit DATA --sample``: sample a fresh :class:`~ctfit.FitResult` on its measurement.

    Returns the fit-result document with ``fit`` and ``uncertainty`` sections; writes it
    atomically to ``output`` when given, and the plots to ``plot_dir``. ``overwrite``: start a
    new chain in an existing ``backend`` (see :func:`ctfit.sample`).
    """
    from .._fitting import fit_result_to_dict
    from .._io import material_to_dict, save_material_json

    res = _run(
        fit_result, data, walkers=walkers, steps=steps, burn=burn, thin=thin, seed=seed, backend=backend, resume=resume,
        progress=progress, priors=priors, overwrite=overwrite,
    )  # fmt: skip
    unc = res.to_dict()
    if plot_dir is not None:
        unc["plots"] = _plots(res, plot_dir, _stem(pathlib.Path(output)) if output is not None else plot_stem)
    extra = {**fit_result_to_dict(fit_result, material_keys=False), "uncertainty": unc}
    if output is not None:
        save_material_json(fit_result.material, output, extra=extra)
    return material_to_dict(fit_result.material, extra=extra)
