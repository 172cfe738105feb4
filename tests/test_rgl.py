"""RGL material database ``.bsdf`` files: the reader's measured points against Mitsuba 3's
``measured`` plugin, bad files, and a fit that recovers the BRDF the file was made from.

The database has no redistribution licence, so the tests write their own tensor files (a small
writer after Mitsuba's ``tensor_io.py``) from a known Cook–Torrance material through the
database's parameterisation: ``ndf`` and ``sigma`` tables, a ``vndf`` per incident direction,
and values on the sample-space grid whose nodes the VNDF warp sends to the measured points. The
builder places the material's values at the nodes with the reader's own warp
(``marginal_sample``); the comparisons with Mitsuba's ``eval`` and ``sample`` are what check it.
"""

import json
import pathlib
import struct
import tempfile

import numpy as np
import pytest
from typer.testing import CliRunner

import ctfit
from ctfit._io import bilinear, marginal_sample
from ctfit.cli import app

mi = pytest.importorskip("mitsuba")

ALPHA = 0.3  # Beckmann roughness of the material the files are made from (ctfit's m)
THETA_I = (0.0, 25.0, 50.0, 70.0)
N = 6  # sample-space grid: N × N measured points per incident direction
SPECTRAL_NM = np.array([360.0, 520.0, 680.0, 840.0, 1000.0])
RGB_F0 = (0.9, 0.6, 0.3)
S = 0.9  # specular share


def write_tensor(path, **fields):
    """A Mitsuba tensor file (``tensor_io.write``): header, field descriptions, 8-byte aligned data."""
    codes = {np.dtype("u1"): 1, np.dtype("<f4"): 10}
    arrays = {k: np.ascontiguousarray(v) for k, v in fields.items()}
    head = b"tensor_file\0" + struct.pack("<BBI", 1, 0, len(arrays))
    offset = len(head) + sum(13 + len(k) + 8 * a.ndim for k, a in arrays.items())
    offset += -offset % 8
    descriptions, data = [], []
    for k, a in arrays.items():
        descriptions.append(struct.pack("<H", len(k)) + k.encode() + struct.pack("<HBQ", a.ndim, codes[a.dtype], offset)
                            + struct.pack(f"<{a.ndim}Q", *a.shape))
        data.append(a.tobytes() + b"\0" * (-a.nbytes % 8))
        offset += a.nbytes + (-a.nbytes % 8)
    blob = head + b"".join(descriptions)
    with open(path, "wb") as f:
        f.write(blob + b"\0" * (-len(blob) % 8) + b"".join(data))


def material(spectral: bool):
    """A Beckmann lobe with Mitsuba's Smith G1 and a diffuse part R_d = F0/π (so that neighbouring
    points differ by less than the float32 precision of Mitsuba's interpolation can resolve)."""
    st = ctfit.Structure(lobes=1, geometry="smith-rational", diffuse="F0/pi")
    one = dict(m=np.array([ALPHA]), w=np.ones(1), s=np.array(S))
    if spectral:
        return ctfit.Material(st, ctfit.Params(**one, f0=np.linspace(0.2, 0.8, len(SPECTRAL_NM))), wavelength_nm=SPECTRAL_NM)
    return ctfit.Material(st, ctfit.Params(**one, f0=np.array(RGB_F0)), channels=("R", "G", "B"))


def beckmann(theta_m, phi_m, ax, ay):
    """The normalised (anisotropic) Beckmann D of a normal at (θ_m, φ_m); 0 on the horizon."""
    c = np.cos(theta_m)
    ok = c > 1e-9
    t2 = np.where(ok, np.tan(np.where(ok, theta_m, 0.0)), 0.0) ** 2
    e = t2 * (np.cos(phi_m) ** 2 / ax**2 + np.sin(phi_m) ** 2 / ay**2)
    return np.where(ok, np.exp(-e) / (np.pi * ax * ay * np.where(ok, c, 1.0) ** 4), 0.0)


def unit(theta, phi):
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta) + 0 * phi], axis=-1)


