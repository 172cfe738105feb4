"""Pictures of fit quality: polar plots per incidence angle, the residual map over (θ_h, θ_d), and
measured | fitted | ΔE2000 renders, on grid, scattered, single-band (ALTA) and RGB data."""

import dataclasses
import warnings

import numpy as np
import pytest

import ctfit
from ctfit._fitting.least_squares import FitResult
from ctfit._fitting.plots import make_fit_quality_figure

from conftest import MEASURED

GLOSS = {"s": 0.6, "d": 0.4, "lobes": [{"m": 0.25}], "F0": [0.9, 0.6, 0.3], "Rd": [0.2, 0.1, 0.05]}


def _gloss_rgb(**changes):
    return ctfit.material_from_dict({**GLOSS, "channels": ["R", "G", "B"], **changes})


def _gloss_spectral():
    return ctfit.material_from_dict({**GLOSS, "wavelength_nm": [450.0, 550.0, 650.0]})


def _grid_data(material):
    """A goniometer grid: θ_i 15–60°, θ_o every 5°, φ_o in five azimuths, every pair in R, G, B."""
    pairs = np.array([(ti, 0.0, to, po) for ti in (15.0, 30.0, 45.0, 60.0) for to in np.arange(0.0, 86.0, 5.0)
                      for po in (0.0, 45.0, 90.0, 135.0, 180.0)])
    rep = lambda a: np.repeat(a, 3)
    data = ctfit.Measurement(theta_i=rep(pairs[:, 0]), phi_i=rep(pairs[:, 1]), theta_o=rep(pairs[:, 2]), phi_o=rep(pairs[:, 3]),
                             band=np.tile(np.arange(3), len(pairs)), channels=("R", "G", "B"), source="grid.csv")
    return data.replace(brdf=ctfit.evaluate(material, data))


def _scattered_data(material, n=1500, seed=3):
    """Every sample its own random directions (θ_i too) and one of five bands: not a grid."""
    rng = np.random.default_rng(seed)
    ti, to = rng.uniform(0, 80, n), np.degrees(np.arcsin(np.sqrt(rng.uniform(0, np.sin(np.radians(85)) ** 2, n))))
    po = np.where(rng.uniform(size=n) < 0.4, rng.choice([0.0, 180.0], n), rng.uniform(0, 360, n))
    data = ctfit.Measurement(theta_i=ti, phi_i=np.zeros(n), theta_o=to, phi_o=po, band=rng.integers(0, 5, n),
                             wavelength_nm=np.linspace(450.0, 650.0, 5), source="scattered.csv")
    return data.replace(brdf=ctfit.evaluate(material, data))


def _alta_retro():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ctfit.DataWarning)  # 86 horizon samples dropped (tests/test_alta.py)
        data = ctfit.read_measurement(MEASURED / "retro-3M-jaune.dat")
    mat = ctfit.Material(ctfit.Structure(lobes=1, diffuse="constant"), ctfit.Params(s=np.asarray(0.5), m=np.array([0.3]), w=np.ones(1),
                         f0=np.array([0.3]), rd=np.array([0.1])), wavelength_nm=np.array([550.0]), band_unknown=True, name="retro fit")
    return mat, data


def _felt_1d():
    data = ctfit.read_measurement(MEASURED / "pink-felt-1d.alta")
    return ctfit.material_from_dict({"s": 0.05, "d": 0.95, "lobes": [{"m": 0.4}], "channels": ["R", "G", "B"],
                                     "F0": [0.32, 0.23, 0.2], "Rd": [0.1, 0.076, 0.06]}), data


def _material_and_data(kind, n_scattered):
    """(material, data it is shown with): RGB grid, scattered spectral, single-band ALTA, 1-D RGB ALTA."""
    if kind == "grid":
        mat = _gloss_rgb()
        return mat, _grid_data(mat)
    if kind == "scattered":
        mat = _gloss_spectral()
        return mat, _scattered_data(mat, n=n_scattered)
    return _alta_retro() if kind == "alta" else _felt_1d()


def _off_plane_deg(data):
    dphi = np.radians(data.phi_o - data.phi_i)
    return np.degrees(np.arcsin(np.sin(np.radians(data.theta_o)) * np.abs(np.sin(dphi))))


