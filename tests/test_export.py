"""``ctfit export``: Mitsuba 3 (evaluated by Mitsuba itself), MERL (read by a second reader), glTF.

Mitsuba's ``eval`` returns the BRDF × cos θ_o (the cosine is divided out here); it evaluates in
float32. The hemisphere grid of the approximation error is rebuilt here from ``docs/export.md``.
"""

import dataclasses
import json
import re
import struct
import warnings

import numpy as np
import pytest
from typer.testing import CliRunner

import ctfit
from ctfit._export.rgb_bands import band_to_rgb, rgb_material
from ctfit.cli import app

runner = CliRunner()
RGB = ("R", "G", "B")


def grid():
    """docs/export.md: θ_i, θ_o ∈ {5°, 15°, …, 85°}, φ_i = 0, φ_o ∈ {0°, 20°, …, 340°}."""
    theta = np.arange(5.0, 86.0, 10.0)
    ti, to, po = (a.reshape(-1) for a in np.meshgrid(theta, theta, np.arange(0.0, 341.0, 20.0), indexing="ij"))
    return ti, np.zeros_like(ti), to, po


def relative(target, fit):
    keep = fit >= 1e-6 * fit.max()
    rel = np.abs(target[keep] - fit[keep]) / fit[keep]
    return float(np.median(rel)), float(rel.max())


def ctfit_values(mat, angles, **kw):
    ti, pi, to, po = angles
    return np.asarray(ctfit.evaluate_at(mat, theta_i=ti, phi_i=pi, theta_o=to, phi_o=po, **kw), float)


def unit(theta_deg, phi_deg):
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def mitsuba_values(bsdf, angles, wavelengths=None):
    """Mitsuba's BRDF at each direction pair (its eval over cos θ_o), one scalar call each."""
    import mitsuba as mi

    out = []
    ctx, frame = mi.BSDFContext(), mi.Frame3f(mi.Vector3f(0, 0, 1))
    for l, v in zip(unit(angles[0], angles[1]), unit(angles[2], angles[3])):
        si = mi.SurfaceInteraction3f()
        si.sh_frame, si.wi = frame, mi.Vector3f(*l)
        if wavelengths is not None:
            si.wavelengths = wavelengths
        out.append(np.asarray(bsdf.eval(ctx, si, mi.Vector3f(*v)), float) / v[2])
    return np.array(out)


def metal(geometry="smith-rational", **structure):
    st = ctfit.Structure(lobes=2, geometry=geometry, diffuse="F0/pi", **structure)
    return ctfit.Material(st, ctfit.Params(s=np.array(0.8), m=np.array([0.15, 0.4]), w=np.array([0.7, 0.3]), f0=np.array([0.9, 0.6, 0.3])),
                          channels=RGB, name="metal")


def conductor():
    st = ctfit.Structure(geometry="smith-rational", fresnel="conductor", normalization="cook-torrance-1982")
    return ctfit.Material(st, ctfit.Params(m=np.array([0.25]), w=np.ones(1), n=np.array([0.2, 0.5, 1.3]), k=np.array([3.5, 2.5, 2.0])), channels=RGB)


def plastic(diffuse="transmitted", geometry="smith-rational", s=0.3):
    st = ctfit.Structure(family="plastic", geometry=geometry, diffuse=diffuse)
    return ctfit.Material(st, ctfit.Params(s=np.array(s), m=np.array([0.2]), w=np.ones(1), n=np.array(1.5), rd=np.array([0.2, 0.1, 0.05])),
                          channels=RGB, name="plastic")


@pytest.mark.mitsuba
@pytest.mark.parametrize("make", [metal, conductor, plastic, lambda: plastic("spectrum")], ids=["metal", "conductor", "plastic", "lambertian-plastic"])
def test_smith_rational_materials_are_mitsubas_exactly(make, tmp_path):
    """The XML (``mi.load_file``) and the dict (``mi.load_dict``) evaluate to ctfit's BRDF to 1e-4
    relative over the hemisphere grid, and the export says it is exact."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    mat = make()
    result = ctfit.export_material(mat, to="mitsuba", path=tmp_path / "m.xml")
    as_dict = json.loads(ctfit.export_material(mat, to="mitsuba-dict").content)
    assert result.error["exact"] and as_dict["ctfit_export"]["exact"]
    ours = ctfit_values(mat, grid())
    for bsdf in (mi.load_file(str(tmp_path / "m.xml")), mi.load_dict(as_dict["bsdf"])):
        assert relative(mitsuba_values(bsdf, grid()), ours)[1] < 1e-4


@pytest.mark.mitsuba
def test_a_spectral_material_is_exact_in_mitsubas_spectral_variant():
    """Spectra become ``spectrum`` λ:value lists (held at the end values beyond them, as ctfit does)."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_spectral")
    wl = np.arange(400.0, 701.0, 20.0)
    st = ctfit.Structure(geometry="smith-rational", fresnel="conductor", diffuse="spectrum")
    mat = ctfit.Material(st, ctfit.Params(s=np.array(0.9), m=np.array([0.3]), w=np.ones(1), n=np.linspace(0.2, 1.2, wl.size),
                                          k=np.linspace(2.0, 4.0, wl.size), rd=np.linspace(0.01, 0.2, wl.size)), wavelength_nm=wl)
    bsdf = mi.load_string(ctfit.export_material(mat, to="mitsuba").content)
    at = [380.0, 455.0, 610.0, 760.0]  # between and beyond the listed wavelengths
    angles = [a[::7] for a in grid()]
    assert relative(mitsuba_values(bsdf, angles, at), ctfit_values(mat, angles, wavelength_nm=at))[1] < 1e-4


