"""Pictures of fit quality as BRDF Explorer and ALTA show them: polar plots per incidence angle, a
residual map over the Rusinkiewicz angles (θ_h, θ_d).

- :func:`plot_polar`: for a few incidence angles θ_i (the data's own, or bins of them when the
  data has many), the BRDF on a log radius against θ_o in the plane of incidence: the forward
  (mirror) side φ_o = φ_i + 180° on the right, the back (light's) side φ_o = φ_i on the left.
  Measured samples within ``plane_tol_deg`` of the plane (the angle between V and the plane,
  arcsin(sin θ_o |sin Δφ|)) are points; the model, evaluated densely with
  :func:`ctfit.evaluate_at`, is a line. RGB data shows R, G, B; spectral data three bands
  (nearest 450, 550, 650 nm) unless ``bands`` says otherwise. 1-D data (every sample has V = L,
  an ALTA ``COS_TH`` file) is one panel: the back-scatter curve against θ_i.
- :func:`plot_residual_map`: ln(model/data) of every sample, averaged per (θ_h, θ_d) cell
  (Rusinkiewicz 1998, :func:`ctfit.angles_deg_to_half_diff_deg`), on a diverging colour map
  centred at 0; cells without samples are left blank (grey).

Both take a :class:`~ctfit.Material` or a :class:`~ctfit.FitResult` and use only the public
evaluation (:func:`ctfit.evaluate`, :func:`ctfit.evaluate_at`), so they work for any model
structure. ``draw_polar`` and ``draw_residual_map`` draw into a given matplotlib figure or
subfigure (``ctfit fit --plot`` puts both under the data-vs-fit panels).
"""

from __future__ import annotations

import os
import textwrap
from collections.abc import Sequence
from typing import Any

import numpy as np
from jaxtyping import ArrayLike, Float

from .._io import angles_deg_to_half_diff_deg
from .._model import Material, Measurement, evaluate, evaluate_at
from .least_squares import FitResult

__all__ = ["plot_polar", "plot_residual_map", "draw_polar", "draw_residual_map", "residual_cells", "PLANE_TOL_DEG"]

PLANE_TOL_DEG = 5.0
_MAX_OWN_INCIDENCES = 10  # more distinct θ_i than this: binned
_DECADES = 6.0  # the radius shows at most this many decades below the top
_RGB_COLOURS = {"R": "tab:red", "G": "tab:green", "B": "tab:blue"}
_COLOURS = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple"]


def _material(material_or_result: Material | FitResult) -> Material:
    return getattr(material_or_result, "material", material_or_result)


def _new_figure(size: tuple[float, float]) -> Any:
    from .._runtime import need

    need("plots", "a plot of a fit")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Any, path: str | os.PathLike[str] | None) -> None:
    if path is not None:
        from .._io import atomic_save, plot_metadata

        atomic_save(path, lambda buffer: fig.savefig(buffer, format="png", dpi=110, metadata=plot_metadata("png")))


def _needs_brdf(data: Measurement) -> None:
    if data.brdf is None:
        raise ValueError(f"{data.source}: the measurement has no BRDF values to plot")


def _shown_bands(data: Measurement, bands: Sequence[int] | None) -> list[int]:
    if bands is not None:
        chosen = [int(b) for b in np.atleast_1d(bands)]
        bad = [b for b in chosen if not 0 <= b < data.n_bands]
        if bad:
            raise ValueError(f"bands {bad} out of range: {data.source} has {data.n_bands} band(s)")
        return chosen
    if data.n_bands <= 3:
        return list(range(data.n_bands))
    wl = np.asarray(data.wavelength_nm, dtype=float)
    return sorted({int(np.argmin(np.abs(wl - target))) for target in (450.0, 550.0, 650.0)})


def _band_colour(data: Measurement, b: int, k: int) -> str:
    if data.channels is not None:
        return _RGB_COLOURS.get(data.channels[b], _COLOURS[k % len(_COLOURS)])
    return _COLOURS[k % len(_COLOURS)]