def _data_lines(ax):
    return [line for line in ax.lines if line.get_label().startswith("data")]


def _model_lines(ax):
    return [line for line in ax.lines if line.get_label().startswith("model")]


# --- polar plots --------------------------------------------------------------------------------


def test_polar_grid_rgb_one_panel_per_incidence_with_the_in_plane_samples(tmp_path):
    mat = _gloss_rgb()
    data = _grid_data(mat)
    fig = ctfit.plot_polar(mat, data, tmp_path / "polar.png")
    assert (tmp_path / "polar.png").stat().st_size > 10_000
    assert [ax.name for ax in fig.axes] == ["polar"] * 4
    in_plane = _off_plane_deg(data) <= 5.0
    for ax, ti in zip(fig.axes, (15.0, 30.0, 45.0, 60.0)):
        assert "θ_o" in ax.get_xlabel() and "BRDF" in ax.get_ylabel() and f"θ_i = {ti:g}°" in ax.get_title()
        assert [line.get_label() for line in _model_lines(ax)] == ["model R", "model G", "model B"]
        expected = [int(np.count_nonzero(in_plane & (data.theta_i == ti) & (data.band == b))) for b in range(3)]
        assert [len(line.get_xdata()) for line in _data_lines(ax)] == expected
        # The model line is the model: forward side (right, +) at φ_o = 180°.
        x, y = (np.asarray(a) for a in _model_lines(ax)[1].get_data())
        k = np.argmin(np.abs(x - np.radians(40.0)))
        exact = ctfit.evaluate_at(mat, theta_i=ti, theta_o=np.degrees(x[k]), phi_o=180.0)[1]
        assert y[k] == pytest.approx(float(exact), rel=1e-9)


def test_polar_scattered_spectral_bins_incidences_and_shows_three_bands():
    mat = _gloss_spectral()
    data = _scattered_data(mat)
    fig = ctfit.plot_polar(mat, data, plane_tol_deg=4.0)
    assert len(fig.axes) == 4
    assert all("–" in ax.get_title() and "model at" in ax.get_title() for ax in fig.axes)  # bins of θ_i
    assert all(len(_model_lines(ax)) == 3 for ax in fig.axes)  # 450, 550, 650 nm of the five bands
    shown_bands = {0, 2, 4}
    in_plane = (_off_plane_deg(data) <= 4.0) & np.isin(data.band, list(shown_bands))
    assert sum(len(line.get_xdata()) for ax in fig.axes for line in _data_lines(ax)) == int(in_plane.sum())
    assert "±4°" in fig.get_suptitle()


def test_polar_single_band_alta_and_1d_rgb():
    mat, data = _alta_retro()
    fig = ctfit.plot_polar(mat, data)
    assert [ax.get_title().split(":")[0] for ax in fig.axes] == ["θ_i = 15°", "θ_i = 30°", "θ_i = 60°"]
    labels = {line.get_label() for ax in fig.axes for line in ax.lines}
    assert {"model", "data"} <= labels and not any("550" in s or "unknown" in s for s in labels)
    felt, data = _felt_1d()
    fig = ctfit.plot_polar(felt, data)
    (ax,) = fig.axes
    assert "V = L" in ax.get_title()
    assert [len(line.get_xdata()) for line in _data_lines(ax)] == [90, 90, 90]
    assert np.all(np.asarray(_data_lines(ax)[0].get_xdata()) <= 0)  # back-scatter: the back side


def test_polar_rejects_data_without_values_or_without_in_plane_samples():
    mat = _gloss_rgb()
    data = _grid_data(mat)
    with pytest.raises(ValueError, match="no BRDF values"):
        ctfit.plot_polar(mat, data.replace(brdf=None))
    off = data.replace(phi_o=np.full(len(data), 90.0), theta_o=np.full(len(data), 40.0))
    with pytest.raises(ValueError, match="plane of incidence"):
        ctfit.plot_polar(mat, off)


# --- residual map ---------------------------------------------------------------------------------