@pytest.mark.mitsuba
def test_roughplastic_is_not_the_transmitted_plastic_but_its_specular_part_is():
    """Mitsuba's ``roughplastic`` with ``specular_reflectance = s`` is ctfit's s R_s exactly, but its
    diffuse part uses rough transmittance tables: the difference from ctfit's transmitted diffuse
    term (the smooth interface's, Mitsuba's ``plastic``) is why the export uses ``plastic`` for it."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    mat = plastic()
    s, rho = 0.3, np.pi * 0.7 * np.array([0.2, 0.1, 0.05])

    def rough(diffuse):
        return mi.load_dict({"type": "roughplastic", "distribution": "beckmann", "alpha": 0.2, "int_ior": 1.5, "ext_ior": 1.0,
                             "nonlinear": False, "specular_reflectance": s, "diffuse_reflectance": {"type": "rgb", "value": list(diffuse)}})

    specular = ctfit.Material(ctfit.Structure(family="plastic", geometry="smith-rational"), ctfit.Params(m=np.array([0.2]), w=np.ones(1), n=np.array(1.5)),
                              channels=RGB)
    assert relative(mitsuba_values(rough([0.0, 0.0, 0.0]), grid()), s * ctfit_values(specular, grid()) * np.ones(3))[1] < 1e-4
    median, worst = relative(mitsuba_values(rough(rho), grid()), ctfit_values(mat, grid()))
    assert median > 1e-3 and worst > 0.1  # docs/export.md gives the figures


def _printed(line):
    found = re.search(r"median (\S+) %, max (\S+) %", line)
    return float(found[1]) / 100, float(found[2]) / 100


@pytest.mark.mitsuba
def test_the_printed_error_of_the_default_v_cavity_structure_is_right(tmp_path):
    """``ctfit export`` of a default-structure material (V-cavity G): the printed median and maximum
    equal those of Mitsuba's evaluation of the written XML against ctfit, recomputed here."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    (tmp_path / "gold.toml").write_text('name = "gold"\ns = 1\nlobes = [{ m = 0.3 }]\nchannels = ["R", "G", "B"]\nF0 = [0.9, 0.7, 0.3]\n')
    r = runner.invoke(app, ["export", str(tmp_path / "gold.toml"), "--to", "mitsuba", "-o", str(tmp_path / "gold.xml")])
    assert r.exit_code == 0, r.output
    assert len(r.stdout.strip().splitlines()) == 1 and "approximate (Mitsuba's G is Smith's rational G1, not the v-cavity G)" in r.stdout
    xml = (tmp_path / "gold.xml").read_text()
    assert r.stdout.strip() in xml  # the XML keeps the line in a comment
    mat = ctfit.load_material(tmp_path / "gold.toml")
    assert mat.structure == ctfit.Structure()
    median, worst = relative(mitsuba_values(mi.load_string(xml), grid()), ctfit_values(mat, grid()))
    printed = _printed(r.stdout)
    assert printed[1] == pytest.approx(worst, rel=2e-3) and worst > 0.05
    assert printed[0] == pytest.approx(median, rel=2e-3, abs=1e-5)