def _model_in_bands(
    material: Material, data: Measurement, theta_i: ArrayLike, theta_o: ArrayLike, phi_o: ArrayLike, bands: Sequence[int]
) -> np.ndarray:
    """The model at the directions (φ_i = 0) in the data's ``bands``, shape (n, len(bands))."""
    if (data.channels is None) != (material.channels is None) or (data.channels is not None and not set(data.channels) <= set(material.channels)):
        raise ValueError(f"{data.source}: bands {data.band_labels} cannot be shown with material {material.name!r} (bands {material.band_labels})")
    if data.channels is not None:
        values = evaluate_at(material, theta_i=theta_i, theta_o=theta_o, phi_o=phi_o)
        return values[..., [list(material.channels).index(data.channels[b]) for b in bands]]
    if data.band_unknown or material.wavelength_nm is None:
        return evaluate_at(material, theta_i=theta_i, theta_o=theta_o, phi_o=phi_o)[..., [0] * len(bands)]
    wl = np.asarray(data.wavelength_nm, dtype=float)[bands]
    return evaluate_at(material, theta_i=theta_i, theta_o=theta_o, phi_o=phi_o, wavelength_nm=wl)


def in_plane_angle(data: Measurement, tol_deg: float = PLANE_TOL_DEG) -> np.ndarray:
    """Each sample's θ_o signed within the plane of incidence (degrees): + forward (mirror side,
    φ_o = φ_i + 180°), − back (light's side); NaN where V is more than ``tol_deg`` from the plane."""
    to = np.asarray(data.theta_o, dtype=float)
    dphi = np.radians(np.asarray(data.phi_o, dtype=float) - np.asarray(data.phi_i, dtype=float))
    off = np.degrees(np.arcsin(np.clip(np.sin(np.radians(to)) * np.abs(np.sin(dphi)), 0.0, 1.0)))
    return np.where(off <= tol_deg, np.where(np.cos(dphi) < 0, to, -to), np.nan)


def _is_v_equals_l(data: Measurement) -> bool:
    same = (data.theta_i == data.theta_o) & ((np.mod(data.phi_o - data.phi_i, 360.0) == 0) | (data.theta_o == 0))
    return data.meta.get("alta_param_in") == "COS_TH" or (len(data) > 1 and bool(same.all()))


def incidence_groups(
    data: Measurement, in_plane: np.ndarray, incidence: ArrayLike | None = None, max_panels: int = 4
) -> list[tuple[str, float | None, np.ndarray]]:
    """``[(label, θ_i of the model curve, sample selection)]``, at most ``max_panels``.

    ``incidence``: θ_i values (degrees) to show, samples within 1° of each. Otherwise the data's
    own θ_i when it has at most 10 distinct ones (spread over their range), else
    ``max_panels`` bins of equal in-plane counts, the model at each bin's median θ_i."""
    ti = np.asarray(data.theta_i, dtype=float)
    ok = np.isfinite(in_plane)
    if incidence is not None:
        return [(f"θ_i = {t:.3g}°", float(t), ok & (np.abs(ti - t) <= 1.0)) for t in np.atleast_1d(incidence)]
    own, counts = np.unique(np.round(ti[ok], 6), return_counts=True)
    if len(own) == 0:
        return []
    if len(own) <= _MAX_OWN_INCIDENCES:
        enough = own[counts >= min(5, counts.max())]  # spread over the range, among θ_i with a few samples
        chosen = enough[np.unique(np.round(np.linspace(0, len(enough) - 1, min(max_panels, len(enough)))).astype(int))]
        return [(f"θ_i = {t:.3g}°", float(t), ok & (np.abs(ti - t) <= 1e-6)) for t in chosen]
    edges = np.unique(np.quantile(ti[ok], np.linspace(0, 1, max_panels + 1)))
    groups: list[tuple[str, float | None, np.ndarray]] = []
    for k, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
        sel = ok & (ti >= lo) & ((ti < hi) | ((k == len(edges) - 2) & (ti <= hi)))
        mid = float(np.median(ti[sel]))
        groups.append((f"θ_i {lo:.3g}–{hi:.3g}° (model at {mid:.3g}°)", mid, sel))
    return groups


