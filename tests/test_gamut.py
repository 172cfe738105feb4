"""The paper's gamut mapping: inside the gamut, same luminance and dominant wavelength, finite gradients."""

import colour
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from ctfit._colour import RGB_to_XYZ, XYZ_to_xy, dominant_wavelength, rgb_conversion
from ctfit._colour.gamut import desaturate_to_gamut, in_gamut, scale_to_display, srgb_luminance

CONV = rgb_conversion("sRGB")  # no adaptation: XYZ of RGB (1, 1, 1) is the display white
LUM = srgb_luminance()
WHITE_XY = np.asarray(XYZ_to_xy(CONV.white_XYZ))

desat = jax.jit(desaturate_to_gamut, static_argnames="upper")
rgb_to_xy = jax.jit(lambda rgb: XYZ_to_xy(RGB_to_XYZ(rgb, CONV)))


def out_of_gamut_colours(n=200, seed=0):
    """Linear sRGB of chromaticities across the spectral locus (most outside sRGB), 0 < Y < 1."""
    rng = np.random.default_rng(seed)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    locus = cmfs.values[(cmfs.wavelengths >= 420) & (cmfs.wavelengths <= 680)]
    locus = locus[:, :2] / locus.sum(1, keepdims=True)
    pick = locus[rng.integers(0, len(locus), n)]
    xy = WHITE_XY + rng.uniform(0.5, 0.98, (n, 1)) * (pick - WHITE_XY)
    Y = rng.uniform(0.02, 0.95, n)
    XYZ = np.column_stack([xy[:, 0] * Y / xy[:, 1], Y, (1 - xy.sum(1)) * Y / xy[:, 1]])
    return np.asarray(XYZ @ CONV.matrix.T)


def test_luminance_is_srgb():
    np.testing.assert_allclose(LUM, [0.2126, 0.7152, 0.0722], atol=2e-4)
    assert LUM.sum() == pytest.approx(1)
    np.testing.assert_allclose(CONV.luminance, LUM, atol=1e-15)


def test_mapped_colours_inside_with_same_luminance_and_dominant_wavelength():
    rgb = out_of_gamut_colours()
    assert not np.all(in_gamut(rgb))
    out = np.asarray(desat(rgb, LUM))
    assert np.all(out >= -1e-12) and np.all(out <= 1 + 1e-12)
    y_in, y_out = rgb @ LUM, out @ LUM
    np.testing.assert_allclose(y_out, y_in, atol=1e-12)  # 0 < Y < 1 here: always reachable
    xy_in, xy_out = np.asarray(rgb_to_xy(rgb)), np.asarray(rgb_to_xy(out))
    # colour-science's intersection search returns NaN points (and λ = 360) for a few exact
    # float inputs; those colours are left out of the oracle comparison, and must be rare.
    ref_in, xyb_in, _ = colour.dominant_wavelength(xy_in, WHITE_XY)
    ref_out, xyb_out, _ = colour.dominant_wavelength(xy_out, WHITE_XY)
    ok = np.all(np.isfinite(xyb_in), axis=1) & np.all(np.isfinite(xyb_out), axis=1)
    assert ok.mean() > 0.95
    np.testing.assert_allclose(ref_out[ok], ref_in[ok], atol=1.0)
    np.testing.assert_allclose(dominant_wavelength(xy_out, WHITE_XY), dominant_wavelength(xy_in, WHITE_XY), atol=1e-6)
    # On the boundary: some channel is 0 or 1 wherever the colour was outside.
    moved = ~np.asarray(in_gamut(rgb))
    edge = np.min(np.abs(np.concatenate([out, 1 - out], 1)), axis=1)
    assert np.all(edge[moved] < 1e-12)


def test_in_gamut_colours_untouched():
    rng = np.random.default_rng(1)
    rgb = np.vstack([rng.uniform(0, 1, (100, 3)), [[0, 0, 0], [1, 1, 1], [0, 1, 0], [1, 0, 0.5]]])
    np.testing.assert_array_equal(np.asarray(desat(rgb, LUM)), rgb)


def test_unmappable_luminances():
    rgb = np.array([[-0.5, -0.1, 0.2], [2.0, 1.5, 0.8], [0.0, 0.0, -1e-3]])
    out = np.asarray(desat(rgb, LUM))
    np.testing.assert_allclose(out[0], 0)  # Y < 0: black
    np.testing.assert_allclose(out[1], 1)  # Y > 1: white of luminance 1
    np.testing.assert_allclose(out[2], 0)


def test_no_upper_bound_keeps_bright_colours():
    rgb = np.array([[2.0, 0.5, -0.1], [3.0, 3.0, 3.0]])
    out = np.asarray(desat(rgb, LUM, upper=None))
    assert np.all(out >= -1e-12)
    np.testing.assert_allclose(out @ LUM, rgb @ LUM, atol=1e-12)
    np.testing.assert_array_equal(out[1], rgb[1])