def rgl_fields(spectral=False, phi_i=(0.0,), anisotropy=1.0, shape=(5, 9)):
    """The fields of an RGL file of :func:`material` (anisotropy ≠ 1: an anisotropic NDF and a
    BRDF that depends on the half vector's azimuth)."""
    mat = material(spectral)
    ax, ay = ALPHA, ALPHA * anisotropy
    iso = len(phi_i) <= 2
    ux, uy = np.meshgrid(np.linspace(0, 1, shape[1]), np.linspace(0, 1, shape[0]))  # (φ, θ) tables
    theta_m, phi_m = ux**2 * np.pi / 2, (2 * uy - 1) * np.pi
    ndf = beckmann(theta_m, phi_m, ax, ay)
    ndf += 0.01 * ndf.max()  # a floor, as measured tables have
    sigma = np.cos(theta_m) + 0.2 * np.sin(theta_m)  # any positive projected area: the values compensate
    theta_i, phi_i = np.radians(THETA_I).astype(np.float32), np.asarray(phi_i, np.float32)
    g = np.linspace(0, 1, N)
    nodes = np.stack([np.tile(g, N), np.repeat(g, N)], axis=1)
    bands = len(SPECTRAL_NM) if spectral else 3
    vndf = np.zeros((len(phi_i), len(theta_i), *shape))
    values = np.zeros((len(phi_i), len(theta_i), bands, N, N))
    for p, ph in enumerate(phi_i.astype(float)):
        for t, th in enumerate(theta_i.astype(float)):
            ph_seen = 0.0 if th == 0 else ph
            wi = unit(th, ph_seen)
            m = unit(theta_m, phi_m + (ph_seen if iso else 0.0))
            vndf[p, t] = np.maximum(m @ wi, 0) * ndf * 2 * np.pi**2 * ux * np.sin(theta_m)
            u_m = marginal_sample(vndf[p, t].astype(np.float32), nodes)
            mn = unit(u_m[:, 0] ** 2 * np.pi / 2, (2 * u_m[:, 1] - 1) * np.pi + (ph_seen if iso else 0.0))
            wo = 2 * (mn @ wi)[:, None] * mn - wi
            f = ctfit.evaluate_at(mat, l=np.broadcast_to(wi, wo.shape), v=wo)  # (N², bands)
            if anisotropy != 1:
                h = (wi + wo) / np.linalg.norm(wi + wo, axis=1, keepdims=True)
                f = f * (1 + 2 * h[:, :1] ** 2)
            u_wi = np.array([[np.sqrt(th * 2 / np.pi), (ph_seen + np.pi) / (2 * np.pi)]])
            d = bilinear(ndf.astype(np.float32), u_m)
            scale = np.where((wo[:, 2] > 0) & (d > 0), wo[:, 2] * 4 * bilinear(sigma.astype(np.float32), u_wi) / np.where(d > 0, d, 1), 0)
            values[p, t] = (f * scale[:, None]).T.reshape(bands, N, N)
    fields = dict(description=np.frombuffer("test material, ✓ made by tests/test_rgl.py".encode(), np.uint8),
                  jacobian=np.array([1], np.uint8), theta_i=theta_i, phi_i=phi_i, ndf=ndf.astype(np.float32),
                  sigma=sigma.astype(np.float32), vndf=vndf.astype(np.float32),
                  luminance=np.ones((len(phi_i), len(theta_i), N, N), np.float32))
    if spectral:
        return dict(fields, wavelengths=SPECTRAL_NM.astype(np.float32), spectra=values.astype(np.float32))
    return dict(fields, rgb=values.astype(np.float32))


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("rgl")
    out = {}
    for name, kw in {"rgb": {}, "spec": dict(spectral=True), "aniso": dict(phi_i=np.linspace(-np.pi, np.pi, 5), anisotropy=2.0)}.items():
        out[name] = d / f"material_{name}.bsdf"
        write_tensor(out[name], **rgl_fields(**kw))
    return out