def _polar_groups(
    data: Measurement, incidence: ArrayLike | None, plane_tol_deg: float, max_panels: int
) -> tuple[np.ndarray, list[tuple[str, float | None, np.ndarray]]]:
    """``(signed in-plane θ_o per sample, groups)`` (see :func:`incidence_groups`); 1-D data
    (V = L) is one group along the back side, with no model θ_i (the model follows V = L)."""
    if _is_v_equals_l(data):
        return -np.asarray(data.theta_i, dtype=float), [("V = L (1-D data): back-scatter against θ_i", None, np.ones(len(data), bool))]
    x = in_plane_angle(data, plane_tol_deg)
    groups = incidence_groups(data, x, incidence, max_panels)
    if not groups:
        raise ValueError(f"{data.source}: no sample lies within {plane_tol_deg:g}° of the plane of incidence; give a larger plane_tol_deg")
    return x, groups


def _radius_limits(data_values: Sequence[np.ndarray], model_values: Sequence[np.ndarray]) -> tuple[float, float]:
    d = np.concatenate([np.ravel(v) for v in data_values]) if data_values else np.zeros(0)
    m = np.concatenate([np.ravel(v) for v in model_values])
    d, m = d[np.isfinite(d) & (d > 0)], m[np.isfinite(m) & (m > 0)]
    pool = d if len(d) else m
    if not len(pool):
        return 1e-3, 1.0
    hi = max(float(pool.max()), float(m.max()) if len(m) else 0.0)
    lo = max(float(np.quantile(pool, 0.005)), hi * 10.0**-_DECADES)
    return lo / 1.5, hi * 1.5


