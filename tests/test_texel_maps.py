"""Texel data fitted chunk by chunk on a ``LocalCluster`` (2 workers): the maps equal the serial
``fit_texels`` in both layouts (Zarr image, HDF5 texel list); a chunk not finished is fitted on a
re-run and the others kept; a store of another input is refused; ``ctfit fit`` writes maps and PNGs."""

import numpy as np
import pytest
import xarray as xr
from typer.testing import CliRunner

import ctfit
from ctfit import read_texel_geometry
from ctfit._fitting.texel_maps import TexelMapError
from ctfit._runtime.cluster import dask_client
from ctfit.cli import app

WL = np.array([450.0, 650.0])
ST = ctfit.Structure(lobes=1)
H, W = 5, 4


def material(m, f0):
    return ctfit.Material(ST, ctfit.Params(m=np.array([m]), w=np.array([1.0]), f0=np.array([f0, 0.9])), wavelength_nm=WL)


@pytest.fixture(scope="module")
def texels():
    geometry = ctfit.simulate(material(0.25, 0.6), 50, noise=0.0, seed=0)
    rng = np.random.default_rng(1)
    values = np.empty((H, W, len(geometry)))
    for y in range(H):
        for x in range(W):
            clean = ctfit.evaluate(material(0.15 + 0.02 * y + 0.01 * x, 0.5 + 0.05 * x), geometry)
            values[y, x] = clean * (1 + 0.01 * rng.standard_normal(len(geometry)))
    return geometry, values


def dataset(geometry, values, dims):
    table = {k: (("sample",), getattr(geometry, k)) for k in ("theta_i", "phi_i", "theta_o", "phi_o", "band")}
    return xr.Dataset({"values": ((*dims, "sample"), values), **table, "wavelength_nm": (("band",), WL)})


@pytest.fixture(scope="module")
def client():
    with dask_client(workers=2) as c:
        yield c


def test_image_maps_equal_the_serial_fits_and_a_rerun_finishes_a_chunk(client, texels, tmp_path):
    geometry, values = texels
    dataset(geometry, values, ("y", "x")).to_zarr(tmp_path / "in.zarr", consolidated=False)
    serial = ctfit.fit_texels(geometry, values.reshape(H * W, -1), ST)
    maps = ctfit.fit_texel_maps(tmp_path / "in.zarr", tmp_path / "maps.zarr", ST, client, chunk=2 * W)
    assert maps["m"].dims == ("y", "x", "lobe") and maps["F0"].dims == ("y", "x", "band")
    np.testing.assert_allclose(maps["m"].values.reshape(H * W, 1), serial.params.m, rtol=1e-8)
    np.testing.assert_allclose(maps["F0"].values.reshape(H * W, 2), serial.params.f0, rtol=1e-8)
    np.testing.assert_array_equal(maps["converged"].values.reshape(-1), serial.converged)
    assert maps.attrs["input_sha256"] and maps["cost"].chunks[0] == (2, 2, 1)
    # rows 2–3 as a killed run leaves them: status (written last) missing, the rest half written
    spoilt = xr.Dataset({"status": (("y", "x"), np.full((2, W), -1, np.int8)), "m": (("y", "x", "lobe"), np.zeros((2, W, 1)))})
    spoilt.to_zarr(tmp_path / "maps.zarr", region={"y": slice(2, 4)}, consolidated=False)
    again = ctfit.fit_texel_maps(tmp_path / "in.zarr", tmp_path / "maps.zarr", ST, client, chunk=2 * W)
    np.testing.assert_allclose(again["m"].values.reshape(H * W, 1), serial.params.m, rtol=1e-8)
    assert np.isfinite(again["cost"].values).all() and (again["status"].values == 0).all()