def test_residual_map_cells_are_mean_log_ratios():
    truth, model = _gloss_rgb(), _gloss_rgb(lobes=[{"m": 0.35}])
    data = ctfit.simulate(truth, 200, seed=2, noise=0.05)
    fig = ctfit.plot_residual_map(model, data, bins=6)
    ax, bar = fig.axes
    shown = ax.collections[0].get_array()
    # Directly: ln(model/data) per sample, cells of 15° in θ_h (rows) and θ_d (columns).
    th, td, _ = ctfit.angles_deg_to_half_diff_deg(data.theta_i, data.phi_i, data.theta_o, data.phi_o)
    r = np.log(ctfit.evaluate(model, data) / data.brdf)
    h, d = np.minimum(th // 15, 5).astype(int), np.minimum(td // 15, 5).astype(int)
    expected = np.full((6, 6), np.nan)
    for i, j in set(zip(h, d)):
        expected[i, j] = r[(h == i) & (d == j)].mean()
    got = np.ma.filled(shown.reshape(6, 6).astype(float), np.nan).T  # pcolormesh rows are θ_d
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-12)  # NaN (blank) where the direct one is empty
    lo, hi = ax.collections[0].get_clim()
    assert lo == -hi and hi > 0  # diverging, centred at 0
    assert "ln(model / data)" in bar.get_ylabel()
    assert ax.get_xlabel().startswith("θ_h") and ax.get_ylabel().startswith("θ_d")


@pytest.mark.parametrize("kind", ["grid", "scattered", "alta", "felt"])
def test_residual_map_on_every_kind_of_data(kind, tmp_path):
    mat, data = _material_and_data(kind, n_scattered=400)
    fig = ctfit.plot_residual_map(mat, data, tmp_path / "r.png")
    ax = fig.axes[0]
    assert len(fig.axes) == 2 and (tmp_path / "r.png").exists()
    counted = int(ax.get_title().split(": ")[1].split(" samples")[0])
    assert counted == int(np.count_nonzero((data.brdf > 0) & (ctfit.evaluate(mat, data) > 0)))


# --- measured | fitted | ΔE2000 ---------------------------------------------------------------


def test_delta_e_is_zero_when_the_fit_is_the_data_generating_material():
    gloss = _gloss_rgb()  # with s = 0: Lambertian, in the structure the other tests compile
    matte = dataclasses.replace(gloss, params=dataclasses.replace(gloss.params, s=np.asarray(0.0)))
    c = ctfit.render_comparison(matte, ctfit.simulate(matte, 500, seed=1), size=32, supersample=1)
    assert np.nanmax(c.delta_e) < 1e-6 and c.median < 1e-6 and c.p95 < 1e-6
    assert f"median {c.median:.2f}, 95th percentile {c.p95:.2f}" in c.figure.get_suptitle()


def _steps(c, compared):
    """The 99th percentile of the jumps between neighbouring pixels of ln(measured / fitted) luminance."""
    lum = lambda rgb: np.log(np.maximum(rgb @ np.array([0.2126, 0.7152, 0.0722]), 1e-12))
    err = lum(c.measured) - lum(c.fitted)
    both = compared[:, 1:] & compared[:, :-1]
    return float(np.quantile(np.abs(np.diff(err, axis=1)[both]), 0.99))


def test_measured_sphere_is_smooth_and_close_to_the_exact_render(monkeypatch):
    from ctfit._render import comparison

    mat = _gloss_rgb()
    data = ctfit.simulate(mat, 3000, seed=1)
    c = ctfit.render_comparison(mat, data, size=48, supersample=1)
    assert c.median < 0.5 and c.p95 < 2.0 and c.coverage > 0.95  # interpolation error only
    compared = np.isfinite(c.delta_e)
    sweep = np.linspace(0.0, 80.0, 400)  # a fine sweep of θ_o: the interpolated BRDF changes at every step
    values = comparison.MeasuredBRDF(data)(np.full(400, 35.0), sweep, np.full(400, 150.0))[:, 1]
    assert len(np.unique(values)) > 390
    # The same data looked up at the nearest measured direction: facets and steps (the test can tell).
    from scipy.interpolate import NearestNDInterpolator

    monkeypatch.setattr(comparison, "_shepard", lambda points, logs: NearestNDInterpolator(points, logs))
    faceted = ctfit.render_comparison(mat, data, size=48, supersample=1)
    nn_values = comparison.MeasuredBRDF(data)(np.full(400, 35.0), sweep, np.full(400, 150.0))[:, 1]
    assert len(np.unique(nn_values)) < 0.25 * len(np.unique(values))
    assert _steps(c, compared) < 0.3 * _steps(faceted, compared)


