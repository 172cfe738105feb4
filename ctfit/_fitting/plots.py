"""Plots of a fit against its data: in-plane slices (or BRDF against θ_h), spectra, fitted F0(λ).

``make_fit_figure(result, data)`` builds one figure with three panels; ``plot_fit(result, data,
path)`` writes them as a PNG above the polar plots and the residual map of ``quality_plots``
(:func:`make_fit_quality_figure`). The three panels:

1. In-plane slices: for up to four incidence angles, the data within ±2.5° of the plane of
   incidence against the model evaluated densely along that plane, in one band (the middle
   one). The viewing angle is signed as in ``docs/conventions.md``
   (:func:`signed_in_plane_angle`: + on the light's side, − on the mirror side). 1-D data
   (every sample has V = L, e.g. an ALTA ``COS_TH`` file) is shown as BRDF against θ_h instead.
2. Spectra: data and model across the bands at the sample nearest the mirror direction and at
   one far from it; for single-band or 1-D data, the relative residuals instead (against the
   angle between L and V, or against θ_h).
3. The fitted normal reflectance F0 per band with ±1 standard error where computed.

Readability: the title and the warnings in it are wrapped, legends sit in a strip below their
panel (never on the data), and y-limits come from the 0.5–99.5 % quantiles of the values shown,
widened to the values within that range's width beyond it (on a log axis in decades, at most
six decades below the top), so one stray value cannot stretch an axis; the panel title says
how many data points fall outside. A band of unknown wavelength (single-band ALTA data) is
labelled "unknown band", never with its placeholder wavelength.
"""

from __future__ import annotations

import itertools
import textwrap

import numpy as np

from .._model import Measurement, band_labels, evaluate, normal_reflectance
from .diagnostics import angle_lv_deg, half_angle_deg
from .losses import loss_floor

__all__ = ["make_fit_figure", "make_fit_quality_figure", "plot_fit", "signed_in_plane_angle"]

TITLE_WIDTH = 150  # characters per title line (the figure is 15 inches wide, 9 pt text)
_PLANE_TOL_DEG = 2.5
_LOG_DECADES = 6.0  # a log axis shows at most this many decades below its top
_REACH = 1.0  # values up to this many quantile-range widths beyond the range are still shown


def signed_in_plane_angle(theta_o, phi_o, phi_i, tol_deg: float = _PLANE_TOL_DEG) -> np.ndarray:
    """The viewing angle θ_o signed within the plane of incidence, in degrees.

    +θ_o where the viewer is on the light's side (φ_o = φ_i, within ``tol_deg``), −θ_o on the
    mirror side (φ_o = φ_i + 180°), so the mirror direction of θ_i lies at −θ_i and
    retro-reflection at +θ_i; NaN for viewers out of the plane. θ_o = 0 is in every plane.
    """
    theta_o = np.asarray(theta_o, dtype=float)
    dphi = np.mod(np.asarray(phi_o, dtype=float) - np.asarray(phi_i, dtype=float), 360.0)
    light = (dphi <= tol_deg) | (dphi >= 360.0 - tol_deg) | (theta_o == 0)
    mirror = np.abs(dphi - 180.0) <= tol_deg
    return np.where(light, theta_o, np.where(mirror, -theta_o, np.nan))


def plot_fit(result, data: Measurement, path) -> None:
    """Write the fit-quality figure of ``result`` (a :class:`~ctfit.FitResult`) to ``path`` (PNG), atomically.

    Top: the data-vs-fit panels (:func:`make_fit_figure`); below: polar plots per incidence angle
    and the residual map over (θ_h, θ_d) (:func:`ctfit.plot_polar`, :func:`ctfit.plot_residual_map`).
    """
    from pathlib import Path

    from .._io import atomic_save, plot_metadata

    fig = make_fit_quality_figure(result, data)
    fmt = Path(path).suffix[1:].lower() or "png"
    atomic_save(path, lambda buffer: fig.savefig(buffer, format=fmt, dpi=110, metadata=plot_metadata(fmt)))