def _mitsuba_sphere(tree, light, seed, size=32, spp=64):
    import mitsuba as mi

    return np.asarray(mi.render(mi.load_dict({
        "type": "scene", "integrator": {"type": "direct"},
        "sensor": {"type": "orthographic", "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 3], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "sphere": {"type": "sphere", "radius": 0.92, "bsdf": tree},  # ctfit's sphere (RADIUS) in the [−1, 1] view
        "light": {"type": "directional", "direction": [-c for c in light], "irradiance": {"type": "rgb", "value": [1, 1, 1]}},
    }), seed=seed), float)


def _ctfit_sphere(mat, light, size=32, supersample=8):
    scene = ctfit.render_scene(mat, directions=[tuple(light)], solid_angles=[1.0], ambient=0.0)
    surf = ctfit.surface_normals("sphere", size, supersample)
    rgb = np.asarray(ctfit.shade_linear(mat.structure, scene, surf.normal), float) * surf.mask[..., None]
    return rgb.reshape(size, supersample, size, supersample, 3).mean(axis=(1, 3))


@pytest.mark.mitsuba
def test_a_sphere_rendered_by_mitsuba_matches_ctfits_render():
    """32 × 32 sphere, orthographic camera, one directional light of irradiance 1 (ctfit: one light
    of unit solid angle, no ambient), ctfit averaging 8 × 8 samples per pixel, Mitsuba 64 random
    ones. Mitsuba's noise is measured by a second render with another seed: ctfit differs from the
    mean of the two by less than their difference, and a material 10 % less specular does not."""
    pytest.importorskip("mitsuba").set_variant("scalar_rgb")
    light = np.array([0.75, 0.25, 0.61]) / np.linalg.norm([0.75, 0.25, 0.61])
    mat = plastic(s=0.4)
    tree = json.loads(ctfit.export_material(mat, to="mitsuba-dict").content)["bsdf"]
    a, b = _mitsuba_sphere(tree, light, 0), _mitsuba_sphere(tree, light, 1)
    noise = np.abs(a - b).mean()
    assert 0 < noise < 1e-2 * a.max()
    assert np.abs(_ctfit_sphere(mat, light) - (a + b) / 2).mean() < noise
    assert np.abs(_ctfit_sphere(plastic(s=0.36), light) - (a + b) / 2).mean() > 3 * noise


def read_merl_independently(path):
    """A MERL reader from the format description (Matusik et al. 2003, MERL's BRDFRead.cpp), not
X
    look-ups at the lower cell edges, θ_h with its square-root spacing."""
    with open(path, "rb") as f:
        dims = struct.unpack("<3i", f.read(12))
        data = np.frombuffer(f.read(), "<f8")
    n = dims[0] * dims[1] * dims[2]
    assert dims == (90, 90, 180) and data.size == 3 * n
    scale = (1.0 / 1500, 1.15 / 1500, 1.66 / 1500)

    def lookup(theta_h, theta_d, phi_d):  # radians, φ_d in [0, π)
        ih = min(int(np.sqrt(theta_h / (np.pi / 2)) * 90), 89) if theta_h > 0 else 0
        id_ = min(int(theta_d / (np.pi / 2) * 90), 89)
        ip = min(int(phi_d / np.pi * 180), 179)
        i = ip + id_ * 180 + ih * 180 * 90
        return np.array([data[i] * scale[0], data[i + n] * scale[1], data[i + 2 * n] * scale[2]])

    return lookup


@pytest.mark.slow
def test_merl_export_reads_back_with_ctfit_and_an_independent_reader(tmp_path):
    """Every cell holds the model at its centre: ctfit's reader gives evaluate_at at each sample's
    directions, and a reader written here from the format finds the same values."""
    mat = plastic("spectrum", geometry="v-cavity")
    r = runner.invoke(app, ["export", str(_save(mat, tmp_path)), "--to", "merl", "-o", str(tmp_path / "p.binary")])
    assert r.exit_code == 0, r.output
    assert "merl: approximate (tabulated in 90 × 90 × 180 cells of linear sRGB)" in r.stdout
    m = ctfit.read_merl(tmp_path / "p.binary")
    k = np.random.default_rng(1).choice(len(m), 3000, replace=False)
    expected = ctfit_values(mat, (m.theta_i[k], m.phi_i[k], m.theta_o[k], m.phi_o[k]))[np.arange(k.size), m.band[k]]
    np.testing.assert_allclose(m.brdf[k], expected, rtol=1e-9)
    lookup = read_merl_independently(tmp_path / "p.binary")
    rng = np.random.default_rng(2)
    for i, j, kk in zip(rng.integers(0, 60, 40), rng.integers(0, 45, 40), rng.integers(0, 180, 40)):  # θ_h < 40°, θ_d < 45°
        th, td, pd = np.pi / 2 * ((i + 0.5) / 90) ** 2, np.pi / 2 * (j + 0.5) / 90, np.pi * (kk + 0.5) / 180  # the cell's centre
        angles = ctfit.half_diff_deg_to_angles_deg(*np.degrees([th, td, pd]))
        assert angles[0] < 90 and angles[2] < 90
        np.testing.assert_allclose(lookup(th, td, pd), ctfit_values(mat, angles), rtol=1e-9)


def _save(mat, folder):
    return ctfit.save_material_json(mat, folder / "material.json")


def test_gltf_is_a_minimal_gltf_2_material_with_the_error_it_prints(tmp_path):
    r = runner.invoke(app, ["export", str(_save(plastic(), tmp_path)), "--to", "gltf", "-o", str(tmp_path / "p.gltf")])
    assert r.exit_code == 0, r.output
    doc = json.loads((tmp_path / "p.gltf").read_text())
    assert doc["asset"]["version"] == "2.0" and set(doc["extensionsUsed"]) == {"KHR_materials_ior", "KHR_materials_specular"}
    (entry,) = doc["materials"]
    pbr = entry["pbrMetallicRoughness"]
    assert len(pbr["baseColorFactor"]) == 4 and all(0 <= c <= 1 for c in pbr["baseColorFactor"])
    assert pbr["metallicFactor"] == 0 and 0 < pbr["roughnessFactor"] <= 1 and entry["extensions"]["KHR_materials_ior"]["ior"] == 1.5
    assert entry["extensions"]["KHR_materials_specular"]["specularFactor"] == pytest.approx(0.3)
    error = entry["extras"]["ctfit_export"]
    assert not error["exact"] and _printed(r.stdout) == pytest.approx((error["median"], error["max"]), rel=2e-3)


def test_gltf_roughness_is_the_least_squares_ggx_fit_and_a_lambertian_surface_is_exact():
    from ctfit._export.gltf import fit_ggx_roughness

    rough = [fit_ggx_roughness(_one_lobe(m)) for m in (0.05, 0.2, 0.5)]
    assert rough == sorted(rough) and abs(rough[1] - np.sqrt(0.2)) < 0.1  # α_GGX ≈ m for narrow lobes
    matte = ctfit.Material(ctfit.Structure(lobes=0, diffuse="constant"), ctfit.Params(rd=np.array(0.2)), wavelength_nm=np.array([550.0]))
    result = ctfit.export_material(matte, to="gltf")
    assert result.error["max"] < 1e-12


def _one_lobe(m):
    return ctfit.Material(ctfit.Structure(geometry="smith"), ctfit.Params(m=np.array([m]), w=np.ones(1), f0=np.array([0.9])), channels=("G",))


def test_a_gaussian_lobe_and_the_papers_normalisation_say_what_is_approximate():
    result = ctfit.export_material(metal("smith-rational", distribution="gaussian"), to="mitsuba")
    assert result.error["approximations"] == ["Mitsuba has no Gaussian D: Beckmann with alpha = m"] and result.error["max"] > 0
    assert ctfit.export_material(conductor(), to="mitsuba").error["exact"]  # cook-torrance-1982: specular_reflectance 4


def test_bad_input_is_one_error_line(tmp_path):
    mat = _save(plastic(), tmp_path)
    for args, message in [(["--to", "obj"], "--to obj: not a format ctfit exports"), (["--to", "mitsuba", "-o", str(mat)], "")]:
        argv = ["export", str(mat), *args] + ([] if "-o" in args else ["-o", str(tmp_path / "x")])
        r = runner.invoke(app, argv)
        assert r.exit_code == 2 and r.output.startswith("error: ") and len(r.output.strip().splitlines()) == 1 and message in r.output
    assert json.loads(mat.read_text())["name"] == "plastic"  # the input is untouched


@pytest.mark.mitsuba
@pytest.mark.parametrize("diffuse", ["transmitted", "spectrum"])
def test_roughplastic_on_request_prints_the_error_mitsuba_measures(diffuse, tmp_path):
    """``--mitsuba-plastic roughplastic``: Mitsuba's own plastic plugin, and the line's figures are
    Mitsuba's evaluation of the written XML against ctfit, recomputed here."""
    mi = pytest.importorskip("mitsuba")
    mat = plastic(diffuse)
    r = runner.invoke(app, ["export", str(_save(mat, tmp_path)), "--to", "mitsuba", "--mitsuba-plastic", "roughplastic", "-o", str(tmp_path / "p.xml")])
    assert r.exit_code == 0, r.output
    assert "approximate (Mitsuba's roughplastic: rough transmittance tables in its diffuse term" in r.stdout
    mi.set_variant("scalar_rgb")
    xml = (tmp_path / "p.xml").read_text()
    assert '<bsdf type="roughplastic" version="3.0.0">' in xml
    median, worst = relative(mitsuba_values(mi.load_string(xml), grid()), ctfit_values(mat, grid()))
    assert _printed(r.stdout) == pytest.approx((median, worst), rel=2e-3) and median > 1e-3
    r = runner.invoke(app, ["export", str(_save(metal(), tmp_path)), "--to", "mitsuba", "--mitsuba-plastic", "roughplastic", "-o", str(tmp_path / "m.xml")])
    assert r.exit_code == 2 and r.output.startswith("error: ") and "roughplastic needs a plastic" in r.output


def test_gltf_ior_below_one_is_its_reciprocal(tmp_path):
    """KHR_materials_ior takes ior ≥ 1: an index below 1 (n = 0.8) is written as 1/n, which has the
    same f0 — all glTF's Schlick F uses — and the printed error is that of the file written."""
    from ctfit._export.gltf import gltf_material

    mat = ctfit.Material(ctfit.Structure(family="plastic", diffuse="spectrum"),
                         ctfit.Params(s=np.array(0.3), m=np.array([0.2]), w=np.ones(1), n=np.array(0.8), rd=np.array([0.1, 0.03, 0.02])),
                         channels=("R", "G", "B"))
    ior = gltf_material(mat)[0]["extensions"]["KHR_materials_ior"]["ior"]
    assert ior == pytest.approx(1.25) and ((ior - 1) / (ior + 1)) ** 2 == pytest.approx((0.2 / 1.8) ** 2)
    r = runner.invoke(app, ["export", str(_save(mat, tmp_path)), "--to", "gltf", "-o", str(tmp_path / "p.gltf")])
    assert r.exit_code == 0, r.output
    assert json.loads((tmp_path / "p.gltf").read_text())["materials"][0]["extensions"]["KHR_materials_ior"]["ior"] == pytest.approx(1.25)


def test_gltf_brdf_is_the_specifications_ggx():
    """glTF's lobe with F = 1 (metallic 1, white): at normal incidence and view V D = 1/(4 π α²);
    the directional albedo at 30° is just below 1 for a smooth surface and falls with roughness
    (single scattering; ≈ 0.8 at roughness 0.6, as the split-sum tables of real-time renderers)."""
    from scipy.integrate import dblquad

    from ctfit._export.gltf import gltf_brdf

    def white(rough):
        return {"pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 1.0, "roughnessFactor": rough}}

    peak = gltf_brdf(white(0.5), 0.0, 0.0, 0.0, 0.0)[0]
    assert peak == pytest.approx(1 / (4 * np.pi * 0.25**2), rel=1e-12)
    albedo = []
    for rough in (0.3, 0.6):
        f = lambda phi, theta: gltf_brdf(white(rough), 30.0, 0.0, np.degrees(theta), np.degrees(phi))[0] * np.cos(theta) * np.sin(theta)
        albedo.append(dblquad(f, 0, np.pi / 2, 0, 2 * np.pi, epsabs=1e-5)[0])
    assert 0.7 < albedo[1] < 0.9 and 0.97 < albedo[0] < 1.0


@pytest.mark.parametrize("to", ["mitsuba", "mitsuba-dict", "gltf"])
def test_a_material_named_after_a_file_that_is_not_utf8_is_exported(to, tmp_path):
    """A material file's name is its name when it has no ``name`` key; Python holds a name that
    is not UTF-8 as lone surrogates, which UTF-8 text cannot hold: the export writes U+FFFD there."""
    import os

    gold = ctfit.Material(ctfit.Structure(), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.9, 0.7, 0.3])),
                          channels=("R", "G", "B"), name=os.fsdecode(b"caf\xe9"))
    path = tmp_path / f"out.{to}"
    ctfit.export_material(gold, to=to, path=path)
    text = path.read_text(encoding="utf-8")  # UTF-8 text (the dict form does not name the material)
    assert "caf\ufffd" in text or to == "mitsuba-dict"