def test_texel_list_in_hdf5_and_another_input_refused(client, texels, tmp_path):
    geometry, values = texels
    flat = values.reshape(H * W, -1)
    dataset(geometry, flat, ("texel",)).to_netcdf(tmp_path / "in.h5", engine="h5netcdf")
    data, dims, sizes = read_texel_geometry(tmp_path / "in.h5")
    assert dims == ("texel",) and sizes == (H * W,) and len(data) == flat.shape[1]
    maps = ctfit.fit_texel_maps(tmp_path / "in.h5", tmp_path / "maps.zarr", ST, client, chunk=7)
    np.testing.assert_allclose(maps["m"].values, ctfit.fit_texels(geometry, flat, ST).params.m, rtol=1e-8)
    dataset(geometry, flat * 1.1, ("texel",)).to_netcdf(tmp_path / "other.h5", engine="h5netcdf")
    with pytest.raises(TexelMapError, match="another input"):
        ctfit.fit_texel_maps(tmp_path / "other.h5", tmp_path / "maps.zarr", ST, client, chunk=7)
    xr.Dataset({"values": (("texel",), flat[:, 0])}).to_netcdf(tmp_path / "bad.h5", engine="h5netcdf")
    with pytest.raises(TexelMapError, match="missing variable"):
        read_texel_geometry(tmp_path / "bad.h5")


def test_cli_writes_maps_and_pngs(texels, tmp_path):
    geometry, values = texels
    dataset(geometry, values, ("y", "x")).to_zarr(tmp_path / "in.zarr", consolidated=False)
    got = CliRunner().invoke(app, ["fit", str(tmp_path / "in.zarr"), "-o", str(tmp_path / "maps.zarr"), "--workers", "2", "--no-diffuse", "--lobes", "1",
                                   "--plot", str(tmp_path / "png")])
    assert got.exit_code == 0, got.output
    assert f"{H * W} texels, {H * W} converged" in got.output
    assert {p.name for p in (tmp_path / "png").iterdir()} >= {"m_0.png", "F0_0.png", "F0_1.png", "cost.png", "converged.png"}
    refused = CliRunner().invoke(app, ["fit", str(tmp_path / "in.zarr"), "-o", str(tmp_path / "maps.json")])
    assert refused.exit_code == 2 and "-o MAPS.zarr" in refused.output
    # A folder of the user's with a file at one of the pictures' names: kept, the run refused before any work.
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "cost.png").write_text("user file\n")
    (tmp_path / "mine" / "notes.png").write_text("not a picture's name\n")
    refused = CliRunner().invoke(app, ["fit", str(tmp_path / "in.zarr"), "-o", str(tmp_path / "maps2.zarr"), "--plot", str(tmp_path / "mine")])
    assert refused.exit_code == 2 and "cost.png: the file exists and is not a plot of ctfit" in refused.output, refused.output
    assert (tmp_path / "mine" / "cost.png").read_text() == "user file\n" and not (tmp_path / "maps2.zarr").exists()
    from ctfit._fitting import map_picture_files

    assert map_picture_files(tmp_path / "png") == sorted((tmp_path / "png").iterdir())  # every picture named: a rerun checks (and replaces) them


def test_plot_of_a_texel_list_is_refused_before_any_work(texels, tmp_path):
    """--plot of a store without an image layout: one error before any fit (the maps were fitted and
    written, then the pictures refused with exit status 2)."""
    geometry, values = texels
    dataset(geometry, values.reshape(H * W, -1), ("texel",)).to_zarr(tmp_path / "in.zarr", consolidated=False)
    got = CliRunner().invoke(app, ["fit", str(tmp_path / "in.zarr"), "-o", str(tmp_path / "maps.zarr"), "--workers", "1", "-q", "--no-diffuse",
                                   "--lobes", "1", "--plot", str(tmp_path / "png")])
    assert got.exit_code == 2 and got.output.count("error:") == 1, got.output
    assert "is not an image (values dims ('texel', 'sample')); pictures of the maps need values dims (y, x, sample)" in got.output
    assert not (tmp_path / "maps.zarr").exists() and not (tmp_path / "png").exists()