def make_fit_quality_figure(result, data: Measurement):
    """The figure ``plot_fit`` writes: the data-vs-fit panels above the polar plots and the residual map."""
    from .._runtime import need

    need("plots", "a plot of a fit")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from .quality_plots import PLANE_TOL_DEG, draw_polar, draw_residual_map

    title = _title(result, data)
    top_height = 5.4 + 0.16 * title.count("\n")
    fig = Figure(figsize=(16, top_height + 7.4), layout="constrained")
    FigureCanvasAgg(fig)
    top, bottom = fig.subfigures(2, 1, height_ratios=[top_height, 7.4])  # type: ignore[misc]  # two: an array
    draw_fit_panels(top, result, data, title)
    polar, residuals = bottom.subfigures(1, 2, width_ratios=[1.6, 1.0])
    try:
        draw_polar(polar, result.material, data, columns=2)
    except ValueError as e:  # e.g. no sample near the plane of incidence: the rest of the figure still helps
        polar.text(0.5, 0.5, textwrap.fill(f"no polar plot: {e}", 80), ha="center", va="center", fontsize=9)
    polar.suptitle(
        "BRDF in the plane of incidence (log radius; back side φ_o = φ_i, forward side φ_o = φ_i + 180°):\n"
        f"points, samples within ±{PLANE_TOL_DEG:g}° of the plane; lines, the model", fontsize=9,
    )
    draw_residual_map(residuals, result.material, data)
    return fig


def make_fit_figure(result, data: Measurement):
    """The data-vs-fit figure (a :class:`matplotlib.figure.Figure`, Agg canvas) of ``result``."""
    from .._runtime import need

    need("plots", "a plot of a fit")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    title = _title(result, data)
    fig = Figure(figsize=(15, 5.4 + 0.16 * title.count("\n")), layout="constrained")
    FigureCanvasAgg(fig)
    draw_fit_panels(fig, result, data, title)
    return fig


def draw_fit_panels(fig, result, data: Measurement, title: str) -> None:
    """The three data-vs-fit panels (module docstring) and ``title``, in a Figure or SubFigure."""
    grid = fig.add_gridspec(2, 3, height_ratios=[4, 1])
    axes = [fig.add_subplot(grid[0, j]) for j in range(3)]
    strips = [fig.add_subplot(grid[1, j]) for j in range(3)]
    mat = result.material
    labels = band_labels(data.wavelength_nm, data.channels, data.band_unknown)
    model = evaluate(mat, data)
    if _is_half_angle_slice(data):
        _half_angle_panel(axes[0], mat, data, labels)
        _residual_panel(axes[1], result, data, model, half_angle_deg(data), "θ_h, angle between N and H (°)", labels)
    else:
        _slices_panel(axes[0], mat, data, labels)
        if data.n_bands == 1:
            _residual_panel(axes[1], result, data, model, angle_lv_deg(data), "angle between L and V (°)", labels)
        else:
            _spectra_panel(axes[1], data, model, labels)
    _fresnel_panel(axes[2], result, mat, data, labels)
    for ax, strip in zip(axes, strips):
        strip.axis("off")
        handles, names = ax.get_legend_handles_labels()
        if handles:
            strip.legend(handles, names, loc="upper center", ncols=2, fontsize=7, frameon=False)
    fig.suptitle(title, fontsize=9)


def _title(result, data) -> str:
    s = result.stats
    head = f"{data.source}: rel. RMS error {s['rel_rmse']:.3g}, loss {s['loss']}, converged {s['converged']}"
    notes = [f"warning: {w}" for w in result.warnings[:3]]
    if len(result.warnings) > 3:
        more = len(result.warnings) - 3
        notes.append(f"… and {more} more warning{'s' * (more != 1)} (see the fit table)")
    return "\n".join(textwrap.fill(t, TITLE_WIDTH, subsequent_indent="  ") for t in [head, *notes])


