"""Rendering: the camera and shapes, highlight positions, a matte material, grids, --compare, gradients."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import ctfit
from ctfit import Material, Params, Structure, render_compare, render_linear, render_material, render_materials, save_png, tone_map
from ctfit._cli.render_command import render_command_body
from ctfit._render.scene import render_scene, shade_linear
from ctfit._render.sheet import grid_layout
from ctfit._render.surfaces import RADIUS, VASE_SCALE, VIEW_DIRECTION, surface_normals, vase_profile
from ctfit._render.tone import BACKGROUND

from conftest import ROOT

RGB = ("R", "G", "B")
BG = np.round(np.asarray(ctfit.eotf_inverse_sRGB(np.asarray(BACKGROUND))) * 255).astype(np.uint8)
FAST = {"supersample": 1, "wavelength_step": 20.0}


def unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def mirror_material(m=0.06):
    return Material(Structure(lobes=1, fresnel="f0"), Params(m=np.array([m]), w=np.array([1.0]), f0=np.full(3, 0.9)), channels=RGB, name="mirror")


def lambert_material():
    return Material(Structure(lobes=0, diffuse="spectrum"), Params(rd=np.array([0.2, 0.15, 0.1])), channels=RGB, name="lambert")


def pixel_of(n, size):
    """(row, col) of the pixel whose sphere normal is ``n``."""
    x, y = n[0] * RADIUS, n[1] * RADIUS
    return (1 - y) / 2 * size - 0.5, (x + 1) / 2 * size - 0.5


def luminance(rgb):
    return rgb @ ctfit.srgb_luminance()


@pytest.mark.parametrize("shape", ["sphere", "vase"])
def test_surface_normals(shape):
    surf = surface_normals(shape, 64, 2)
    assert surf.normal.shape == (128, 128, 3) and surf.mask.shape == (128, 128)
    n = surf.normal[surf.mask]
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1, atol=1e-12)
    assert np.all(n[:, 2] >= 0)
    assert not surf.mask[0, 0] and not surf.mask[-1, -1] and surf.mask[64, 64]
    if shape == "sphere":
        assert surf.mask.mean() == pytest.approx(np.pi * RADIUS**2 / 4, rel=0.02)


def test_vase_normal_is_perpendicular_to_the_surface():
    y = np.linspace(-0.9, 0.9, 41)
    r, dr = vase_profile(y)
    h = 1e-6
    fd = (vase_profile(y + h)[0] - vase_profile(y - h)[0]) / (2 * h)
    np.testing.assert_allclose(dr, fd, atol=1e-6)
    # Near the meridian (x ≈ 0) the surface point is (x, y, z(y)), z = √(r² − x²), and a tangent
    # along the meridian is (0, 1, dz/dy) = (0, 1, r r′/z); r = 0.9 p(y/0.9), r′ = p′(y/0.9).
    surf = surface_normals("vase", 200)
    col = 100
    x = (col + 0.5) / 200 * 2 - 1
    rows = np.flatnonzero(surf.mask[:, col])
    yy = 1 - (rows + 0.5) / 200 * 2
    p, dp = vase_profile(yy / VASE_SCALE)
    r = VASE_SCALE * p
    z = np.sqrt(r * r - x * x)
    tangent = np.stack([np.zeros_like(yy), np.ones_like(yy), r * dp / z], axis=-1)
    n = surf.normal[rows, col]
    cos = np.sum(n * tangent, axis=-1) / np.linalg.norm(tangent, axis=-1)
    np.testing.assert_allclose(cos, 0, atol=1e-12)
    # and perpendicular to the circle of latitude: tangent (z, 0, −x).
    np.testing.assert_allclose(n[:, 0] * z - n[:, 2] * x, 0, atol=1e-12)


def test_render_material_is_an_image_with_background():
    img = render_material(lambert_material(), 32, **FAST)
    assert img.shape == (32, 32, 3) and img.dtype == np.uint8
    for corner in (img[0, 0], img[0, -1], img[-1, 0], img[-1, -1]):
        np.testing.assert_array_equal(corner, BG)
    assert np.any(img[16, 16] != BG)


def test_highlight_where_the_mirror_condition_holds():
    size = 64
    light = unit([0.5, 0.3, 0.8])
    tile = render_linear(mirror_material(), size, directions=(light,), solid_angles=(1e-4,), ambient=0.0, supersample=1)
    y = np.where(tile.mask, luminance(tile.rgb), -np.inf)
    row, col = np.unravel_index(np.argmax(y), y.shape)
    expect = pixel_of(unit(light + np.asarray(VIEW_DIRECTION)), size)
    assert abs(row - expect[0]) <= 1.5 and abs(col - expect[1]) <= 1.5
    # The highlight is small: away from it the sphere is dark (no ambient here).
    assert np.mean(y[tile.mask] > 0.05 * y.max()) < 0.1


def test_highlight_moves_with_the_light():
    size = 64
    peaks = []
    for light in (unit([-0.6, 0.2, 0.8]), unit([0.2, -0.6, 0.8])):
        tile = render_linear(mirror_material(), size, directions=(light,), solid_angles=(1e-4,), ambient=0.0, supersample=1)
        y = np.where(tile.mask, luminance(tile.rgb), -np.inf)
        peaks.append((np.unravel_index(np.argmax(y), y.shape), pixel_of(unit(light + np.asarray(VIEW_DIRECTION)), size)))
    for (row, col), (er, ec) in peaks:
        assert abs(row - er) <= 1.5 and abs(col - ec) <= 1.5


def test_matte_material_has_no_highlight():
    """Lunar dust (s = 0): brightest where N = L, and exactly affine in max(0, N·L) (no lobe)."""
    dust = ctfit.load_material(ROOT / "configs" / "lunar-dust.toml")
    size = 48
    light = unit([0.4, 0.5, 0.77])
    tile = render_linear(dust, size, directions=(light,), solid_angles=(2e-4,), ambient=0.01, **FAST)
    y = np.where(tile.mask, luminance(tile.rgb), -np.inf)
    row, col = np.unravel_index(np.argmax(y), y.shape)
    er, ec = pixel_of(light, size)
    assert abs(row - er) <= 1.5 and abs(col - ec) <= 1.5
    cos = np.maximum(surface_normals("sphere", size).normal[tile.mask] @ light, 0)
    a, b = np.polyfit(cos, y[tile.mask], 1)
    np.testing.assert_allclose(a * cos + b, y[tile.mask], rtol=1e-9)
    assert b > 0  # the ambient term lifts the unlit side


def test_tone_map_paper_rule_and_reference_exposure():
    tile = render_linear(mirror_material(0.2), 32, supersample=1)
    img, scale = tone_map(tile, exposure="tile")
    assert scale == pytest.approx(1 / tile.rgb[tile.mask].max(), rel=1e-9)
    assert img.max() == 255
    # A dark diffuse material: the tile rule makes it white, the reference exposure keeps it dark.
    dark = Material(Structure(lobes=0, diffuse="constant"), Params(rd=np.asarray(0.05 / np.pi)), channels=RGB, name="dark")
    t = render_linear(dark, 32, supersample=1)
    assert tone_map(t, exposure="tile")[0].max() == 255
    ref, s = tone_map(t)
    assert s == pytest.approx(t.white_scale)
    assert ref[t.mask].max() < 0.35 * 255
    with pytest.raises(ValueError, match="exposure"):
        tone_map(t, exposure="bright")


def test_grid_has_one_tile_per_material():
    mats = [lambert_material(), mirror_material(0.3), lambert_material()]
    size = 24
    img = render_materials(mats, size, labels=["a", "b", "c"], columns=2, supersample=1)
    height, width, boxes = grid_layout(3, size, 2)
    assert img.shape == (height, width, 3) and len(boxes) == 3
    for top, left in boxes:
        tile = img[top : top + size, left : left + size]
        assert np.any(np.any(tile != BG, axis=-1))
        np.testing.assert_array_equal(tile[0, 0], BG)
    empty = img[size + (height // 2 - size) :, size:]  # the fourth cell of the 2 × 2 grid
    assert np.all(empty[: size // 2, : size // 2] == BG)
    no_labels = render_materials(mats, size, shape=["sphere", "vase", "sphere"], labels=False, supersample=1)
    assert no_labels.shape == (size, 3 * size, 3)
    with pytest.raises(ValueError, match="labels"):
        render_materials(mats, size, labels=["only one"])
    with pytest.raises(ValueError, match="shape"):
        render_materials(mats, size, shape="cube")


def test_rendered_pixel_gradients_are_finite():
    """d(displayed pixel)/d(parameters) through eq. 1, the colour matrix, the gamut mapping at a
    fixed exposure and the sRGB encoding; finite on the whole sphere including exact
    silhouette normals (N·V = 0, 1e-300, < 0)."""
    st = Structure(lobes=1, fresnel="f0", diffuse="spectrum")
    params = Params(s=jnp.asarray(0.8), m=jnp.array([0.1]), w=jnp.array([1.0]), f0=jnp.array([0.6, 0.7, 0.9]), rd=jnp.array([0.1, 0.05, 0.02]))
    mat = Material(st, params, channels=RGB)
    scene = render_scene(mat, ambient=1e-6 * np.pi / 3e-4)  # I_ia = 1e-6 per channel
    surf = surface_normals("sphere", 12)
    phi = np.linspace(0, 2 * np.pi, 9)
    rim = [np.stack([np.cos(phi) * np.sqrt(1 - z * z), np.sin(phi) * np.sqrt(1 - z * z), np.full_like(phi, z)], -1) for z in (0.0, 1e-300, 1e-9, -1e-9)]
    normals = np.concatenate([surf.normal[surf.mask], *rim])
    scale = 3e3  # about the paper's scale for this tile (its highlight just over display white)

    @eqx.filter_jit
    @eqx.filter_grad
    def grad(p):
        rgb = shade_linear(st, scene._replace(params=p), normals)
        shown = ctfit.eotf_inverse_sRGB(ctfit.desaturate_to_gamut(rgb * scale, upper=1.0))
        return jnp.sum(shown[len(normals) // 3]) + jnp.sum(shown[-40:]) + jnp.sum(rgb)

    g = grad(params)
    for name in ("s", "m", "f0", "rd"):
        leaf = np.asarray(getattr(g, name))
        assert np.all(np.isfinite(leaf)) and np.any(leaf != 0), name


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    mat = ctfit.load_material(ROOT / "configs" / "rust.toml")
    data = ctfit.simulate(mat, 4000, wavelength_nm=np.array([450.0, 550.0, 650.0]), seed=2, max_theta=88)
    return mat, data


def test_compare_has_two_tiles_that_agree_on_model_data(simulated):
    mat, data = simulated
    size = 32
    img = render_compare(mat, data, size, supersample=1)
    height, width, boxes = grid_layout(2, size, 2)
    assert img.shape == (height, width, 3) == (size + (height - size), 2 * size, 3)
    left, right = img[:size, :size].astype(float), img[:size, size:].astype(float)
    on = np.any(left != BG, axis=-1) & np.any(right != BG, axis=-1)
    assert on.mean() > 0.5
    # Data simulated from the same material: nearest-neighbour shading is close to the model.
    assert np.mean(np.abs(left[on] - right[on])) < 8


def test_one_exact_grazing_value_changes_no_other_pixel_of_the_measured_sphere():
    """The measured sphere is interpolated in log BRDF, values below 10⁻⁶ of the band's scale held
    there. That scale was the band's maximum: one exact grazing pair (θ = 89.9°, 10⁵ sr⁻¹ of a
    rough plastic) lifted the floor over every diffuse value, and ΔE2000 of exact data went from a
    median 0.05 to 30. It is now the 99th percentile."""
    mat = ctfit.load_material(ROOT / "configs" / "rubber.toml")
    data = ctfit.simulate(mat, 300, seed=1)
    grazing = ctfit.Measurement(theta_i=np.full(7, 89.9), phi_i=np.zeros(7), theta_o=np.full(7, 89.9), phi_o=np.full(7, 180.0), band=np.arange(7),
                                wavelength_nm=data.wavelength_nm)
    grazing = grazing.replace(brdf=np.asarray(ctfit.evaluate(mat, grazing), float))
    assert grazing.brdf.min() > 100 * data.brdf.max()
    both = data.replace(**{k: np.concatenate([getattr(data, k), getattr(grazing, k)]) for k in ("theta_i", "phi_i", "theta_o", "phi_o", "band", "brdf")})
    plain, with_grazing = (ctfit.render_comparison(mat, d, size=32, supersample=1) for d in (data, both))
    assert plain.median < 0.2 and with_grazing.median == pytest.approx(plain.median, abs=0.05)


def test_command_body_writes_png(tmp_path, simulated):
    from PIL import Image

    out = tmp_path / "grid.png"
    info = render_command_body([ROOT / "configs" / "lunar-dust.toml", ROOT / "configs" / "rust.toml"], out, 16, "sphere", None, True, supersample=1,
                               wavelength_step=20)
    assert out.exists() and info["image_shape"] == list(np.asarray(Image.open(out)).shape)
    assert info["image_shape"][1] == 32
    mat, data = simulated
    csv = tmp_path / "data.csv"
    ctfit.write_csv(data, csv)
    out2 = tmp_path / "compare.png"
    info = render_command_body([ROOT / "configs" / "rust.toml"], out2, 16, "sphere", csv, False, supersample=1)
    assert info["image_shape"] == [16, 32, 3]
    with pytest.raises(ValueError, match="one material"):
        render_command_body([ROOT / "configs" / "rust.toml"] * 2, out2, 16, "sphere", csv, False)
    with pytest.raises(ValueError, match="shape"):
        render_command_body([ROOT / "configs" / "rust.toml"], out2, 16, "cube", None, False)
    with pytest.raises(ValueError, match="png"):
        render_command_body([ROOT / "configs" / "rust.toml"], tmp_path / "x.jpg", 16, "sphere", None, False)


def test_save_png_round_trip(tmp_path):
    from PIL import Image

    img = np.zeros((5, 7, 3), np.uint8)
    img[1, 2] = (10, 200, 30)
    path = save_png(img, tmp_path / "sub" / "a.png")
    np.testing.assert_array_equal(np.asarray(Image.open(path)), img)
    with pytest.raises(ValueError):
        save_png(img.astype(float), tmp_path / "b.png")


def test_compare_rejects_mismatched_bands(simulated):
    _, data = simulated
    with pytest.raises(ValueError, match="spectral material"):
        render_compare(lambert_material(), data, 8, supersample=1)
    mat, _ = simulated
    one = ctfit.simulate(mat, 50, wavelength_nm=[550.0], seed=1).replace(source="one.csv")
    for show in (render_compare, lambda m, d, size, supersample: ctfit.render_comparison(m, d, size=size, supersample=supersample)):
        with pytest.raises(ValueError, match=r"^one.csv: one band \(550 nm\)"):  # was "wavelength_nm must be a 1-D array of at least 2 …"
            show(mat, one, 8, supersample=1)


def test_cli_render(tmp_path):
    from typer.testing import CliRunner

    from ctfit.cli import app

    out = tmp_path / "r.png"
    cfg = str(ROOT / "configs" / "lunar-dust.toml")
    res = CliRunner().invoke(app, ["render", cfg, cfg, "-o", str(out), "--size", "16", "--supersample", "1", "--step", "20", "--shape", "vase"])
    assert res.exit_code == 0, res.output
    assert out.exists()
    res = CliRunner().invoke(app, ["render", cfg, "-o", str(out), "--shape", "cube"])
    assert res.exit_code == 2 and "shape" in res.output



def test_pictures_of_sizes_in_one_bucket_compile_nothing_new_and_padding_changes_no_pixel():
    """Shading runs in blocks of fixed sizes and the tone mapping on sides padded to four sizes
    per octave: after one picture, sides in its bucket (113–128 pixels) compile nothing (each
    new size compiled three programs, ~1 s and ~70 memory maps), and every pixel and scale is
    that of the picture shaded and mapped without padding."""
    import jax

    from ctfit._render import tone
    from ctfit._render.scene import shade_tile

    gold = ctfit.material_from_dict({"s": 1, "lobes": [{"m": 0.3}], "optical_constants": "Au"})
    scene, sizes = render_scene(gold), (113, 117, 127, 128)
    render_material(gold, 120, "sphere", supersample=3)  # sides 113–128: one bucket
    compiled: list = []

    def listener(event, duration, **kw):
        if event == "/jax/core/compile/backend_compile_duration":
            compiled.append(kw.get("fun_name"))

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        pictures = {n: (tile, *tone_map(tile)) for n in sizes for tile in [shade_tile(gold.structure, scene, surface_normals("sphere", n, 3), 3)]}
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    assert compiled == []
    assert [tone._padded_side(n) for n in (1, 64, 65, 80, 81, 128, 129, 160, 2049)] == [64, 64, 80, 80, 96, 128, 160, 160, 2560]
    for n, (tile, image, scale) in pictures.items():  # against the same steps unpadded (a program per size)
        assert image.shape == (n, n, 3)
        normals = surface_normals("sphere", n, 3).normal[tile.mask]
        np.testing.assert_allclose(tile.rgb[tile.mask], np.asarray(shade_linear(gold.structure, scene, normals)), rtol=1e-12, atol=0)
        rgb = np.where(tile.mask[..., None], tile.rgb, 0.0)
        assert scale == min(float(tone._paper_scale(rgb)), tile.white_scale)
        np.testing.assert_array_equal(image, np.asarray(tone._compose(rgb, tile.mask, jnp.asarray(scale), np.asarray(BACKGROUND), 3)))