def _red_metal(tmp_path):
    """A saturated spectral metal (F0 → 1 in the red): effective indices up to 4 × 10⁶."""
    path = tmp_path / "red.toml"
    path.write_text('name = "red metal"\ns = 1.0\nlobes = [{ m = 0.2 }]\ngeometry = "smith-rational"\nwavelength_nm = [450, 550, 650, 700]\n'
                    "F0 = [0.6, 0.7, 0.99, 1.0]\n")
    return path


@pytest.mark.mitsuba
def test_a_spectral_material_exported_as_colours_is_its_colour_in_mitsubas_rgb_variant(tmp_path):
    """``--mitsuba-colour rgb``: in ``scalar_rgb`` Mitsuba gives the fit's linear-sRGB colour
    (its spectrum under D65, CIE 1931) at mirror directions up to 25° to 0.1 %, and the printed figures
    are Mitsuba's evaluation against that colour over the grid, recomputed here. The spectra as
    they are (the default) come out grey in that variant: Mitsuba converts the index spectrum like a
    colour, and clamps its negative channels."""
    mi = pytest.importorskip("mitsuba")
    mat = ctfit.load_material(_red_metal(tmp_path))
    fit_rgb = ctfit_values(mat, grid()) @ band_to_rgb(mat)
    r = runner.invoke(app, ["export", str(_red_metal(tmp_path)), "--to", "mitsuba", "--mitsuba-colour", "rgb", "-o", str(tmp_path / "c.xml")])
    assert r.exit_code == 0, r.output
    assert "approximate (spectra as linear-sRGB colours (D65, CIE 1931), F0 by the effective index of its colour per channel)" in r.stdout
    mi.set_variant("scalar_rgb")
    xml = (tmp_path / "c.xml").read_text()
    assert '<rgb name="eta"' in xml and "<spectrum" not in xml
    ours = mitsuba_values(mi.load_string(xml), grid())
    near = (grid()[0] == grid()[2]) & (grid()[3] == 180.0) & (grid()[0] < 30)  # the mirror directions up to 25°
    assert np.max(np.abs(ours[near] / fit_rgb[near] - 1)) < 1e-3  # (the grazing colour shift, per channel, differs: 0.8 % at 55°)
    median, worst = relative(ours, fit_rgb)
    assert _printed(r.stdout) == pytest.approx((median, worst), rel=2e-3, abs=5e-6)  # (Mitsuba evaluates in float32)
    r = runner.invoke(app, ["export", str(_red_metal(tmp_path)), "--to", "mitsuba", "-o", str(tmp_path / "s.xml")])
    assert r.exit_code == 0 and r.stdout.strip().endswith("its RGB variants take the spectra as colours (for those, export the Mitsuba colours as rgb)")
    assert r.stdout.strip() in (tmp_path / "s.xml").read_text()
    as_spectra = mitsuba_values(mi.load_string((tmp_path / "s.xml").read_text()), [a[near] for a in grid()])
    assert np.ptp(as_spectra, axis=1).max() < 1e-3 * as_spectra.max() and np.ptp(fit_rgb[near], axis=1).min() > 0.2 * fit_rgb[near].max()