def _band_unknown(data: Measurement, mat=None) -> bool:
    return bool(getattr(data, "band_unknown", False) or getattr(mat, "band_unknown", False))


def _is_half_angle_slice(data: Measurement) -> bool:
    """1-D data: an ALTA ``COS_TH`` file, or any data whose every sample has V = L."""
    if data.meta.get("alta_param_in") == "COS_TH":
        return True
    same = (data.theta_i == data.theta_o) & ((np.mod(data.phi_o - data.phi_i, 360.0) == 0) | (data.theta_o == 0))
    return len(data) > 1 and bool(same.all())


def _band_name(labels, band) -> str:
    return "" if labels[band] == "unknown band" else f", band {labels[band]}"


def _slices_panel(ax, mat, data, labels) -> None:
    band = data.n_bands // 2
    x_all = signed_in_plane_angle(data.theta_o, data.phi_o, data.phi_i)
    incidences, counts = np.unique(data.theta_i, return_counts=True)
    chosen = sorted(incidences[np.argsort(-counts)][:4])
    line = np.linspace(-89.5, 89.5, 721)
    shown, curves = [], []
    for c, ti in zip(_colours(), chosen):
        sel = (np.abs(data.theta_i - ti) < 1e-6) & (data.band == band) & np.isfinite(x_all)
        order = np.argsort(x_all[sel])
        x, y = x_all[sel][order], data.brdf[sel][order]
        n = len(line)
        probe = Measurement(
            theta_i=np.full(n, ti), phi_i=np.zeros(n), theta_o=np.abs(line), phi_o=np.where(line >= 0, 0.0, 180.0),
            band=np.full(n, band), wavelength_nm=data.wavelength_nm, channels=data.channels, band_unknown=data.band_unknown,
        )
        curve = evaluate(mat, probe)
        ax.plot(line, curve, color=c, lw=1.2, label=f"model, θ_i = {ti:.3g}°")
        if len(x):
            ax.plot(x, y, "o", ms=3, color=c, alpha=0.7, label=f"data, θ_i = {ti:.3g}° (in plane ±{_PLANE_TOL_DEG:g}°)")
        shown.append(y)
        curves.append(curve)
    data_y = np.concatenate(shown) if shown else np.zeros(0)
    note = _log_limits(ax, data_y, np.concatenate(curves) if curves else np.zeros(0))
    ax.set_xlabel("signed θ_o in the plane of incidence (°)\n+: light's side (φ_o = φ_i), −: mirror side (φ_o = φ_i + 180°)")
    ax.set_ylabel(f"BRDF (sr⁻¹){_band_name(labels, band)}")
    ax.set_title("in-plane slices (mirror direction at −θ_i)" + note, fontsize=10)


def _half_angle_panel(ax, mat, data, labels) -> None:
    th = half_angle_deg(data)
    line = np.linspace(0.0, max(float(th.max()), 1.0), 400)
    data_y, curves = [], []
    for b, c in zip(range(data.n_bands), _colours(data)):
        sel = data.band == b
        n = len(line)
        probe = Measurement(
            theta_i=line, phi_i=np.zeros(n), theta_o=line, phi_o=np.zeros(n),
            band=np.full(n, b), wavelength_nm=data.wavelength_nm, channels=data.channels, band_unknown=data.band_unknown,
        )
        curve = evaluate(mat, probe)
        name = "" if labels[b] == "unknown band" else f" {labels[b]}"
        ax.plot(line, curve, color=c, lw=1.2, label=f"model{name}")
        ax.plot(th[sel], data.brdf[sel], "o", ms=3, color=c, alpha=0.7, label=f"data{name}")
        data_y.append(data.brdf[sel])
        curves.append(curve)
    note = _auto_limits(ax, np.concatenate(data_y), np.concatenate(curves))
    ax.set_xlabel("θ_h, angle between N and H (°)")
    ax.set_ylabel("BRDF (sr⁻¹)")
    ax.set_title("BRDF against θ_h (1-D data, V = L)" + note, fontsize=10)