@pytest.mark.slow
def test_bad_texels_are_recorded_in_the_maps_and_the_rest_fitted(client, texels, tmp_path):
    """NaN, inf, all-zero, 1e300 and negative texels: status says why, their maps are NaN, the
    others equal the serial fits; the command prints no traceback and counts them."""
    geometry, values = texels
    bad = values.copy()
    bad[0, 0, 3], bad[0, 1, 2], bad[1, 0], bad[1, 1], bad[2, 0, 0] = np.nan, np.inf, 0.0, 1e300, -1.0
    dataset(geometry, bad, ("y", "x")).to_zarr(tmp_path / "in.zarr", consolidated=False)
    maps = ctfit.fit_texel_maps(tmp_path / "in.zarr", tmp_path / "maps.zarr", ST, client, chunk=2 * W)
    status = maps["status"].values
    expected = np.zeros((H, W), int)
    expected[0, 0], expected[0, 1], expected[1, 0], expected[1, 1], expected[2, 0] = 1, 1, 3, 4, 2
    np.testing.assert_array_equal(status, expected)
    assert maps["status"].attrs["flag_meanings"].split() == ["not_written", "fitted", "non_finite_values", "negative_values", "all_zero", "out_of_range"]
    skipped = expected > 0
    assert np.isnan(maps["m"].values[skipped]).all() and np.isnan(maps["cost"].values[skipped]).all() and not maps["converged"].values[skipped].any()
    serial = ctfit.fit_texels(geometry, values.reshape(H * W, -1), ST)
    np.testing.assert_allclose(maps["m"].values[~skipped], serial.params.m.reshape(H, W, 1)[~skipped], rtol=1e-8)
    # the command: no traceback, one summary line naming what was not fitted; a re-run fits nothing again
    got = CliRunner().invoke(app, ["fit", str(tmp_path / "in.zarr"), "-o", str(tmp_path / "cli.zarr"), "--workers", "1", "-q",
                                   "--plot", str(tmp_path / "png")])
    assert got.exit_code == 1 and "Traceback" not in got.output, got.output
    assert "5 not fitted (2 non finite values, 1 negative values, 1 all zero, 1 out of range; map 'status')" in got.output
    assert (tmp_path / "png" / "status.png").exists()


def _store(tmp_path, geometry, values, name="in.zarr", **changes):
    table = {k: (("sample",), changes.get(k, getattr(geometry, k))) for k in ("theta_i", "phi_i", "theta_o", "phi_o", "band")}
    wl = changes.get("wavelength_nm", WL)
    xr.Dataset({"values": (("y", "x", "sample"), values), **table, "wavelength_nm": (("band",), wl)}).to_zarr(tmp_path / name, consolidated=False)
    return tmp_path / name


def _changed(a, i, value):
    a = np.array(a, copy=True)
    a[i] = value
    return a