def test_colours_of_a_spectral_material_keep_what_is_linear_and_say_what_is_not():
    """:func:`rgb_material`: R_d's and F0's colours are the spectra's (a Lambertian material is its
    colour exactly); a conductor's n, k and a metal's real n become F0's effective index; a
    plastic keeps its one n; an RGB material is left as it is."""
    wl = np.arange(400.0, 701.0, 20.0)
    lam = ctfit.Material(ctfit.Structure(lobes=0, diffuse="spectrum"), ctfit.Params(rd=np.linspace(0.01, 0.2, wl.size)), wavelength_nm=wl)
    as_rgb, notes = rgb_material(lam)
    assert as_rgb.channels == RGB and notes == ["spectra as linear-sRGB colours (D65, CIE 1931)"]
    np.testing.assert_allclose(ctfit_values(as_rgb, grid()), ctfit_values(lam, grid()) @ band_to_rgb(lam), rtol=1e-12)
    st = ctfit.Structure(geometry="smith-rational", fresnel="conductor", diffuse="spectrum")
    cond = ctfit.Material(st, ctfit.Params(s=np.array(0.9), m=np.array([0.3]), w=np.ones(1), n=np.linspace(0.2, 1.2, wl.size),
                                           k=np.linspace(2.0, 4.0, wl.size), rd=np.linspace(0.01, 0.2, wl.size)), wavelength_nm=wl)
    as_rgb, notes = rgb_material(cond)
    assert as_rgb.structure.fresnel == "f0" and as_rgb.params.n is None and as_rgb.params.k is None and "n, k as the effective index of F0 (k = 0)" in notes
    np.testing.assert_allclose(as_rgb.params.f0, np.asarray(ctfit.normal_reflectance(st, cond.params)) @ band_to_rgb(cond), rtol=1e-12)
    normal = ctfit_values(as_rgb, ([0.0], [0.0], [0.0], [0.0]))  # at normal incidence the specular colour is F0's: exact
    np.testing.assert_allclose(normal, ctfit_values(cond, ([0.0], [0.0], [0.0], [0.0])) @ band_to_rgb(cond), rtol=1e-9)
    shiny = plastic(diffuse="spectrum")
    spectral_plastic = ctfit.Material(shiny.structure, dataclasses.replace(shiny.params, rd=np.linspace(0.05, 0.2, wl.size)), wavelength_nm=wl)
    assert rgb_material(spectral_plastic)[0].params.n == 1.5 and rgb_material(shiny) == (shiny, [])
    narrow = ctfit.Material(ctfit.Structure(), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.where(np.abs(wl - 520) < 15, 0.95, 0.0)),
                            wavelength_nm=wl)  # a green outside sRGB's gamut
    as_rgb, notes = rgb_material(narrow)
    assert notes[-1] == "colours outside sRGB's gamut desaturated into it" and np.all(as_rgb.params.f0 >= 0)


