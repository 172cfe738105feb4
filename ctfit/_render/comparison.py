"""Measured | fitted | ΔE2000: a fit beside a smooth rendering of its measurement (``ctfit render --compare DATA --delta-e``).

Both spheres are lit by the renderer's two lights (:data:`ctfit.LIGHT_DIRECTIONS`), with no
ambient term (the data gives no hemispherical reflectance), seen from :data:`ctfit.VIEW_DIRECTION`.
For every pixel and light the local (θ_i, θ_o, Δφ) is computed once; the fitted sphere takes
the model there (:func:`ctfit.evaluate_at`), the measured sphere the measurement *interpolated*
there (:class:`MeasuredBRDF`): in log BRDF over the Rusinkiewicz angles (θ_h, θ_d, φ_d), φ_d
folded to [0°, 90°] (isotropy and reciprocity), by a local linear regression on the 16 nearest
samples (a SciPy k-d tree) with modified Shepard weights, which reach 0 before a sample leaves
the neighbourhood: the result is continuous, exact at the samples and for linear functions.
So the measured sphere is smooth, never faceted by nearest samples. (SciPy's
``LinearNDInterpolator`` was the first choice; its simplex search on the triangulation of
goniometer grids takes tens of milliseconds per pixel.) Pixels outside the convex hull of the
measured directions (in those coordinates) are outside the measured domain: they are shown
grey and left out of the ΔE statistics.

The colour difference is CIEDE2000 (:func:`ctfit.delta_E_CIE2000`) between the two linear
sRGB pixels, both scaled by the fitted sphere's exposure (the paper's scale, see
:func:`ctfit.tone_map`), taken to XYZ and CIELAB with the display white (RGB 1, 1, 1) as white.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt
from jaxtyping import ArrayLike, Float

from .._colour import RGB_to_XYZ, XYZ_to_Lab, delta_E_CIE2000, rgb_conversion
from .._io import angles_deg_to_half_diff_deg, shorten
from .._model import Light, Material, Measurement, evaluate_at
from .measured import check_colour_bands
from .scene import LIGHT_DIRECTIONS, SOLID_ANGLES, Scene, Tile, render_bands, scene_lights, white_scale
from .surfaces import VIEW_DIRECTION, surface_normals
from .tone import tone_map

__all__ = ["MeasuredBRDF", "Comparison", "coverage_text", "half_diff_folded_deg", "render_comparison"]

def coverage_text(fraction: float) -> str:
    """A share as a percentage that reads 100 % only when it is all (0.99863 printed "100%" over a
    sphere with grey, unmeasured pixels), and 0 % only when it is none.

    >>> coverage_text(0.99863), coverage_text(1.0), coverage_text(0.5), coverage_text(0.0004)
    ('99.9 %', '100 %', '50 %', '0.04 %')
    """
    for digits in range(0, 6):
        text = f"{100 * fraction:.{digits}f}"
        if (float(text) < 100 or fraction >= 1) and (float(text) > 0 or fraction <= 0):
            return f"{text} %"
    return f"{100 * fraction:.6g} %"


MAX_POINTS = 100_000  # direction pairs interpolated from at most (a fixed random subset beyond)
OUTSIDE_GREY = 140  # uint8 grey of sphere pixels outside the measured domain
_LOG_FLOOR = 1e-6  # values below this fraction of the band's 99th percentile are interpolated as this fraction
_FLOOR_QUANTILE = 0.99  # (not the maximum: one exact grazing value, 10⁵ sr⁻¹, floored every other value and greyed the sphere)
_AXES = ("θ_h", "θ_d", "φ_d")
NEIGHBOURS = 16  # samples that shape each interpolated value (in 2 or 3 dimensions)


def half_diff_folded_deg(
    theta_i: Float[ArrayLike, "*#batch"], phi_i: Float[ArrayLike, "*#batch"], theta_o: Float[ArrayLike, "*#batch"],
    phi_o: Float[ArrayLike, "*#batch"],
) -> Float[np.ndarray, "*batch 3"]:
    """Rusinkiewicz (θ_h, θ_d, φ_d) in degrees, shape (..., 3), φ_d folded to [0°, 90°].

    Isotropy makes the BRDF even in φ_d, reciprocity (swapping L and V) turns φ_d into φ_d + 180°.

    >>> half_diff_folded_deg(40.0, 0.0, 20.0, 180.0).round(6).tolist()  # H at 10°, 30° from L and V
    [10.0, 30.0, 0.0]
    """
    th, td, pd = angles_deg_to_half_diff_deg(theta_i, phi_i, theta_o, phi_o)
    pd = np.mod(np.abs(pd), 180.0)
    return np.stack(np.broadcast_arrays(th, td, np.minimum(pd, 180.0 - pd)), axis=-1)


def _band_groups(data: Measurement) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``[(bands, pairs (D, 4), values (D, len(bands)))]``: one group for grid data, else one per band."""
    if data.brdf is None:
        raise ValueError(f"{data.source}: the measurement has no BRDF values to show")
    values = np.asarray(data.brdf, dtype=float)
    grid = data.grid()
    if grid is not None:
        pairs, order = grid
        return [(np.arange(data.n_bands), np.asarray(pairs), values[order].reshape(len(pairs), data.n_bands))]
    groups = []
    for b in range(data.n_bands):
        idx = np.flatnonzero(data.band == b)
        if len(idx) == 0:
            raise ValueError(f"{data.source}: band {data.band_labels[b]} has no samples")
        pairs = np.stack([data.theta_i[idx], data.phi_i[idx], data.theta_o[idx], data.phi_o[idx]], axis=1)
        groups.append((np.array([b]), pairs, values[idx][:, None]))
    return groups


