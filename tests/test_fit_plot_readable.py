"""The fit plot (`ctfit fit --plot`) stays readable and honest: wrapped titles, legends off the
data, robust y-limits, 1-D data against θ_h, no placeholder wavelength, one in-plane sign."""

import numpy as np
import pytest
from matplotlib.text import Text

import ctfit
from ctfit._fitting.least_squares import FitResult
from ctfit._fitting.plots import make_fit_figure, plot_fit, signed_in_plane_angle

from conftest import MEASURED


def _result(material, warnings=()):
    stats = {"rel_rmse": 0.1, "loss": "relative", "converged": True}
    return FitResult(material=material, stats=stats, stderr=None, warnings=list(warnings), loss="relative", solver="lm")


def _material(wavelength_nm=(450.0, 650.0), diffuse=True, m=0.2, **kw):
    nb = len(kw.get("channels") or wavelength_nm)
    st = ctfit.Structure(lobes=1, diffuse="F0/pi" if diffuse else None)
    p = ctfit.Params(s=np.asarray(0.9) if diffuse else None, m=np.array([m]), w=np.array([1.0]), f0=np.linspace(0.5, 0.9, nb))
    wl = None if kw.get("channels") else np.asarray(wavelength_nm)
    return ctfit.Material(st, p, wavelength_nm=wl, name="t", **kw)


def _in_plane_data(material, bands=(450.0, 650.0), noise=0.02, **kw):
    """θ_i = 30°, θ_o every 5° on both sides of the plane of incidence, plus out-of-plane rows."""
    to = np.arange(0.0, 86.0, 5.0)
    pairs = [(30.0, 0.0, t, p) for t in to for p in (0.0, 180.0)] + [(30.0, 0.0, t, 90.0) for t in to]
    pairs = np.array(pairs)
    nb = len(kw.get("channels") or bands)
    rep = lambda a: np.repeat(a, nb)
    geo = dict(theta_i=rep(pairs[:, 0]), phi_i=rep(pairs[:, 1]), theta_o=rep(pairs[:, 2]), phi_o=rep(pairs[:, 3]))
    band = np.tile(np.arange(nb), len(pairs))
    wl = None if kw.get("channels") else np.asarray(bands)
    data = ctfit.Measurement(**geo, band=band, wavelength_nm=wl, source="plane.csv", **kw)
    truth = ctfit.evaluate(material, data)
    rng = np.random.default_rng(0)
    return data.replace(brdf=truth * (1 + noise * rng.standard_normal(len(truth))))


def _texts(fig):
    fig.canvas.draw()
    return [t.get_text() for t in fig.findobj(Text) if t.get_text()]


def _data_axes(fig):
    return [ax for ax in fig.axes if ax.lines or ax.collections]


# --- titles ----------------------------------------------------------------------------------


def test_long_warnings_wrap_and_the_title_stays_inside_the_figure():
    mat = _material()
    data = _in_plane_data(mat).replace(source="a/rather/long/path/to/" + "measurement-" * 12 + ".csv")
    long = "systematic residuals: " + "the model is well below the data in one group of samples " * 8
    fig = make_fit_figure(_result(mat, [long, "s = 0.99 is near its upper bound", long, "fourth"]), data)
    fig.canvas.draw()
    title = fig._suptitle
    lines = title.get_text().split("\n")
    assert len(lines) > 4 and max(map(len, lines)) <= 150
    assert "1 more warning" in title.get_text()  # the fourth warning is counted, not dropped silently
    renderer = fig.canvas.get_renderer()
    box = title.get_window_extent(renderer)
    assert fig.bbox.x0 <= box.x0 and box.x1 <= fig.bbox.x1 and box.y1 <= fig.bbox.y1
    for ax in _data_axes(fig):
        assert not box.overlaps(ax.get_tightbbox(renderer))
    for lg in (ax.get_legend() for ax in fig.axes if ax.get_legend()):  # the room comes from the figure
        assert fig.bbox.y0 <= lg.get_window_extent(renderer).y0


# --- y-limits --------------------------------------------------------------------------------


def test_one_tiny_value_does_not_stretch_the_log_axis():
    mat = _material(wavelength_nm=(550.0,))
    data = _in_plane_data(mat, bands=(550.0,))
    x = signed_in_plane_angle(data.theta_o, data.phi_o, data.phi_i)
    row = int(np.flatnonzero(np.isfinite(x))[3])
    brdf = data.brdf.copy()
    brdf[row] = 1e-16
    fig = make_fit_figure(_result(mat), data.replace(brdf=brdf))
    slices, residuals = fig.axes[0], fig.axes[1]
    lo, hi = slices.get_ylim()
    genuine = np.delete(brdf, row)[np.isfinite(np.delete(x, row))]
    assert lo > 1e-8 and lo <= genuine.min() and hi >= genuine.max()
    assert "1 data point below the shown range" in slices.get_title()
    # its relative residual is an outlier too: left out of the residual axis, and said so
    assert residuals.get_ylim()[1] < 1.0
    assert "1 data point above the shown range" in residuals.get_title()


def test_the_steep_ends_of_real_1d_data_stay_in_view():
    data = ctfit.read_measurement(MEASURED / "pink-felt-1d.alta")
    fig = make_fit_figure(_result(_material(channels=("R", "G", "B"))), data)
    ax = fig.axes[0]
    lo, hi = ax.get_ylim()
    assert lo <= data.brdf.min() and data.brdf.max() <= hi
    assert "shown range" not in ax.get_title()


# --- 1-D data --------------------------------------------------------------------------------