def test_a_bad_mitsuba_colour_is_one_error_line(tmp_path):
    r = runner.invoke(app, ["export", str(_save(plastic(), tmp_path)), "--to", "mitsuba", "--mitsuba-colour", "xyz", "-o", str(tmp_path / "p.xml")])
    assert r.exit_code == 2 and r.output.strip() == "error: --mitsuba-colour xyz: one of spectrum, rgb" and not (tmp_path / "p.xml").exists()
    with pytest.raises(ValueError, match="mitsuba_colour must be one of spectrum, rgb"):
        ctfit.export_material(plastic(), mitsuba_colour="xyz")
    assert ctfit.export_material(metal(), mitsuba_colour="rgb").content == ctfit.export_material(metal()).content  # RGB already


def test_a_colour_outside_srgbs_gamut_is_desaturated_not_lost(tmp_path):
    """A pure green R_d (520 nm ± 15 nm) has negative red and blue in linear sRGB. MERL marks a
    negative value as a cell not measured: the table kept them, and a reader dropped two thirds of
    the values while the line said "max 0 %". Now every cell of the MERL table and glTF's base
    colour hold the colour desaturated at constant luminance, and both lines say so."""
    wl = np.arange(400.0, 701.0, 20.0)
    green = ctfit.Material(ctfit.Structure(lobes=0, diffuse="spectrum"), ctfit.Params(rd=np.where(np.abs(wl - 520) < 15, 0.3, 0.0)),
                           wavelength_nm=wl, name="green")
    colour = np.asarray(green.params.rd) @ band_to_rgb(green)
    assert colour.min() < 0  # outside the gamut
    luminance = np.asarray(ctfit.srgb_luminance())
    r = runner.invoke(app, ["export", str(_save(green, tmp_path)), "--to", "merl", "-o", str(tmp_path / "g.binary")])
    assert r.exit_code == 0 and "colours outside sRGB's gamut desaturated into it" in r.stdout and _printed(r.stdout)[1] > 0.1
    m = ctfit.read_merl(tmp_path / "g.binary")
    per_channel = np.bincount(m.band, minlength=3)
    assert per_channel[0] == per_channel[1] == per_channel[2] > 10**6 and m.brdf.min() >= 0  # every cell above the horizon, in each channel
    cell = np.array([m.brdf[(m.band == c)][0] for c in range(3)])  # a Lambertian: R_d's colour in every cell
    assert cell.min() == 0 and cell @ luminance == pytest.approx(colour @ luminance, rel=1e-9)
    gltf = ctfit.export_material(green, to="gltf")
    base = np.array(json.loads(gltf.content)["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"][:3])
    assert "colours outside sRGB's gamut desaturated into it" in gltf.line() and base.min() == 0
    assert base @ luminance == pytest.approx(colour @ luminance * np.pi, rel=1e-9)


