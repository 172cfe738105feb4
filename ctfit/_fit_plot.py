"""Plots of a fit against its data: slices through the specular peak, spectra, fitted F0(λ).

``plot_fit(result, data, path)`` writes one PNG with three panels:

1. In-plane slices: for up to four incidence angles, the data within ±2.5° of the plane of
   incidence (φ_o ≈ φ_i + 180° counted positive, φ_o ≈ φ_i negative) against the model evaluated
   densely along that plane, in one band (the middle one), on a log scale.
2. Spectra: data and model across the bands at the sample nearest the mirror direction and at
   one far from it; for single-band data, the relative residuals against the angle between L
   and V instead (a retro-reflection lobe shows up near 0°).
3. The fitted normal reflectance F0 per band with ±1 standard error where computed.
"""

from __future__ import annotations

import numpy as np

from ._brdf import normal_reflectance
from ._measurement import Measurement
from ._simulate import evaluate

__all__ = ["plot_fit"]


def _in_plane(data: Measurement, theta_i: float, band: int):
    dphi = np.mod(data.phi_o - data.phi_i, 360.0)
    sel = (np.abs(data.theta_i - theta_i) < 1e-6) & (data.band == band)
    fwd = sel & (np.abs(dphi - 180.0) < 2.5)
    back = sel & ((dphi < 2.5) | (dphi > 357.5))
    x = np.concatenate([data.theta_o[fwd], -data.theta_o[back]])
    y = np.concatenate([data.brdf[fwd], data.brdf[back]])
    order = np.argsort(x)
    return x[order], y[order]


def plot_fit(result, data: Measurement, path) -> None:
    """Write the data-vs-fit figure of ``result`` (a :class:`~ctfit.FitResult`) to ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mat = result.material
    band = data.n_bands // 2
    labels = data.band_labels
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5), constrained_layout=True)

    ax = axes[0]
    incidences, counts = np.unique(data.theta_i, return_counts=True)
    chosen = incidences[np.argsort(-counts)][:4]
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for c, ti in zip(colours, sorted(chosen)):
        x, y = _in_plane(data, ti, band)
        line = np.linspace(-89.5, 89.5, 721)
        n = len(line)
        probe = Measurement(
            theta_i=np.full(n, ti), phi_i=np.zeros(n), theta_o=np.abs(line), phi_o=np.where(line >= 0, 180.0, 0.0),
            band=np.full(n, band), wavelength_nm=data.wavelength_nm, channels=data.channels,
        )
        ax.plot(line, evaluate(mat, probe), color=c, lw=1.2, label=f"model, θ_i = {ti:.3g}°")
        if len(x):
            ax.plot(x, y, "o", ms=3, color=c, alpha=0.7, label="data (in plane ±2.5°)")
    ax.set_yscale("log")
    ax.set_xlabel("θ_o in the plane of incidence (°; > 0 towards the mirror side)")
    ax.set_ylabel(f"BRDF (sr⁻¹), band {labels[band]}")
    ax.set_title("slices through the specular peak")
    ax.legend(fontsize=7)

    ax = axes[1]
    model = evaluate(mat, data)
    if data.n_bands == 1:
        from ._diagnostics import _angle_lv

        floor = result.stats.get("relative_floor", 1e-3 * float(np.max(data.brdf)))
        rel = (model - data.brdf) / np.maximum(np.abs(data.brdf), floor)
        ax.plot(_angle_lv(data), rel, ".", ms=2, alpha=0.5)
        ax.axhline(0, color="k", lw=0.8)
        ax.set_xlabel("angle between L and V (°)")
        ax.set_ylabel("(model − data) / max(data, floor)")
        ax.set_title("relative residuals")
        _fresnel_panel(axes[2], result, mat)
        _finish(fig, result, data, path)
        return
    pairs, index = data.directions()
    mirror_dist = np.hypot(pairs[:, 0] - pairs[:, 2], np.abs(np.mod(pairs[:, 3] - pairs[:, 1], 360.0) - 180.0) * np.sin(np.deg2rad(pairs[:, 2])))
    picks = [int(np.argmin(mirror_dist)), int(np.argsort(mirror_dist)[len(mirror_dist) // 2])]
    xs = data.wavelength_nm if data.channels is None else np.arange(data.n_bands)
    for c, pk, what in zip(colours, picks, ("nearest the mirror direction", "median distance from it")):
        rows = np.flatnonzero(index == pk)
        rows = rows[np.argsort(data.band[rows])]
        ti, pi_, to, po = pairs[pk]
        ax.plot(xs[data.band[rows]], data.brdf[rows], "o", color=c, ms=4, label=f"data {what}")
        ax.plot(xs[data.band[rows]], model[rows], "-x", color=c, label=f"model (θ_i {ti:.3g}°, θ_o {to:.3g}°, Δφ {np.mod(po - pi_, 360):.3g}°)")
    ax.set_xlabel("wavelength (nm)" if data.channels is None else "channel")
    if data.channels is not None:
        ax.set_xticks(xs, labels)
    ax.set_ylabel("BRDF (sr⁻¹)")
    ax.set_title("spectra")
    ax.legend(fontsize=7)

    _fresnel_panel(axes[2], result, mat)
    _finish(fig, result, data, path)


def _fresnel_panel(ax, result, mat) -> None:
    if mat.structure.needs_fresnel_params:
        f0 = np.asarray(normal_reflectance(mat.structure, mat.params))
        se = (result.stderr or {}).get("F0")
        xb = mat.wavelength_nm if mat.channels is None else np.arange(len(f0))
        if len(f0) == 1:
            ax.errorbar(xb, f0, yerr=None if se is None else se, fmt="o", capsize=4, label="fitted F0 ± 1 standard error")
        else:
            ax.plot(xb, f0, "-o", ms=3, label="fitted F0")
            if se is not None:
                ax.fill_between(xb, f0 - se, f0 + se, alpha=0.3, label="± 1 standard error")
        ax.set_ylim(0, 1)
        ax.legend(fontsize=8)
        if mat.channels is not None:
            ax.set_xticks(xb, list(mat.channels))
    else:
        ax.text(0.5, 0.5, "no Fresnel parameters (diffuse only)", ha="center", va="center", transform=ax.transAxes)
    ax.set_title("normal reflectance F0")
    ax.set_xlabel("wavelength (nm)" if mat.channels is None else "channel")


def _finish(fig, result, data, path) -> None:
    import matplotlib.pyplot as plt

    s = result.stats
    title = f"{data.source}: rel. RMS error {s['rel_rmse']:.3g}, loss {s['loss']}, converged {s['converged']}"
    if result.warnings:
        title += "\n" + "; ".join(w.split(" — ")[0] for w in result.warnings[:2])
    fig.suptitle(title, fontsize=9)
    fig.savefig(path, dpi=110)
    plt.close(fig)