def test_1d_cos_th_data_is_plotted_against_theta_h():
    data = ctfit.read_measurement(MEASURED / "pink-felt-1d.alta")
    assert data.meta["alta_param_in"] == "COS_TH"
    cos_th = np.loadtxt(MEASURED / "pink-felt-1d.alta", comments="#")[:, 0]
    for d in (data, data.replace(meta={})):  # the marker, or the geometry (every sample has V = L)
        fig = make_fit_figure(_result(_material(channels=("R", "G", "B"))), d)
        ax = fig.axes[0]
        assert "θ_h" in ax.get_xlabel() and "θ_h" in fig.axes[1].get_xlabel()
        assert not any("slice" in a.get_title() for a in fig.axes)
        red = [ln for ln in ax.lines if ln.get_label() == "data R"]
        assert len(red) == 1
        np.testing.assert_allclose(np.sort(red[0].get_xdata()), np.sort(np.rad2deg(np.arccos(cos_th))), atol=1e-6)
        model = [ln for ln in ax.lines if ln.get_label() == "model R"][0]
        assert model.get_xdata()[0] == 0 and model.get_xdata()[-1] >= red[0].get_xdata().max()


# --- band labels -----------------------------------------------------------------------------


def test_single_band_of_unknown_wavelength_shows_no_placeholder_wavelength():
    mat = _material(wavelength_nm=(550.0,), band_unknown=True)
    data = _in_plane_data(mat, bands=(550.0,), band_unknown=True).replace(source="tape.alta")
    texts = _texts(make_fit_figure(_result(mat), data))
    assert not any("550" in t or "wavelength" in t for t in texts), [t for t in texts if "550" in t or "wavelength" in t]
    assert "unknown band" in texts


def test_known_single_wavelength_is_labelled():
    mat = _material(wavelength_nm=(550.0,))
    texts = _texts(make_fit_figure(_result(mat), _in_plane_data(mat, bands=(550.0,))))
    assert any("550 nm" in t for t in texts)


# --- legends ---------------------------------------------------------------------------------


@pytest.mark.parametrize("case", ["spectral", "single-band", "1-d"])
def test_legends_do_not_cover_data(case):
    if case == "1-d":
        mat = _material(channels=("R", "G", "B"))
        data = ctfit.read_measurement(MEASURED / "pink-felt-1d.alta")
    else:
        bands = (450.0, 650.0) if case == "spectral" else (550.0,)
        mat = _material(wavelength_nm=bands)
        data = _in_plane_data(mat, bands=bands)
    fig = make_fit_figure(_result(mat), data)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    legends = [lg for ax in fig.axes for lg in ([ax.get_legend()] if ax.get_legend() else [])]
    assert len(legends) >= 2
    points = []
    for ax in _data_axes(fig):  # every drawn point: inside its axes (the rest is clipped away)
        frame = ax.get_window_extent(renderer)
        for ln in ax.lines:
            xy = ln.get_transform().transform(ln.get_xydata())
            points.append(xy[(xy[:, 0] >= frame.x0) & (xy[:, 0] <= frame.x1) & (xy[:, 1] >= frame.y0) & (xy[:, 1] <= frame.y1)])
    points = np.concatenate(points)
    assert len(points) > 100
    for lg in legends:
        box = lg.get_window_extent(renderer)
        assert fig.bbox.x0 <= box.x0 and box.x1 <= fig.bbox.x1 and fig.bbox.y0 <= box.y0
        for ax in _data_axes(fig):
            assert not box.overlaps(ax.get_window_extent(renderer))
        inside = (points[:, 0] >= box.x0) & (points[:, 0] <= box.x1) & (points[:, 1] >= box.y0) & (points[:, 1] <= box.y1)
        assert not inside.any()


# --- in-plane sign convention ----------------------------------------------------------------


def test_signed_in_plane_angle():
    theta_o = np.full(8, 40.0)
    phi_o = np.array([0.0, 180.0, 90.0, 180.0, 0.0, 2.0, 358.0, 177.0])
    phi_i = np.array([0.0, 0.0, 0.0, 180.0, 180.0, 0.0, 0.0, 0.0])
    x = signed_in_plane_angle(theta_o, phi_o, phi_i)
    np.testing.assert_array_equal(x[[0, 1, 3, 4, 5, 6]], [40.0, -40.0, 40.0, -40.0, 40.0, 40.0])
    assert np.isnan(x[2]) and np.isnan(x[7])
    assert signed_in_plane_angle(0.0, 77.0, 0.0) == 0.0


def test_light_side_is_positive_and_the_mirror_peak_negative_in_the_plot():
    mat = _material(wavelength_nm=(550.0,), diffuse=False, m=0.1)
    data = _in_plane_data(mat, bands=(550.0,), noise=0.0)
    light_side = (data.phi_o == data.phi_i) & (data.theta_o > 0)
    brdf = data.brdf.copy()
    brdf[light_side] = 1e3  # mark the viewer-on-the-light's-side samples
    ax = make_fit_figure(_result(mat), data.replace(brdf=brdf)).axes[0]
    dots = [ln for ln in ax.lines if ln.get_label().startswith("data")][0]
    x, y = dots.get_xdata(), dots.get_ydata()
    assert np.all(x[y == 1e3] > 0) and np.all(x[y < 1e3] <= 0) and (y == 1e3).sum() == light_side.sum()
    model = [ln for ln in ax.lines if ln.get_label().startswith("model")][0]
    peak = model.get_xdata()[np.argmax(model.get_ydata())]
    assert -35.0 < peak < -25.0  # the mirror direction of θ_i = 30°
    assert "light's side (φ_o = φ_i)" in ax.get_xlabel()


def test_plot_fit_writes_a_png(tmp_path):
    mat = _material()
    plot_fit(_result(mat, ["a warning"]), _in_plane_data(mat), tmp_path / "fit.png")
    assert (tmp_path / "fit.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