@pytest.mark.mitsuba
def test_a_spectral_plastic_exported_as_colours_keeps_its_one_index(tmp_path):
    """``configs/rubber.toml`` (a plastic, its index listed per band) with ``--mitsuba-colour rgb``:
    it failed on the index's shape; now Mitsuba's ``scalar_rgb`` gives the printed figures against
    the fit's colour."""
    mi = pytest.importorskip("mitsuba")
    rubber = "configs/rubber.toml"
    r = runner.invoke(app, ["export", rubber, "--to", "mitsuba", "--mitsuba-colour", "rgb", "-o", str(tmp_path / "r.xml")])
    assert r.exit_code == 0, r.output
    mat = ctfit.load_material(rubber)
    mi.set_variant("scalar_rgb")
    xml = (tmp_path / "r.xml").read_text()
    assert 'name="int_ior" value="1.5"' in xml or "int_ior" not in xml
    median, worst = relative(mitsuba_values(mi.load_string(xml), grid()), ctfit_values(mat, grid()) @ band_to_rgb(mat))
    assert _printed(r.stdout) == pytest.approx((median, worst), rel=2e-3, abs=5e-6)


def test_a_coarse_spectrum_has_the_colour_ctfit_color_and_colour_science_give():
    """Two and three bands: the exports' colour of a spectrum is that of the spectrum
    ``docs/formats.md`` defines (linear between bands, held beyond), the colour ``ctfit color``
    reports and colour-science finds for it. (It integrated the bands as rectangles over their own
    range alone: 37 % more red for two bands.)"""
    import colour

    for wl, f0 in (([500.0, 600.0], [0.3, 0.9]), ([450.0, 550.0, 650.0], [0.2, 0.5, 0.9])):
        mat = ctfit.Material(ctfit.Structure(), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array(f0)), wavelength_nm=np.array(wl))
        nm = np.arange(360.0, 831.0)
        sd = colour.SpectralDistribution(dict(zip(nm, np.interp(nm, wl, f0))))
        with warnings.catch_warnings():  # colour-science says it aligns D65 (5 nm) to the observer's 1 nm
            warnings.simplefilter("ignore", colour.utilities.ColourRuntimeWarning)
            xyz = colour.sd_to_XYZ(sd, colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"], colour.SDS_ILLUMINANTS["D65"]) / 100
        expected = colour.XYZ_to_RGB(xyz, "sRGB", apply_cctf_encoding=False)
        np.testing.assert_allclose(np.array(f0) @ band_to_rgb(mat), expected, rtol=1e-3)  # (colour-science integrates its own way: 2e-4)
        np.testing.assert_allclose(np.array(f0) @ band_to_rgb(mat), ctfit.colour_report(mat, angle_deg=0.0)["linear_rgb"], rtol=1e-9)


@pytest.mark.parametrize("to", ["mitsuba-dict", "gltf", "merl"])
def test_a_black_material_exports_exactly_with_no_nan(to):
    """A black material: the fit and the target are 0 everywhere. The figures are 0 (they were NaN,
    and the JSON held NaN, which JSON does not have)."""
    black = ctfit.Material(ctfit.Structure(lobes=0, diffuse="spectrum"), ctfit.Params(rd=np.zeros(3)), wavelength_nm=np.array([400.0, 550.0, 700.0]))
    result = ctfit.export_material(black, to=to)
    assert (result.error["median"], result.error["max"]) == (0.0, 0.0) and "nan" not in result.line()
    if to != "merl":
        json.loads(result.content, parse_constant=lambda name: pytest.fail(f"{name} in the JSON"))


def test_gltf_says_when_a_metals_own_diffuse_colour_is_lost():
    """glTF has one base colour: a metal's own R_d becomes F0/π, and the line names it."""
    st = ctfit.Structure(geometry="smith-rational", diffuse="spectrum")
    mat = ctfit.Material(st, ctfit.Params(s=np.array(0.3), m=np.array([0.3]), w=np.ones(1), f0=np.full(3, 0.9), rd=np.array([0.25, 0.01, 0.01])),
                         channels=RGB)
    line = ctfit.export_material(mat, to="gltf").line()
    assert "glTF's one base colour is F0: the diffuse part F0/π, not R_d" in line
    assert "R_d" not in ctfit.export_material(metal(), to="gltf").line()  # F0/π: glTF's own


@pytest.mark.parametrize("to", ["mitsuba-dict", "gltf", "merl"])
def test_channels_b_g_r_export_as_the_same_material_in_r_g_b(to):
    """Channels listed B, G, R are picked by name, as ``ctfit color`` and the renderer pick them:
    the export is the R, G, B material's, byte for byte (it was refused)."""
    rgb = metal()
    order = [2, 1, 0]
    bgr = dataclasses.replace(rgb, params=dataclasses.replace(rgb.params, f0=rgb.params.f0[order]), channels=("B", "G", "R"))
    ours, theirs = ctfit.export_material(bgr, to=to), ctfit.export_material(rgb, to=to)
    assert ours.line() == theirs.line()
    if to == "merl":
        np.testing.assert_array_equal(ours.content, theirs.content)
    else:
        assert ours.content == theirs.content


def test_channels_that_are_not_r_g_b_are_still_refused():
    grey = ctfit.Material(ctfit.Structure(), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.3, 0.6, 0.9])), channels=("X", "Y", "Z"))
    with pytest.raises(ValueError, match=r"channels \['X', 'Y', 'Z'\]"):
        ctfit.export_material(grey, to="gltf")