@pytest.mark.parametrize("what, words", [
    ("theta_i", "variable theta_i[3]: 120.0 is outside [0, 90] degrees"),
    ("phi_o", "variable phi_o[3]: NaN is not allowed"),
    ("band", "variable band[3] = 7 is not a band index: the data has 2 bands"),
    ("wavelength_nm", "variable wavelength_nm[0]: -5.0 is not a positive wavelength"),
    ("empty", "no texels or no samples (y = 0)"),
    ("few", "2 samples, 3 free parameters"),
])
def test_texel_geometry_is_checked_as_every_reader_checks_it(texels, tmp_path, what, words):
    """What the CSV reader refuses, a texel store refuses too, with one error line and no traceback."""
    geometry, values = texels
    if what == "empty":
        path = _store(tmp_path, geometry, values[:0])
    elif what == "few":
        path = _store(tmp_path, geometry, values[..., :2], **{k: getattr(geometry, k)[:2] for k in ("theta_i", "phi_i", "theta_o", "phi_o", "band")})
    elif what == "wavelength_nm":
        path = _store(tmp_path, geometry, values, wavelength_nm=np.array([-5.0, 650.0]))
    else:
        path = _store(tmp_path, geometry, values, **{what: _changed(getattr(geometry, what), 3, {"theta_i": 120.0, "phi_o": np.nan, "band": 7}[what])})
    got = CliRunner().invoke(app, ["fit", str(path), "-o", str(tmp_path / "maps.zarr"), "--workers", "1", "-q", "--no-diffuse"])
    assert got.exit_code == 2 and "Traceback" not in got.output, got.output
    errors = [ln for ln in got.output.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1 and words in errors[0] and str(path) in errors[0], got.output


def test_a_corrupt_chunk_is_one_error_naming_its_rows(client, texels, tmp_path):
    geometry, values = texels
    path = _store(tmp_path, geometry, values)
    chunks = [f for f in (path / "values").rglob("*") if f.is_file() and not f.name.startswith(".") and not f.name.endswith(".json")]
    assert chunks
    for f in chunks:
        f.write_bytes(b"garbage" * 10)
    with pytest.raises(TexelMapError, match=r"in.zarr, rows 0–1: .*"):
        ctfit.fit_texel_maps(path, tmp_path / "maps.zarr", ST, client, chunk=2 * W)


def test_an_image_smaller_than_a_chunk_is_fitted_without_padding(texels, tmp_path, monkeypatch):
    """A chunk of rows is padded to the chunk's row count so that every chunk runs one program, but
    an image of fewer rows than a chunk holds is one chunk of its own size: 20 texels fitted as
    20, not as the 4,096 of the default chunk (3 texels took 140 s instead of 8)."""
    from distributed import Client

    import ctfit._fitting.texels as texels_module
    from ctfit._runtime import cluster

    geometry, values = texels
    dataset(geometry, values, ("y", "x")).to_zarr(tmp_path / "in.zarr", consolidated=False)
    fitted, real = [], texels_module.fit_texels
    monkeypatch.setattr(texels_module, "fit_texels", lambda data, v, *a, **k: fitted.append(len(v)) or real(data, v, *a, **k))
    monkeypatch.setattr(cluster, "_prepared", {False, True})  # this process is the worker: leave its JAX set-up as it is
    with Client(processes=False, n_workers=1, threads_per_worker=1, dashboard_address=":0") as c:
        maps = ctfit.fit_texel_maps(tmp_path / "in.zarr", tmp_path / "maps.zarr", ST, c)
    assert fitted == [H * W]
    assert maps["m"].shape == (H, W, 1) and (maps["status"].values == 0).all()


def test_an_rgb_store_writes_its_channels_without_a_zarr_warning(texels, tmp_path, monkeypatch):
    """Channels R, G (an attribute of the store): the maps' ``channel`` coordinate is written as
    variable-length text. As fixed-width text Zarr v3 warned ("FixedLengthUTF32 … does not have a
    Zarr V3 specification"), an error under this suite's warning filter."""
    from distributed import Client

    from ctfit._runtime import cluster

    geometry, values = texels
    ds = dataset(geometry, values, ("y", "x")).drop_vars("wavelength_nm")
    ds.attrs["channels"] = "R,G"
    ds.to_zarr(tmp_path / "rgb.zarr", consolidated=False)
    monkeypatch.setattr(cluster, "_prepared", {False, True})
    with Client(processes=False, n_workers=1, threads_per_worker=1, dashboard_address=":0") as c:
        maps = ctfit.fit_texel_maps(tmp_path / "rgb.zarr", tmp_path / "maps.zarr", ST, c)
    assert (maps["status"].values == 0).all()
    assert xr.open_zarr(tmp_path / "maps.zarr", consolidated=False)["channel"].values.tolist() == ["R", "G"]