def _mean_of_repeats(points: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    keys, inverse = np.unique(np.round(points, 9), axis=0, return_inverse=True)
    inverse = inverse.ravel()
    counts = np.bincount(inverse, minlength=len(keys))
    sums = np.stack([np.bincount(inverse, weights=v, minlength=len(keys)) for v in values.T], axis=1)
    return keys, sums / counts[:, None]


class MeasuredBRDF:
    """A measurement as a function of direction: log BRDF interpolated over (θ_h, θ_d, φ_d) (module docstring).

    ``MeasuredBRDF(data)(theta_i, theta_o, dphi)`` (degrees, arrays of one shape) gives the
    BRDF in every band, shape ``(..., n_bands)``, NaN outside the measured domain (the convex
    hull of the measured directions; the range of 1-D data, which is interpolated linearly).
    Coordinates that do not vary in the data are dropped (in-plane data: φ_d; 1-D
    ``COS_TH`` data: θ_d and φ_d), so the BRDF is taken not to depend on them; :attr:`note`
    says so. Repeated direction pairs are averaged; beyond :data:`MAX_POINTS` pairs a fixed
    random subset is used. Values below 10⁻⁶ of the maximum are interpolated as that floor.

    >>> import numpy as np, ctfit
    >>> matte = ctfit.material_from_dict({"s": 0, "d": 1, "channels": ["R", "G", "B"], "Rd": [0.2, 0.1, 0.05]})
    >>> f = MeasuredBRDF(ctfit.simulate(matte, 400, seed=1))
    >>> f(np.array([30.0]), np.array([40.0]), np.array([120.0])).round(6).tolist()  # a constant BRDF, in R, G, B
    [[0.2, 0.1, 0.05]]
    """

    def __init__(self, data: Measurement, max_points: int = MAX_POINTS) -> None:
        self.n_bands = data.n_bands
        self.parts = []
        kept = set()
        for bands, pairs, values in _band_groups(data):
            floor = _LOG_FLOOR * max(float(np.quantile(values, _FLOOR_QUANTILE)), np.finfo(float).tiny)
            points, logs = _mean_of_repeats(half_diff_folded_deg(*pairs.T), np.log(np.maximum(values, floor)))
            if len(points) > max_points:
                pick = np.sort(np.random.default_rng(0).choice(len(points), max_points, replace=False))
                points, logs = points[pick], logs[pick]
            dims = [j for j in range(3) if np.ptp(points[:, j]) > 1e-6]
            kept.update(dims)
            self.parts.append((bands, dims, _interpolant(points, logs, dims)))
        dropped = [_AXES[j] for j in range(3) if j not in kept]
        self.note = "in log BRDF over (" + ", ".join(_AXES[j] for j in sorted(kept)) + ")"
        self.note += f" by Shepard-weighted local linear regression on {NEIGHBOURS} neighbours" if len(kept) > 1 else " linearly"
        if dropped:
            self.note += f"; {', '.join(dropped)} constant in the data, taken not to matter"

    def __call__(self, theta_i: np.ndarray, theta_o: np.ndarray, dphi: np.ndarray) -> np.ndarray:
        coords = half_diff_folded_deg(theta_i, 0.0, theta_o, dphi)
        out = np.full(coords.shape[:-1] + (self.n_bands,), np.nan)
        for bands, dims, f in self.parts:
            out[..., bands] = np.exp(f(coords[..., dims]))
        return out


def _interpolant(points: np.ndarray, logs: np.ndarray, dims: list[int]) -> Callable[[np.ndarray], np.ndarray]:
    """A function of (..., len(dims)) coordinates giving (..., bands) log values, NaN outside."""
    if not dims:
        return lambda q: np.broadcast_to(logs[0], q.shape[:-1] + logs.shape[1:])
    p, logs = _mirrored(points[:, dims], logs, dims)
    if len(dims) == 1:
        order = np.argsort(p[:, 0])
        x, y = p[order, 0], logs[order]

        def along(q: np.ndarray) -> np.ndarray:
            q = q[..., 0]
            inside = (q >= x[0]) & (q <= x[-1])
            return np.where(inside[..., None], np.stack([np.interp(q, x, c) for c in y.T], axis=-1), np.nan)

        return along
    return _shepard(p, logs)


def _shepard(points: np.ndarray, logs: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """Local linear regression on the :data:`NEIGHBOURS` nearest points (a k-d tree), weighted
    by modified Shepard weights ((R − d)₊ / (R d))², R the distance to the next nearest point
    (Franke & Nielson 1980): a weight falls to 0 before its point leaves the neighbourhood, so the
    result is continuous, exact at the samples and exact for linear functions. NaN outside the
    convex hull of the points (the measured domain)."""
    from scipy.spatial import ConvexHull, QhullError, cKDTree

    tree = cKDTree(points)
    k = min(NEIGHBOURS + 1, len(points))
    try:
        hull = ConvexHull(points).equations
    except QhullError:  # too few points, or all in a lower-dimensional set: no domain test
        hull = None

    def regression(q: np.ndarray) -> np.ndarray:
        d, j = (np.asarray(a) for a in tree.query(q, k=k))  # (len(q), k): k > 1
        far, d, j = d[:, -1:], d[:, :-1], j[:, :-1]
        w = (np.maximum(far - d, 0.0) / (far * np.maximum(d, 1e-9))) ** 2
        w = np.where(w.sum(axis=1, keepdims=True) > 0, w, 1.0)
        w = w / w.max(axis=1, keepdims=True)
        x = (points[j] - q[:, None, :]) / np.maximum(far, 1e-9)[:, :, None]
        x = np.concatenate([np.ones(x.shape[:2] + (1,)), x], axis=-1)
        a = np.einsum("nk,nki,nkj->nij", w, x, x)
        a[:, 1:, 1:] += 1e-3 * w.sum(axis=1)[:, None, None] * np.eye(x.shape[-1] - 1)  # a little ridge: no wild slopes
        b = np.einsum("nk,nki,nkc->nic", w, x, logs[j])
        out = np.linalg.solve(a, b)[:, 0, :]
        if hull is not None:
            out[np.any(q @ hull[:, :-1].T + hull[:, -1] > 1e-6, axis=1)] = np.nan
        return out

    def local_linear(q: np.ndarray) -> np.ndarray:
        flat = q.reshape(-1, q.shape[-1])
        out = np.concatenate([regression(flat[i : i + 4096]) for i in range(0, len(flat), 4096)] or [np.zeros((0, logs.shape[1]))])
        return out.reshape(q.shape[:-1] + (logs.shape[1],))

    return local_linear


def _mirrored(p: np.ndarray, logs: np.ndarray, dims: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """The points with their mirror images across θ_h = 0, θ_d = 0, φ_d = 0° and φ_d = 90° (the
    folded BRDF is even about each), for points within 20° of the edge: so that the convex hull,
    and the interpolation, reach the edges of the domain (the mirror direction, retro-reflection)."""
    for k, j in enumerate(dims):
        for edge in (0.0, 90.0) if j == 2 else (0.0,):
            near = (np.abs(p[:, k] - edge) < 20.0) & (np.abs(p[:, k] - edge) > 1e-6)  # not those on the edge: no duplicates
            image = p[near].copy()
            image[:, k] = 2 * edge - image[:, k]
            p, logs = np.concatenate([p, image]), np.concatenate([logs, logs[near]])
    return p, logs


class Comparison(NamedTuple):
    """What :func:`render_comparison` returns.

    ``figure`` (matplotlib, measured | fitted | ΔE2000); ``delta_e`` (size, size), NaN where
    not compared (off the sphere, unlit, outside the measured domain); ``median`` and ``p95``
    of ``delta_e`` over the compared pixels; ``coverage``, the fraction of lit sphere pixels
    inside the measured domain; ``measured`` and ``fitted``, linear sRGB (size, size, 3) at the
    shown exposure (NaN outside the measured domain); ``note``, how the data was interpolated.
    """

    figure: object
    delta_e: np.ndarray
    median: float
    p95: float
    coverage: float
    measured: np.ndarray
    fitted: np.ndarray
    note: str


def _bands_of(material: Material, data: Measurement) -> tuple[np.ndarray, np.ndarray, Callable[..., np.ndarray]]:
    """``(light spectrum (B,), to_rgb (B, 3), model: f(θ_i, θ_o, Δφ) → (..., B))`` on the data's bands."""
    if data.band_unknown != material.band_unknown:
        unknown, known = (data.source, material.name) if data.band_unknown else (material.name, data.source)
        raise ValueError(f"{unknown}: its band's wavelength is unknown, so it cannot be shown beside {known}, whose bands are known")
    if data.channels is not None:
        if not material.is_rgb or not {"R", "G", "B"} <= set(data.channels) or not {"R", "G", "B"} <= set(material.channels):
            raise ValueError(f"{data.source}: RGB data (channels {list(data.channels)}) needs channels R, G, B and an RGB material")
        _, spectrum, _ = render_bands(material)
        to_rgb = np.zeros((data.n_bands, 3))
        for k, c in enumerate("RGB"):
            to_rgb[list(data.channels).index(c), k] = 1.0
        take = [list(material.channels).index(c) for c in data.channels]
        return np.ones(data.n_bands), to_rgb, lambda ti, to, dp: evaluate_at(material, theta_i=ti, theta_o=to, phi_o=dp)[..., take]
    if material.is_rgb:
        raise ValueError(f"{data.source}: spectral data needs a spectral material; {material.name!r} has RGB channels")
    if data.band_unknown:
        _, spectrum, to_rgb = render_bands(material)
        return spectrum, to_rgb, lambda ti, to, dp: evaluate_at(material, theta_i=ti, theta_o=to, phi_o=dp)
    check_colour_bands(data)
    wl = np.asarray(data.wavelength_nm, dtype=float)
    _, spectrum, to_rgb = render_bands(material, wavelength_nm=wl)
    return spectrum, to_rgb, lambda ti, to, dp: evaluate_at(material, theta_i=ti, theta_o=to, phi_o=dp, wavelength_nm=wl)


def _local_angles_deg(normals: np.ndarray, light: np.ndarray, view: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """θ_i, θ_o, Δφ (degrees) of each normal (P, 3) for one light and the view, and N·L, N·V > 0."""
    cl, cv = normals @ light, normals @ view
    tl, tv = light - cl[:, None] * normals, view - cv[:, None] * normals
    den = np.linalg.norm(tl, axis=-1) * np.linalg.norm(tv, axis=-1)
    ok = den > 1e-12
    cos_dphi = np.where(ok, np.sum(tl * tv, axis=-1) / np.where(ok, den, 1.0), 1.0)
    angle = lambda c: np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))
    return angle(cl), angle(cv), angle(cos_dphi), (cl > 0) & (cv > 0)


def _shade(
    normals: np.ndarray, lights: Sequence[Light], brdf_fn: Callable[..., np.ndarray], n_bands: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(intensity (P, B), lit (P,), missing (P,))``: Σ over lights of E dω cos θ_i f, no ambient.

    ``missing``: a light reaches the sample but ``brdf_fn`` has no value there (NaN)."""
    view = np.asarray(VIEW_DIRECTION, dtype=float)
    intensity = np.zeros((len(normals), n_bands))
    lit = np.zeros(len(normals), bool)
    missing = np.zeros(len(normals), bool)
    for light in lights:
        direction = np.asarray(light.direction, dtype=float)
        ti, to, dphi, valid = _local_angles_deg(normals, direction / np.linalg.norm(direction), view)
        f = np.asarray(brdf_fn(ti[valid], to[valid], dphi[valid]), dtype=float)
        bad = ~np.isfinite(f).all(axis=-1)
        missing[np.flatnonzero(valid)[bad]] = True
        e = np.asarray(light.spectrum, dtype=float) * float(light.solid_angle)
        intensity[valid] += e * np.cos(np.radians(ti[valid]))[:, None] * np.nan_to_num(f)
        lit |= valid
    return intensity, lit, missing


def _per_pixel(samples: np.ndarray, s: int) -> np.ndarray:
    """(n·s, n·s, ...) samples → (n, n, ...) means over each pixel's s × s samples."""
    n = samples.shape[0] // s
    return samples.reshape(n, s, n, s, *samples.shape[2:]).mean(axis=(1, 3))


def _delta_e(measured: np.ndarray, fitted: np.ndarray) -> np.ndarray:
    conv = rgb_conversion("sRGB", None, None)
    white = np.asarray(RGB_to_XYZ(np.ones(3), conv), dtype=float)
    lab = [XYZ_to_Lab(RGB_to_XYZ(np.nan_to_num(x), conv), white) for x in (measured, fitted)]
    return np.asarray(delta_E_CIE2000(*lab), dtype=float)


def render_comparison(
    material: Material, data: Measurement, path: str | os.PathLike[str] | None = None, *, size: int = 128, shape: str = "sphere",
    supersample: int = 2, exposure: str = "reference", directions: Float[npt.ArrayLike, "lights 3"] = LIGHT_DIRECTIONS,
    solid_angles: Float[npt.ArrayLike, " lights"] = SOLID_ANGLES, max_delta_e: float = 10.0,
) -> Comparison:
    """Measured | fitted | ΔE2000 of ``material`` (a Material or FitResult) and ``data``; see the module docstring.

    Writes the figure to ``path`` (PNG) when given. The title states the median and 95th
    percentile ΔE2000 over the compared sphere pixels, which :class:`Comparison` also holds;
    the ΔE panel's colour scale ends at ``max_delta_e``.

    >>> import ctfit
    >>> gloss = ctfit.material_from_dict({"s": 0.5, "d": 0.5, "lobes": [{"m": 0.3}], "channels": ["R", "G", "B"],
    ...                                   "F0": [0.9, 0.6, 0.3], "Rd": [0.2, 0.1, 0.05]})
    >>> c = ctfit.render_comparison(gloss, ctfit.simulate(gloss, 3000, seed=1), size=24, supersample=1)
    >>> len(c.figure.axes), c.delta_e.shape, bool(c.median < 1.0)  # three panels and a colourbar
    (4, (24, 24), True)
    """
    material = getattr(material, "material", material)
    surface = surface_normals(shape, size, supersample)
    normals = surface.normal[surface.mask]
    spectrum, to_rgb, model_fn = _bands_of(material, data)
    measured_fn = MeasuredBRDF(data)
    lights = scene_lights(spectrum, directions, solid_angles)
    n_bands = len(spectrum)
    fit_i, lit, _ = _shade(normals, lights, model_fn, n_bands)
    meas_i, _, missing = _shade(normals, lights, measured_fn, n_bands)
    scene = Scene(material.params, lights, 0.0, to_rgb)
    samples = {}
    for name, intensity in (("fitted", fit_i), ("measured", meas_i)):
        samples[name] = np.zeros(surface.mask.shape + (3,))
        samples[name][surface.mask] = intensity @ to_rgb
    on = lambda flags: _per_pixel(np.where(surface.mask, _scatter(surface.mask, flags), False).astype(float), supersample)
    full = _per_pixel(surface.mask.astype(float), supersample) == 1
    lit_px, missing_px = full & (on(lit) == 1), full & (on(missing) > 0)
    compared = lit_px & ~missing_px
    meas_mask = surface.mask & ~_scatter(surface.mask, missing)
    left, scale = tone_map(Tile(samples["fitted"], surface.mask, supersample, white_scale(normals, scene)), exposure=exposure)
    right = tone_map(Tile(np.where(meas_mask[..., None], samples["measured"], 0.0), meas_mask, supersample, 1.0), scale=scale)[0].copy()
    right[(_per_pixel(surface.mask.astype(float), supersample) > 0) & (on(missing) > 0)] = OUTSIDE_GREY
    fitted, measured = (scale * _per_pixel(samples[k], supersample) for k in ("fitted", "measured"))
    measured[missing_px] = np.nan
    de = np.where(compared, _delta_e(measured, fitted), np.nan)
    values = de[compared]
    median, p95 = (float(np.percentile(values, q)) if len(values) else float("nan") for q in (50, 95))
    coverage = float(compared.sum() / max(lit_px.sum(), 1))
    fig = _comparison_figure(material, data, (right, left, de, full & ~compared & missing_px), (median, p95, int(compared.sum()), coverage),
                             measured_fn.note, max_delta_e)
    if path is not None:
        from .._io import atomic_save, plot_metadata

        atomic_save(path, lambda buffer: fig.savefig(buffer, format="png", dpi=110, metadata=plot_metadata("png")))
    return Comparison(fig, de, median, p95, coverage, measured, fitted, measured_fn.note)


def _scatter(mask: np.ndarray, flags: np.ndarray) -> np.ndarray:
    out = np.zeros(mask.shape, bool)
    out[mask] = flags
    return out


def _comparison_figure(
    material: Material, data: Measurement, images: Sequence[np.ndarray], stats: Sequence[float], note: str, max_delta_e: float
) -> Any:
    """The three panels: measured (grey outside the measured domain), fitted, ΔE2000 with its colourbar."""
    import textwrap

    from .._runtime import need

    need("plots", "a rendered comparison")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import ListedColormap
    from matplotlib.figure import Figure

    measured, fitted, de, outside = images
    median, p95, n, coverage = stats
    fig = Figure(figsize=(12, 4.9), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 3)
    name = material.name or "fitted material"
    axes[0].imshow(measured, interpolation="nearest")
    axes[0].set_title(f"measured: {shorten(os.path.basename(str(data.source)) or str(data.source), 47)}\n(interpolated; grey: outside the measured domain)",
                      fontsize=9)  # the file's name: a long path was cut at the figure's left edge
    axes[1].imshow(fitted, interpolation="nearest")
    axes[1].set_title(f"fitted: {shorten(name, 47)}", fontsize=9)
    axes[2].imshow(np.where(outside, 1.0, np.nan), cmap=ListedColormap([(OUTSIDE_GREY / 255,) * 3]), interpolation="nearest")
    shown = axes[2].imshow(de, cmap="viridis", vmin=0.0, vmax=max_delta_e, interpolation="nearest")
    axes[2].set_title("ΔE2000 (CIEDE2000), measured vs fitted", fontsize=9)
    fig.colorbar(shown, ax=axes[2], extend="max", shrink=0.85).set_label("ΔE2000 (1 ≈ just noticeable)")
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    head = f"ΔE2000 over the sphere: median {median:.2f}, 95th percentile {p95:.2f} ({n} pixels, {coverage_text(coverage)} of the lit sphere measured)"
    tail = f"Measured sphere interpolated {note}; two lights, no ambient light; same exposure for both spheres."
    fig.suptitle(head + "\n" + textwrap.fill(tail, 150), fontsize=9)
    return fig