@pytest.mark.parametrize("kind", ["grid", "scattered", "alta", "felt"])
def test_comparison_on_every_kind_of_data(kind, tmp_path):
    mat, data = _material_and_data(kind, n_scattered=3000)
    c = ctfit.render_comparison(mat, data, tmp_path / "c.png", size=24)
    assert (tmp_path / "c.png").stat().st_size > 5_000
    assert len(c.figure.axes) == 4  # measured, fitted, ΔE and its colourbar
    assert "measured" in c.figure.axes[0].get_title() and "fitted" in c.figure.axes[1].get_title()
    assert "ΔE2000" in c.figure.axes[3].get_ylabel()
    assert np.isfinite([c.median, c.p95]).all() and 0 <= c.median <= c.p95
    assert c.delta_e.shape == (24, 24) and 0 < c.coverage <= 1


def test_comparison_rejects_mismatched_bands():
    data = _scattered_data(_gloss_spectral(), n=200)
    with pytest.raises(ValueError, match="spectral material"):
        ctfit.render_comparison(_gloss_rgb(), data, size=8)


# --- wired in: ctfit fit --plot, ctfit render --compare --delta-e ------------------------------------


def test_fit_plot_has_the_peak_panels_the_polar_plots_and_the_residual_map():
    mat = _gloss_rgb()
    result = FitResult(material=mat, stats={"rel_rmse": 0.1, "loss": "relative", "converged": True}, stderr=None, warnings=[],
                       loss="relative", solver="lm")
    fig = make_fit_quality_figure(result, _grid_data(mat))
    axes = [ax for sub in fig.subfigs for ax in _all_axes(sub)]
    assert sum(ax.name == "polar" for ax in axes) == 4
    assert any(ax.get_xlabel().startswith("θ_h") and ax.get_ylabel().startswith("θ_d") for ax in axes)
    assert any("in-plane slices" in ax.get_title() for ax in axes)


def _all_axes(fig):
    return list(fig.axes) + [ax for sub in getattr(fig, "subfigs", []) for ax in _all_axes(sub)]


def test_cli_render_delta_e(tmp_path):
    from typer.testing import CliRunner

    from ctfit.cli import app

    mat = _gloss_rgb()
    ctfit.write_csv(ctfit.simulate(mat, 1500, seed=1), tmp_path / "data.csv")
    ctfit.save_material_json(mat, tmp_path / "fit.json")
    out = tmp_path / "de.png"
    res = CliRunner().invoke(app, ["render", str(tmp_path / "fit.json"), "--compare", str(tmp_path / "data.csv"), "--delta-e",
                                   "-o", str(out), "--size", "24"])
    assert res.exit_code == 0, res.output
    assert out.stat().st_size > 5_000 and "ΔE2000 over the sphere: median" in res.output
    res = CliRunner().invoke(app, ["render", str(tmp_path / "fit.json"), "--delta-e", "-o", str(out)])
    assert res.exit_code == 2 and res.output.strip().splitlines()[-1].startswith("error: --delta-e")


def test_fit_plot_without_in_plane_samples_still_has_the_other_panels(tmp_path):
    from ctfit._fitting.plots import plot_fit

    mat = _gloss_rgb()
    data = _grid_data(mat)
    off = data.replace(phi_o=np.full(len(data), 90.0), theta_o=np.full(len(data), 40.0))
    result = FitResult(material=mat, stats={"rel_rmse": 0.1, "loss": "relative", "converged": True}, stderr=None, warnings=[],
                       loss="relative", solver="lm")
    plot_fit(result, off, tmp_path / "fit.png")
    assert (tmp_path / "fit.png").stat().st_size > 10_000
    fig = make_fit_quality_figure(result, off)
    texts = [t.get_text() for sub in fig.subfigs for s in [sub, *sub.subfigs] for t in s.texts]
    assert any("no polar plot" in t and "plane of incidence" in t for t in texts)
    assert any(ax.get_xlabel().startswith("θ_h") for ax in _all_axes(fig))


def test_polar_rejects_bands_the_material_lacks():
    data = _grid_data(_gloss_rgb())
    with pytest.raises(ValueError, match="cannot be shown with material"):
        ctfit.plot_polar(_gloss_spectral(), data)