def test_gradients_finite_and_match_differences():
    f = jax.jit(lambda c: jnp.sum(desaturate_to_gamut(c, LUM) ** 2))
    g = jax.jit(jax.grad(f))
    cases = [
        [0, 0, 0], [1, 1, 1], [0.2, 0.5, 0.7], [0.0, 0.5, 0.7], [0.5, -0.2, 0.3],
        [1.4, 0.2, 0.1], [-0.1, -0.1, -0.1], [2, 2, 2], [0, 0, 1], [1, 0, 0],
    ]  # fmt: skip
    for c in cases:
        assert np.all(np.isfinite(g(jnp.asarray(c, dtype=float)))), c
    d = jnp.asarray([0.3, -0.7, 0.2])
    for c in ([0.5, -0.2, 0.3], [1.3, 0.4, 0.1], [0.2, 0.5, 0.7]):
        c = jnp.asarray(c)
        fd = (f(c + 1e-6 * d) - f(c - 1e-6 * d)) / 2e-6
        assert float(jnp.vdot(g(c), d)) == pytest.approx(float(fd), rel=1e-6, abs=1e-9)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-3, 3, allow_nan=False), min_size=3, max_size=3))
def test_property_inside_and_luminance(c):
    c = np.asarray(c)
    out = np.asarray(desat(c, LUM))
    assert np.all(out >= -1e-12) and np.all(out <= 1 + 1e-12)
    y = c @ LUM
    assert out @ LUM == pytest.approx(np.clip(y, 0, 1), abs=1e-12)


def test_special_values():
    vals = [-1.0, 0.0, 1.0, -np.inf, np.inf, np.nan]
    rgb = np.array([[v, 0.5, 0.5] for v in vals])
    out = np.asarray(desat(rgb, LUM))
    assert out.shape == rgb.shape
    assert np.all(np.isfinite(out[:3]))
    assert np.all(np.any(np.isnan(out[3:]), axis=1))  # non-finite in, NaN out, nothing raised
    assert not np.any(np.asarray(in_gamut(rgb))[3:])
    disp, scale = jax.jit(scale_to_display)(rgb, LUM)
    assert np.isfinite(scale) and np.all(np.isfinite(np.asarray(disp)[:3]))


def test_scale_to_display():
    rng = np.random.default_rng(2)
    scene = np.concatenate([rng.uniform(0, 5, (50, 3)), out_of_gamut_colours(20) * 4])
    scaled = jax.jit(scale_to_display)
    disp, scale = scaled(scene, LUM)
    disp = np.asarray(disp)
    assert disp.max() == pytest.approx(1, abs=1e-12)
    assert np.all(disp >= -1e-12)
    # One global factor: in-gamut pixels are just scaled.
    ok = np.all(scene >= 0, axis=1)
    np.testing.assert_allclose(disp[ok], scene[ok] * float(scale), atol=1e-12)
    # Scale invariance and the degenerate black scene.
    np.testing.assert_allclose(np.asarray(scaled(3 * scene, LUM)[0]), disp, atol=1e-12)
    black, s = scaled(np.zeros_like(scene), LUM)
    assert float(s) == 1 and np.all(np.asarray(black) == 0)
    g = jax.jit(jax.grad(lambda x: jnp.sum(scale_to_display(x, LUM)[0])))(jnp.asarray(scene))
    assert np.all(np.isfinite(g))
    # A NaN pixel does not change the others.
    with_nan = np.vstack([scene[:-1], [[np.nan, 0, 0]]])
    ref = np.asarray(scaled(np.vstack([scene[:-1], [[0, 0, 0]]]), LUM)[0])
    np.testing.assert_allclose(np.asarray(scaled(with_nan, LUM)[0])[:-1], ref[:-1], atol=1e-12)


@pytest.mark.parametrize("upper", [1.0, 0.5, None])
def test_the_numpy_mapping_is_the_traced_one(upper):
    """``xp=numpy`` (the exports' host path: nothing compiled) maps every colour as the traced
    function does, to rounding: out-of-gamut colours of the spectral locus, in-gamut ones, black,
    white beyond ``upper`` and a negative luminance."""
    c = np.concatenate([out_of_gamut_colours(), np.array([[0.3, 0.2, 0.1], [0.0, 0.0, 0.0], [2.0, 2.0, 2.0], [-0.1, -0.2, 0.05]])])
    on_host = desaturate_to_gamut(c, upper=upper, xp=np)
    assert isinstance(on_host, np.ndarray) and on_host.dtype == np.float64
    np.testing.assert_allclose(on_host, np.asarray(desat(c, upper=upper)), rtol=1e-12, atol=1e-15)