def _auto_limits(ax, data_y, model_y) -> str:
    """A log y-axis when the positive values span more than 30×, else a linear one; the note
    on points outside the shown range."""
    positive = np.concatenate([data_y, model_y])
    positive = positive[positive > 0]
    if len(positive) and positive.max() > 30 * positive.min():
        return _log_limits(ax, data_y, model_y)
    return _linear_limits(ax, data_y, model_y)


def _residual_panel(ax, result, data, model, x, xlabel, labels) -> None:
    floor = result.stats.get("relative_floor", loss_floor(data.brdf, "relative"))
    rel = (model - data.brdf) / np.maximum(np.abs(data.brdf), floor)
    if data.n_bands == 1:
        ax.plot(x, rel, ".", ms=2, alpha=0.5)
    else:
        for b, c in zip(range(data.n_bands), _colours(data)):
            sel = data.band == b
            ax.plot(x[sel], rel[sel], ".", ms=3, alpha=0.7, color=c, label=labels[b])
    ax.axhline(0, color="k", lw=0.8)
    note = _linear_limits(ax, rel, np.zeros(1), include_zero=True)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("(model − data) / max(data, floor)")
    ax.set_title("relative residuals" + note, fontsize=10)


def _spectra_panel(ax, data, model, labels) -> None:
    pairs, index = data.directions()
    mirror_dist = np.hypot(pairs[:, 0] - pairs[:, 2], np.abs(np.mod(pairs[:, 3] - pairs[:, 1], 360.0) - 180.0) * np.sin(np.deg2rad(pairs[:, 2])))
    picks = [int(np.argmin(mirror_dist)), int(np.argsort(mirror_dist)[len(mirror_dist) // 2])]
    xs = data.wavelength_nm if data.channels is None else np.arange(data.n_bands)
    shown = []
    for c, pk, what in zip(_colours(), picks, ("nearest the mirror direction", "median distance from it")):
        rows = np.flatnonzero(index == pk)
        rows = rows[np.argsort(data.band[rows])]
        ti, pi_, to, po = pairs[pk]
        ax.plot(xs[data.band[rows]], data.brdf[rows], "o", color=c, ms=4, label=f"data {what}")
        ax.plot(xs[data.band[rows]], model[rows], "-x", color=c, label=f"model (θ_i {ti:.3g}°, θ_o {to:.3g}°, Δφ {np.mod(po - pi_, 360):.3g}°)")
        shown.append((data.brdf[rows], model[rows]))
    note = _auto_limits(ax, np.concatenate([d for d, _ in shown]), np.concatenate([m for _, m in shown]))
    ax.set_xlabel("wavelength (nm)" if data.channels is None else "channel")
    if data.channels is not None:
        ax.set_xticks(xs, labels)
    ax.set_ylabel("BRDF (sr⁻¹)")
    ax.set_title("spectra at two directions" + note, fontsize=10)


def _fresnel_panel(ax, result, mat, data, labels) -> None:
    if mat.structure.needs_fresnel_params:
        f0 = np.asarray(normal_reflectance(mat.structure, mat.params))
        se = (result.stderr or {}).get("F0")
        by_index = mat.channels is not None or _band_unknown(data, mat)
        xb = np.arange(len(f0)) if by_index else mat.wavelength_nm
        if len(f0) == 1:
            ax.errorbar(xb, f0, yerr=None if se is None else se, fmt="o", capsize=4, label="fitted F0 ± 1 standard error")
        else:
            ax.plot(xb, f0, "-o", ms=3, label="fitted F0")
            if se is not None:
                ax.fill_between(xb, f0 - se, f0 + se, alpha=0.3, label="± 1 standard error")
        ax.set_ylim(0, 1)
        if mat.channels is not None:
            ax.set_xticks(xb, list(mat.channels))
        elif by_index:
            ax.set_xticks(xb, labels[: len(f0)])
    else:
        ax.text(0.5, 0.5, "no Fresnel parameters (diffuse only)", ha="center", va="center", transform=ax.transAxes)
    ax.set_title("normal reflectance F0", fontsize=10)
    ax.set_xlabel("channel" if mat.channels is not None else ("band" if _band_unknown(data, mat) else "wavelength (nm)"))


def _colours(data: Measurement | None = None):
    if data is not None and data.channels is not None and tuple(data.channels) == ("R", "G", "B"):
        return iter(["tab:red", "tab:green", "tab:blue"])
    return itertools.cycle(["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown"])


def _outside_note(data_y, lo, hi) -> str:
    data_y = np.asarray(data_y, dtype=float)
    below, above = int(np.count_nonzero(data_y < lo)), int(np.count_nonzero(data_y > hi))
    parts = [f"{k} data point{'s' * (k != 1)} {where} the shown range" for k, where in ((below, "below"), (above, "above")) if k]
    return "\n(" + "; ".join(parts) + ")" if parts else ""


def _robust_range(values: np.ndarray) -> tuple[float, float]:
    """The 0.5–99.5 % quantile range, widened to the extreme values that lie within its width
    beyond it: a detached outlier is left out, the steep ends of a curve are not. (The quantiles
    are sample values taken inwards, so that with few samples one outlier is never one of them.)"""
    q_lo, q_hi = sorted((np.quantile(values, 0.005, method="higher"), np.quantile(values, 0.995, method="lower")))
    reach = _REACH * (q_hi - q_lo)
    inner = values[(values >= q_lo - reach) & (values <= q_hi + reach)]
    return float(inner.min()), float(inner.max())


def _log_limits(ax, data_y, model_y) -> str:
    """Log y-axis over the robust range (:func:`_robust_range`, in log10) of the positive data (the
    model's where there is no data), its top raised to the model's maximum, at most
    ``_LOG_DECADES`` decades deep; returns a note on the data left outside."""
    ax.set_yscale("log")
    d = np.asarray(data_y, dtype=float)
    d = d[np.isfinite(d) & (d > 0)]
    m = np.asarray(model_y, dtype=float)
    m = m[np.isfinite(m) & (m > 0)]
    pool = d if len(d) else m
    if not len(pool):
        return ""
    lo, hi = (10.0**v for v in _robust_range(np.log10(pool)))
    if len(m):
        hi = max(hi, float(m.max()))
    lo = max(lo, hi * 10.0**-_LOG_DECADES)
    pad = 10.0 ** (0.05 * max(np.log10(hi / lo), 0.5))
    lo, hi = lo / pad, hi * pad
    ax.set_ylim(lo, hi)
    note = _outside_note(d, lo, hi)
    zeros = int(np.count_nonzero(np.asarray(data_y) <= 0))
    if zeros:
        note = (note[:-1] + "; " if note else "\n(") + f"{zeros} data values ≤ 0 not shown)"
    return note


def _linear_limits(ax, data_y, model_y, include_zero: bool = False) -> str:
    """Linear y-axis over the robust range (:func:`_robust_range`) of the data and model values
    (and 0 with ``include_zero``); returns a note on the data left outside."""
    d = np.asarray(data_y, dtype=float)
    pool = np.concatenate([d, np.asarray(model_y, dtype=float)])
    pool = pool[np.isfinite(pool)]
    if not len(pool):
        return ""
    lo, hi = _robust_range(pool)
    if include_zero:
        lo, hi = min(lo, 0.0), max(hi, 0.0)
    pad = 0.05 * (hi - lo) if hi > lo else max(abs(hi), 1.0) * 0.05
    lo, hi = lo - pad, hi + pad
    ax.set_ylim(lo, hi)
    return _outside_note(d, lo, hi)