def mitsuba_brdf(path, data: ctfit.Measurement, variant: str):
    """Mitsuba's ``measured`` plugin at every sample's directions, divided by cos θ_o."""
    mi.set_variant(variant)
    bsdf = mi.load_dict({"type": "measured", "filename": str(path)})
    ctx = mi.BSDFContext()
    t_i, p_i, t_o, p_o = (np.radians(a) for a in (data.theta_i, data.phi_i, data.theta_o, data.phi_o))
    out = np.empty(len(data))
    for k in range(len(data)):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*unit(t_i[k], p_i[k]))
        if data.wavelength_nm is not None:
            si.wavelengths = mi.Spectrum(float(data.wavelength_nm[data.band[k]]))
        value = bsdf.eval(ctx, si, mi.Vector3f(*unit(t_o[k], p_o[k])))
        out[k] = np.asarray(value)[0 if data.wavelength_nm is not None else data.band[k]] / np.cos(t_o[k])
    return out


@pytest.mark.parametrize("name, variant", [("rgb", "scalar_rgb"), ("spec", "scalar_spectral")])
def test_measured_points_match_mitsuba(files, name, variant):
    data = ctfit.read_rgl(files[name])
    assert data.meta["format"] == "RGL" and data.meta["description"] == "test material, ✓ made by tests/test_rgl.py"
    assert (data.channels == ("R", "G", "B")) if name == "rgb" else np.array_equal(data.wavelength_nm, SPECTRAL_NM)
    n_bands = 3 if name == "rgb" else len(SPECTRAL_NM)
    kept = len(THETA_I) * N * N - int(data.meta["rgl_points_at_horizon"])
    assert len(data) == kept * n_bands and int(data.meta["rgl_points_at_horizon"]) >= len(THETA_I) * N  # u₁ = 1: θ_m = 90°
    reference = mitsuba_brdf(files[name], data, variant)
    np.testing.assert_allclose(data.brdf, reference, rtol=1e-4, atol=0)
    # ... and they are the material the file was made from, at the measured points
    np.testing.assert_allclose(data.brdf, ctfit.evaluate(material(name == "spec"), data), rtol=2e-5)