def draw_polar(container: Any, material: Material | FitResult, data: Measurement, *, incidence: ArrayLike | None = None,
               bands: Sequence[int] | None = None, plane_tol_deg: float = PLANE_TOL_DEG, max_panels: int = 4,
               columns: int | None = None) -> list[Any]:
    """Draw the polar panels (module docstring) into ``container``, a matplotlib Figure or
    SubFigure, ``columns`` per row (default: all in one row); returns the list of axes, one per
    incidence angle (or bin)."""
    material = _material(material)
    _needs_brdf(data)
    shown = _shown_bands(data, bands)
    x_all, groups = _polar_groups(data, incidence, plane_tol_deg, max_panels)
    cols = min(columns or len(groups), len(groups))
    grid = container.subplots(-(-len(groups) // cols), cols, subplot_kw={"projection": "polar"}, squeeze=False).ravel()
    for extra in grid[len(groups):]:
        extra.remove()
    axes = grid[: len(groups)]
    line = np.linspace(-89.5, 89.5, 359)
    drawn = []
    for ax, (title, t_model, sel) in zip(axes, groups):
        xs = line if t_model is not None else line[line <= 0]
        ti = t_model if t_model is not None else np.abs(xs)
        curve = _model_in_bands(material, data, ti, np.abs(xs), np.where(xs > 0, 180.0, 0.0), shown)
        points = [sel & (data.band == b) for b in shown]
        drawn.append((ax, title, t_model, xs, curve, points))
    lo, hi = _radius_limits([data.brdf[p] for *_, ps in drawn for p in ps], [d[4] for d in drawn])
    for ax, title, t_model, xs, curve, points in drawn:
        hidden = 0
        for k, (b, p) in enumerate(zip(shown, points)):
            colour, name = _band_colour(data, b, k), _band_suffix(data, b)
            line_colour = "k" if len(shown) == 1 else colour
            ax.plot(np.radians(xs), np.where(curve[:, k] >= lo, curve[:, k], np.nan), color=line_colour, lw=1.4, zorder=3, label=f"model{name}")
            keep = p & (data.brdf >= lo) & (data.brdf <= hi)
            hidden += int(np.count_nonzero(p & ~keep))
            ax.plot(np.radians(x_all[keep]), data.brdf[keep], "o", ms=3, alpha=0.6, mec="none", color=colour, label=f"data{name}")
        if t_model is not None:
            ax.plot(np.radians([t_model, t_model]), [lo, hi], "--", color="0.4", lw=0.9, label="mirror direction (θ_o = θ_i, forward)")
            ax.plot([np.radians(-t_model)], [hi], marker="v", ms=8, color="gold", mec="k", clip_on=False, label="light (θ_i, back side)")
        n = int(sum(np.count_nonzero(p) for p in points))
        note = f"\n({hidden} point{'s' * (hidden != 1)} outside the radius range)" if hidden else ""
        _polar_style(ax, f"{title}: {n} in-plane sample{'s' * (n != 1)}{note}", lo, hi)
    handles, names = axes[0].get_legend_handles_labels()
    ncols = len(shown) + (len(names) > 2 * len(shown))  # a column per band (model, data), one for the markers
    container.legend(handles, names, loc="outside lower center", ncols=ncols, fontsize=8, frameon=False)
    return list(axes)


def _band_suffix(data: Measurement, b: int) -> str:
    label = data.band_labels[b]
    return "" if label == "unknown band" else f" {label}"


def _polar_style(ax: Any, title: str, lo: float, hi: float) -> None:
    ax.set_theta_zero_location("N")
    ax.set_theta_direction(-1)  # + (forward, mirror side) on the right
    ax.set_thetamin(-90)
    ax.set_thetamax(90)
    ax.set_rscale("log")
    ax.set_rlim(lo, hi)
    ax.set_xticks(np.radians(np.arange(-90, 91, 30)), [f"{abs(a)}°" for a in range(-90, 91, 30)])
    ax.tick_params(which="both", labelsize=7)
    ax.set_xlabel("θ_o:  ← back side | forward side →", fontsize=8, labelpad=-25)
    ax.set_ylabel("BRDF (sr⁻¹), log", fontsize=8, labelpad=22)
    ax.set_title(title, fontsize=9)


def plot_polar(
    material: Material | FitResult, data: Measurement, path: str | os.PathLike[str] | None = None, *, incidence: Float[ArrayLike, "*angles"] | None = None,
    bands: Sequence[int] | None = None, plane_tol_deg: float = PLANE_TOL_DEG, max_panels: int = 4,
) -> Any:
    """Polar plots of data and model per incidence angle (module docstring): a matplotlib Figure.

    ``material``: a Material or FitResult. ``incidence``: θ_i values to show (default: the
    data's own, or bins); ``bands``: band indices (default: all of RGB or single-band data,
    three of spectral data); ``plane_tol_deg``: how far from the plane of incidence a sample
    may lie to be shown. Writes a PNG to ``path`` when given.

    >>> import ctfit
    >>> gloss = ctfit.material_from_dict({"s": 0.6, "d": 0.4, "lobes": [{"m": 0.25}], "channels": ["R", "G", "B"],
    ...                                   "F0": [0.9, 0.6, 0.3], "Rd": [0.2, 0.1, 0.05]})
    >>> fig = ctfit.plot_polar(gloss, ctfit.simulate(gloss, 400, seed=1), "polar.png")
    >>> len(fig.axes), fig.axes[0].name  # one polar panel per incidence angle of the data
    (4, 'polar')
    """
    _needs_brdf(data)
    n_panels = 1 if _is_v_equals_l(data) else len(incidence_groups(data, in_plane_angle(data, plane_tol_deg), incidence, max_panels))
    fig = _new_figure((max(4.4 * n_panels, 7.0), 3.9))
    axes = draw_polar(fig, material, data, incidence=incidence, bands=bands, plane_tol_deg=plane_tol_deg, max_panels=max_panels)
    what = "1-D data" if len(axes) == 1 and _is_v_equals_l(data) else f"points: samples within ±{plane_tol_deg:g}° of the plane of incidence"
    title = f"{data.source}: BRDF in the plane of incidence (log radius; back side φ_o = φ_i, forward side φ_o = φ_i + 180°); {what}; lines: model"
    fig.suptitle(textwrap.fill(title, int(14 * fig.get_figwidth())), fontsize=10)
    _save(fig, path)
    return fig


def residual_cells(
    material: Material | FitResult, data: Measurement, bins: int = 30, band: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """``(θ_h edges, θ_d edges, mean ln(model/data) per cell (n_h, n_d), samples per cell, left out)``.

    Every sample (of ``band`` only, if given) with data > 0 and model > 0 counts once; cells
    span 0–90° in ``bins`` equal steps of θ_h and of θ_d; empty cells are NaN. ``left out``:
    the number of samples with data or model ≤ 0 (no logarithm)."""
    _needs_brdf(data)
    material = _material(material)
    model = np.asarray(evaluate(material, data), dtype=float)
    measured = np.asarray(data.brdf, dtype=float)
    pairs, index = data.directions()
    th, td, _ = angles_deg_to_half_diff_deg(*pairs.T)
    th, td = th[index], td[index]
    use = np.ones(len(data), bool) if band is None else np.asarray(data.band) == int(band)
    ok = use & np.isfinite(model) & np.isfinite(measured) & (model > 0) & (measured > 0)
    from scipy.stats import binned_statistic_2d

    edges = np.linspace(0.0, 90.0, int(bins) + 1)
    th_ok, td_ok, r = np.clip(th[ok], 0.0, 90.0), np.clip(td[ok], 0.0, 90.0), np.log(model[ok] / measured[ok])
    mean = binned_statistic_2d(th_ok, td_ok, r, "mean", bins=[edges, edges]).statistic
    counts = binned_statistic_2d(th_ok, td_ok, r, "count", bins=[edges, edges]).statistic
    return edges, edges, mean, counts.astype(int), int(np.count_nonzero(use & ~ok))


def draw_residual_map(container: Any, material: Material | FitResult, data: Measurement, *, bins: int = 30, band: int | None = None) -> Any:
    """Draw the residual map (module docstring) into ``container`` (Figure or SubFigure); returns its axes."""
    h_edges, d_edges, mean, counts, left_out = residual_cells(material, data, bins, band)
    ax = container.subplots()
    ax.set_facecolor("0.82")  # cells without samples
    cells = mean[np.isfinite(mean)]
    top = max(float(np.quantile(np.abs(cells), 0.98)) if len(cells) else 0.0, 0.05)
    mesh = ax.pcolormesh(h_edges, d_edges, np.ma.masked_invalid(mean.T), cmap="RdBu_r", vmin=-top, vmax=top)
    bar = container.colorbar(mesh, ax=ax, extend="both")
    bar.set_label("mean ln(model / data) per cell\n(red: model above data; 0.1 ≈ 10 %)")
    ax.set_xlabel("θ_h, half-vector angle from the normal (°)")
    ax.set_ylabel("θ_d, angle between L and H (°)")
    ax.set_xlim(0, 90)
    ax.set_ylim(0, 90)
    which = "all bands" if band is None else f"band {data.band_labels[int(band)]}"
    note = f"; {left_out} sample{'s' * (left_out != 1)} with data or model ≤ 0 left out" if left_out else ""
    ax.set_title(f"log residuals over (θ_h, θ_d), {which}: {int(counts.sum())} samples in {len(cells)} cells"
                 f"\n(grey: no samples{note})", fontsize=9)
    return ax


def plot_residual_map(
    material: Material | FitResult, data: Measurement, path: str | os.PathLike[str] | None = None, *, bins: int = 30, band: int | None = None
) -> Any:
    """ln(model/data) averaged over (θ_h, θ_d) cells (module docstring): a matplotlib Figure.

    ``material``: a Material or FitResult; ``bins``: cells per axis over 0–90°; ``band``: one
    band index (default: all bands pooled). Writes a PNG to ``path`` when given.

    >>> import ctfit
    >>> gloss = ctfit.material_from_dict({"s": 0.6, "d": 0.4, "lobes": [{"m": 0.25}], "channels": ["R", "G", "B"],
    ...                                   "F0": [0.9, 0.6, 0.3], "Rd": [0.2, 0.1, 0.05]})
    >>> data = ctfit.simulate(gloss, 300, seed=1, noise=0.05)
    >>> fig = ctfit.plot_residual_map(gloss, data, "residuals.png")
    >>> [ax.get_xlabel()[:3] for ax in fig.axes]  # the map and its colourbar
    ['θ_h', '']
    """
    fig = _new_figure((6.4, 5.2))
    draw_residual_map(fig, material, data, bins=bins, band=band)
    fig.suptitle(textwrap.fill(f"{data.source}: where the fit misses (Rusinkiewicz half/difference angles)", 80), fontsize=10)
    _save(fig, path)
    return fig