def test_a_mirror_like_lobe_does_not_hide_the_diffuse_part_from_the_error():
    """m = 0.001 with a diffuse part: the lobe's peak on the grid (3.3·10⁶ sr⁻¹) put the floor
    (10⁻⁶ of it) above the whole diffuse part, and the glTF line gave a median of 1.1 % over the
    27 peak values, where over all 4,374 it is 79 % (glTF's diffuse is not ctfit's). The floor is
    the diffuse part's then: every value counts, as recomputed here."""
    mat = ctfit.Material(ctfit.Structure(lobes=1, diffuse="spectrum"), ctfit.Params(s=0.5, m=np.array([0.001]), w=np.ones(1),
                         f0=np.array([0.9, 0.5, 0.2]), rd=np.array([0.1, 0.2, 0.3])), channels=("R", "G", "B"))
    res = ctfit.export_material(mat, "gltf")
    e = res.error
    assert e["compared"] == e["values"] == 4374
    assert e["median"] > 0.5 and "values above that floor" not in res.line()
    spec = ctfit.export_material(dataclasses.replace(mat, structure=ctfit.Structure(lobes=1, diffuse=None),
                                                     params=ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.9, 0.5, 0.2]))), "gltf")
    assert spec.error["compared"] < spec.error["values"] and f"{spec.error['compared']:,} of its 4,374 values above that floor" in spec.line()