def test_the_points_are_where_mitsuba_samples_the_nodes(files):
    """Each stored node is one direction pair, the one Mitsuba's own sampling sends the node to
    (its luminance table is uniform here, so ``sample`` warps the node by the VNDF alone)."""
    data = ctfit.read_rgl(files["rgb"])
    assert np.array_equal(data.band, np.tile([0, 1, 2], len(data) // 3))  # the bands of a node are consecutive
    mi.set_variant("scalar_rgb")
    bsdf = mi.load_dict({"type": "measured", "filename": str(files["rgb"])})
    expected = []
    for theta in np.radians(THETA_I).astype(np.float32):
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*unit(float(theta), 0.0))
        for j in range(N):
            for k in range(N):
                bs, _ = bsdf.sample(mi.BSDFContext(), si, 0.0, mi.Point2f(j / (N - 1), k / (N - 1)))  # Mitsuba swaps u₁, u₂
                if bs.wo[2] >= 0.01:
                    expected.append(np.array(bs.wo))
    viewers = unit(np.radians(data.theta_o[::3]), np.radians(data.phi_o[::3]))
    assert len(viewers) == len(expected) == len(data.directions()[0])
    # At θ_i = 0 this Mitsuba may turn the viewer by 180° about the normal (measured.cpp leaves
    # its symmetry fold, m_reduction, uninitialised for isotropic files; the fold and then
    # atan2(−0, −0) = 0 turn the frame); the authors' reference code (powitacq) and ctfit do not.
    # Under normal incidence an isotropic BRDF is the same either way: compared up to that turn.
    normal = data.theta_i[::3] == 0
    expected = np.array(expected)
    expected[normal, :2] *= np.sign(expected[normal, :2]) * np.sign(viewers[normal, :2])
    np.testing.assert_allclose(viewers, expected, atol=2e-5)


def test_anisotropic_files_are_refused_or_read_by_choice(files):
    with pytest.raises(ctfit.DataError, match=r"material_aniso\.bsdf: anisotropic BRDF: 5 incident azimuths φ_i from -180° to 180°.*anisotropic=True"):
        ctfit.read_rgl(files["aniso"])
    data = ctfit.read_measurement(files["aniso"], anisotropic=True)
    assert data.meta["rgl_isotropic"] == "false" and data.meta["rgl_normal_incidence_slices_skipped"] == "4"
    assert len(np.unique(data.phi_i.round(3))) == 4  # −180° and 180° are one azimuth (to float32 π)
    np.testing.assert_allclose(data.brdf, mitsuba_brdf(files["aniso"], data, "scalar_rgb"), rtol=1e-4, atol=0)
    r = CliRunner().invoke(app, ["fit", str(files["aniso"])])
    assert r.exit_code == 2 and r.output.count("error:") == 1 and "anisotropic BRDF" in r.output and "Traceback" not in r.output


@pytest.mark.parametrize("suffix", [".bsdf", ".dat", ""])
def test_recognised_by_content(files, tmp_path, suffix):
    path = tmp_path / f"copy{suffix}"
    path.write_bytes(files["rgb"].read_bytes())
    assert ctfit.read_measurement(path).meta["format"] == "RGL"


def test_invalid_cells_are_dropped(tmp_path):
    fields = rgl_fields()
    valid = np.ones(fields["luminance"].shape, np.uint8)
    valid[0, 1, 2, :] = 0  # one row of sample space at θ_i = 25°
    write_tensor(tmp_path / "all.bsdf", **fields)
    write_tensor(tmp_path / "some.bsdf", **fields, valid=valid)
    whole, some = ctfit.read_rgl(tmp_path / "all.bsdf"), ctfit.read_rgl(tmp_path / "some.bsdf")
    assert some.meta["rgl_invalid_cells"] == str(N)
    dropped = {tuple(r) for r in np.round(whole.directions()[0], 9)} - {tuple(r) for r in np.round(some.directions()[0], 9)}
    assert len(dropped) == N - 1 and {round(r[0], 6) for r in dropped} == {25.0}  # the row's last node is below the horizon


def test_negative_rgb_values_are_dropped_with_a_warning(tmp_path):
    fields = rgl_fields()
    fields["rgb"][0, 2, 1, 1, :3] = -0.01  # G channel, three nodes at θ_i = 50°
    write_tensor(tmp_path / "neg.bsdf", **fields)
    with pytest.warns(ctfit.DataWarning, match=r"neg\.bsdf: 3 negative values dropped"):
        data = ctfit.read_rgl(tmp_path / "neg.bsdf")
    assert data.meta["rgl_negative_values"] == "3" and data.brdf.min() >= 0
    write_tensor(tmp_path / "pos.bsdf", **rgl_fields())
    assert len(ctfit.read_rgl(tmp_path / "pos.bsdf")) == len(data) + 3


@pytest.mark.parametrize(
    "change, pattern",
    [
        (lambda raw, f: raw[: len(raw) - 100], r"truncated: field 'rgb' \(float32, shape \(1, 4, 3, 6, 6\)\) takes bytes \d+–\d+, the file has \d+ bytes"),
        (lambda raw, f: raw[:30], r"truncated: the header ends at byte 30"),
        (lambda raw, f: b"TENSOR" + raw[6:], r"not a tensor file: it does not start with 'tensor_file\\0'"),
        (lambda raw, f: raw[:12] + b"\x02" + raw[13:], r"tensor file version 2\.0: only version 1\.0 is known"),
        (lambda raw, f: _rewritten(f, rgb=None, unknown=np.zeros(2, np.float32)), r"a tensor file, but not an RGL BRDF: no field 'rgb'"),
        (lambda raw, f: _rewritten(f, rgb=f["rgb"][:, :, :2]), r"field 'rgb' is float32 of shape \(1, 4, 2, 6, 6\); an RGL BRDF has float32 with 5 axes of "
                                                               r"shape \(1, 4, 3, 6, 6\)"),
        (lambda raw, f: _rewritten(f, theta_i=f["theta_i"].astype(np.uint8)), r"field 'theta_i' is uint8"),
        (lambda raw, f: _rewritten(f, rgb=np.where(np.arange(6) == 3, np.nan, f["rgb"]).astype(np.float32)),
         r"field 'rgb', index \(0, 0, 0, 0, 3\): nan is not a finite number"),
        (lambda raw, f: _rewritten(f, vndf=-f["vndf"]), r"field 'vndf' has negative values: it is a density"),
        (lambda raw, f: _rewritten(f, theta_i=np.concatenate([[-0.0174533], f["theta_i"][1:]]).astype(np.float32)),  # (an IndexError)
         r"field 'theta_i', index 0: -0.0174533 rad \(-1°\) is not an incident direction above the surface \(0 to π/2 rad\)"),
        (lambda raw, f: _rewritten(f, vndf=np.concatenate([f["vndf"][:, :1], 0 * f["vndf"][:, 1:2], f["vndf"][:, 2:]], axis=1)),  # (an IndexError)
         r"field 'vndf', slice \(phi_i 0, theta_i 1\) is 0 everywhere: a density that places no measured point"),
        (lambda raw, f: _rewritten(f, sigma=0 * f["sigma"]),  # (values of inf, and NumPy's divide-by-zero warning)
         r"field 'sigma' is 0 at the light of slice \(phi_i 0, theta_i 0\): a projected area that divides the values"),
        (lambda raw, f: _with_shape(raw, "rgb", (1, 2, 3, 2**31, 2**31)),  # 24 · 2⁶⁴ bytes: 0 in NumPy's int64 (a reshape error, no file named)
         r"truncated: field 'rgb' \(float32, shape \(1, 2, 3, 2147483648, 2147483648\)\) takes bytes \d+–110680464442257\d+, the file has"),
    ],
)
def test_bad_files_give_one_error(tmp_path, change, pattern):
    fields = rgl_fields()
    write_tensor(tmp_path / "good.bsdf", **fields)
    bad = tmp_path / "bad.bsdf"
    bad.write_bytes(change((tmp_path / "good.bsdf").read_bytes(), fields))
    with pytest.raises(ctfit.DataError, match=r"bad\.bsdf: " + pattern):
        ctfit.read_rgl(bad)
    r = CliRunner().invoke(app, ["fit", str(bad)])
    assert r.exit_code == 2 and r.output.count("error:") == 1 and "bad.bsdf" in r.output and "Traceback" not in r.output


def _with_shape(raw: bytes, name: str, shape: tuple) -> bytes:
    """``raw`` with field ``name``'s declared shape replaced (as many axes as it had)."""
    at = raw.index(struct.pack("<H", len(name)) + name.encode()) + 2 + len(name)
    ndim = struct.unpack_from("<H", raw, at)[0]
    assert ndim == len(shape)
    start = at + 11  # ndim, code, offset
    return raw[:start] + struct.pack(f"<{ndim}Q", *shape) + raw[start + 8 * ndim:]


def _rewritten(fields, **changes):
    new = {k: v for k, v in {**fields, **changes}.items() if v is not None}
    with tempfile.TemporaryDirectory() as d:
        write_tensor(pathlib.Path(d) / "x.bsdf", **new)
        return (pathlib.Path(d) / "x.bsdf").read_bytes()


@pytest.mark.slow
def test_fit_recovers_the_material_and_its_colour(files, tmp_path):
    """``ctfit fit`` on a spectral file (360–1000 nm) recovers m, s and F0(λ) across the whole band;
    its colour (from the visible part, 360–830 nm) is the material's. A folder's .bsdf files are fitted."""
    fits, folder = tmp_path / "fits", tmp_path / "materials"
    folder.mkdir()
    (folder / "material_spec.bsdf").write_bytes(files["spec"].read_bytes())
    r = CliRunner().invoke(app, ["fit", str(folder), "--geometry", "smith-rational", "--diffuse", "F0/pi", "--lobes", "1", "-o", str(fits)])
    assert r.exit_code == 0, r.output
    out = fits / "material_spec.fit.json"  # a folder's results: a folder (with summary.json)
    fitted, truth = ctfit.load_material(out), material(spectral=True)
    np.testing.assert_array_equal(fitted.wavelength_nm, SPECTRAL_NM)
    np.testing.assert_allclose(fitted.params.m, [ALPHA], rtol=1e-3)
    np.testing.assert_allclose(fitted.params.s, S, rtol=1e-3)
    np.testing.assert_allclose(fitted.params.f0, truth.params.f0, rtol=1e-3)
    r = CliRunner().invoke(app, ["color", str(out), "--json"])
    assert r.exit_code == 0, r.output
    colour = json.loads(r.output)
    np.testing.assert_allclose(colour["xy"], ctfit.colour_report(truth)["xy"], atol=1e-5)
