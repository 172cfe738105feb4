"""Colorimetry against colour-science: XYZ, RGB, encoding, CIELAB, ΔE2000, dominant wavelength, report."""

import json
import warnings

import colour
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from colour.utilities import suppress_warnings

import ctfit
from ctfit._colour import (
    DEFAULT_OBSERVER,
    RGB_to_XYZ,
    SpectralResamplingWarning,
    XYZ_to_display_RGB,
    XYZ_to_Lab,
    XYZ_to_RGB,
    XYZ_to_xy,
    delta_E_CIE2000,
    dominant_wavelength,
    encode_RGB,
    eotf_inverse_sRGB,
    excitation_purity,
    rgb_conversion,
    spectral_weights,
    spectrum_to_RGB,
    spectrum_to_XYZ,
)
from ctfit._colour.report import colour_report, reflectance_spectrum

OBSERVER_10 = "CIE 1964 10 Degree Standard Observer"

# Copper, Johnson & Christy (1972), Phys. Rev. B 6, 4370 (refractiveindex.info, main/Cu/Johnson):
# wavelength (nm), n, k. Test data for a realistic metal spectrum, not a colorimetric table.
CU_NK = np.array(
    [
        (342.5, 1.360, 1.864), (354.2, 1.370, 1.916), (367.9, 1.360, 1.975), (381.5, 1.330, 2.045),
        (397.4, 1.320, 2.116), (413.3, 1.280, 2.207), (430.5, 1.250, 2.305), (450.9, 1.240, 2.397),
        (471.4, 1.250, 2.483), (495.9, 1.220, 2.564), (520.9, 1.180, 2.608), (548.6, 1.020, 2.577),
        (582.1, 0.700, 2.704), (616.8, 0.300, 3.205), (659.5, 0.220, 3.747), (704.5, 0.210, 4.205),
        (756.0, 0.240, 4.665), (821.1, 0.260, 5.180), (892.0, 0.300, 5.768),
    ]
)  # fmt: skip


def cu_nk(wl):
    return np.interp(wl, CU_NK[:, 0], CU_NK[:, 1]), np.interp(wl, CU_NK[:, 0], CU_NK[:, 2])


def cu_f0(wl):
    n, k = cu_nk(wl)
    return ((n - 1) ** 2 + k**2) / ((n + 1) ** 2 + k**2)


def quiet():
    return suppress_warnings(colour_runtime_warnings=True, colour_usage_warnings=True, colour_warnings=True)


def spectra(wl):
    return np.stack([np.ones_like(wl), (wl - wl[0]) / (wl[-1] - wl[0]), 0.5 + 0.4 * np.sin(wl / 30), cu_f0(wl)])


def colour_xyz(specs, wl, step, illuminant, observer, **kw):
    with quiet():
        return colour.sd_to_XYZ(
            specs,
            colour.MSDS_CMFS[observer],
            colour.SDS_ILLUMINANTS[illuminant],
            method="Integration",
            shape=colour.SpectralShape(wl[0], wl[-1], step),
            **kw,
        ) / 100


# ---- spectrum → XYZ ----


@pytest.mark.parametrize("step", [1, 5, 10])
@pytest.mark.parametrize("illuminant", ["D65", "A"])
@pytest.mark.parametrize("observer", [DEFAULT_OBSERVER, OBSERVER_10])
def test_xyz_matches_colour_integration(step, illuminant, observer):
    wl = np.arange(360.0, 831.0, step)
    specs = spectra(wl)
    w = spectral_weights(wl, illuminant, observer)
    mine = np.asarray(spectrum_to_XYZ(specs, w))
    ref = colour_xyz(specs, wl, step, illuminant, observer)
    np.testing.assert_allclose(mine, ref, atol=1e-9)
    # colour-science's default path (ASTM E308 weights for 10 nm; CMF-grid alignment of the spectrum).
    with quiet():
        dflt = np.array(
            [
                colour.sd_to_XYZ(colour.SpectralDistribution(s, wl), colour.MSDS_CMFS[observer], colour.SDS_ILLUMINANTS[illuminant])
                for s in specs
            ]
        ) / 100
    np.testing.assert_allclose(mine, dflt, atol=1e-3)


def test_xyz_narrow_range_matches_colour():
    wl = np.arange(400.0, 701.0, 5)
    specs = spectra(wl)
    ref = colour_xyz(specs, wl, 5, "D65", DEFAULT_OBSERVER)
    np.testing.assert_allclose(np.asarray(spectrum_to_XYZ(specs, spectral_weights(wl))), ref, atol=1e-9)


def test_white_is_illuminant_white_point():
    for name in ("D65", "A", "D50"):
        w = spectral_weights(np.arange(360.0, 831.0), name)
        assert w.white_XYZ[1] == pytest.approx(1, abs=1e-14)
        np.testing.assert_allclose(np.asarray(spectrum_to_XYZ(np.ones(471), w)), w.white_XYZ, atol=1e-14)
        ref = colour.CCS_ILLUMINANTS[DEFAULT_OBSERVER][name]
        np.testing.assert_allclose(w.white_xy, ref, atol=2e-4)


def test_user_illuminant_equals_named():
    d65 = colour.SDS_ILLUMINANTS["D65"]
    wl = np.arange(380.0, 781.0, 5)
    named = spectral_weights(wl, "D65")
    user = spectral_weights(wl, (d65.wavelengths, d65.values))  # on its grid: no warning
    np.testing.assert_allclose(user.weights, named.weights, atol=1e-15)
    assert user.illuminant == "custom"


def test_off_grid_wavelengths_warn_and_still_agree():
    wl = np.arange(400.5, 700.6, 5)
    specs = spectra(wl)
    with pytest.warns(SpectralResamplingWarning, match="interpolated"):
        w = spectral_weights(wl)
    ref = colour_xyz(specs, wl, 5, "D65", DEFAULT_OBSERVER)
    np.testing.assert_allclose(np.asarray(spectrum_to_XYZ(specs, w)), ref, atol=1e-6)


def test_user_illuminant_interpolation_warns():
    wl = np.arange(380.0, 781.0, 5)
    with pytest.warns(SpectralResamplingWarning, match="illuminant"):
        spectral_weights(wl, (np.arange(400.0, 701.0, 10), np.ones(31)))


def test_named_illuminant_on_1nm_is_silent():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        spectral_weights(np.arange(360.0, 831.0))


def test_nonuniform_grid_quadrature():
    wl = np.concatenate([np.arange(360.0, 600.0, 5), np.arange(600.0, 831.0, 10)])
    dense = np.arange(360.0, 831.0)
    for f in (lambda x: 0.5 + 0.4 * np.sin(x / 40), cu_f0):
        a = np.asarray(spectrum_to_XYZ(f(wl), spectral_weights(wl)))
        b = np.asarray(spectrum_to_XYZ(f(dense), spectral_weights(dense)))
        np.testing.assert_allclose(a, b, atol=2e-3)


def test_wavelengths_outside_observer_range_get_zero_weight():
    wl = np.arange(300.0, 901.0, 5)
    w = spectral_weights(wl)
    outside = (wl < 360) | (wl > 830)
    assert np.all(w.weights[outside] == 0)
    assert w.white_XYZ[1] == pytest.approx(1)


def test_batch_shape_and_dtype():
    wl = np.arange(360.0, 831.0, 10)
    w = spectral_weights(wl)
    r = jnp.ones((2, 4, wl.size))
    assert spectrum_to_XYZ(r, w).shape == (2, 4, 3)
    assert spectrum_to_XYZ(r.astype(jnp.float32), w).dtype == jnp.float32
    assert spectrum_to_XYZ(np.ones(wl.size, dtype=int), w).dtype == jnp.float64


def test_jit_with_weights_as_argument():
    wl = np.arange(360.0, 831.0, 10)
    w = spectral_weights(wl)
    f = jax.jit(spectrum_to_XYZ)
    np.testing.assert_allclose(f(jnp.ones(wl.size), w), w.white_XYZ, atol=1e-14)


@pytest.mark.parametrize(
    "wl, kwargs, match",
    [
        (np.array([500.0]), {}, "at least 2"),
        (np.array([500.0, 400.0]), {}, "increasing"),
        (np.array([400.0, np.nan]), {}, "finite"),
        (np.array([100.0, 200.0]), {}, "range"),
        (np.arange(400.0, 701.0, 10), {"observer": "nobody"}, "unknown observer"),
        (np.arange(400.0, 701.0, 10), {"illuminant": "D99"}, "unknown illuminant"),
    ],
)
def test_spectral_weights_errors(wl, kwargs, match):
    with pytest.raises(ValueError, match=match):
        spectral_weights(wl, **kwargs)


def test_spectrum_length_mismatch():
    with pytest.raises(ValueError, match="wavelengths on its last axis"):
        spectrum_to_XYZ(np.ones(5), spectral_weights(np.arange(360.0, 831.0, 10)))


def test_special_values_do_not_crash():
    wl = np.arange(360.0, 831.0, 10)
    w = spectral_weights(wl)
    vals = np.array([-1, 0, 1, -np.inf, np.inf, np.nan])
    xyz = np.asarray(spectrum_to_XYZ(vals[:, None] * np.ones(wl.size), w))
    np.testing.assert_allclose(xyz[:3], vals[:3, None] * w.white_XYZ, atol=1e-14)
    assert np.all(np.isnan(xyz[5]))
    conv = rgb_conversion("sRGB", w.white_XYZ)
    for f in (
        lambda x: XYZ_to_RGB(x, conv),
        lambda x: XYZ_to_xy(x, w.white_xy),
        lambda x: XYZ_to_Lab(x, w.white_XYZ),
        eotf_inverse_sRGB,
        lambda x: spectrum_to_RGB(x[..., :1] * np.ones(wl.size), w, conv),
    ):
        out = np.asarray(jax.jit(f)(np.broadcast_to(vals[:, None], (6, 3))))
        assert out.shape == (6, 3) if out.shape[-1] == 3 else out.shape == (6, 2)
        assert np.all(np.isfinite(out[:3]))
    dw = dominant_wavelength(np.stack([vals, vals], -1), [0.3127, 0.329])
    assert dw.shape == (6,)
    assert np.isnan(dw[-1])


# ---- XYZ → RGB → encoding ----


@pytest.mark.parametrize("colourspace", ["sRGB", "Adobe RGB (1998)", "Display P3", "ProPhoto RGB", "ITU-R BT.2020"])
@pytest.mark.parametrize("illuminant, cat", [("D65", "CAT02"), ("A", "CAT02"), ("D50", "Bradford")])
def test_xyz_to_rgb_matches_colour(colourspace, illuminant, cat):
    w = spectral_weights(np.arange(360.0, 831.0, 5), illuminant)
    conv = rgb_conversion(colourspace, w.white_XYZ, cat)
    rng = np.random.default_rng(0)
    XYZ = rng.uniform(0.05, 0.9, (20, 3))
    with quiet():
        ref = colour.XYZ_to_RGB(
            XYZ, colourspace, illuminant=w.white_xy, chromatic_adaptation_transform=cat, apply_cctf_encoding=False
        )
    np.testing.assert_allclose(np.asarray(XYZ_to_RGB(XYZ, conv)), ref, atol=1e-3)
    np.testing.assert_allclose(np.asarray(RGB_to_XYZ(XYZ_to_RGB(XYZ, conv), conv)), XYZ, atol=1e-12)
    # The scene white is the display white exactly.
    np.testing.assert_allclose(np.asarray(XYZ_to_RGB(w.white_XYZ, conv)), np.ones(3), atol=1e-12)


def test_encoded_srgb_matches_colour():
    wl = np.arange(360.0, 831.0, 5)
    w = spectral_weights(wl)
    conv = rgb_conversion("sRGB", w.white_XYZ)
    specs = 0.9 * spectra(wl)[[0, 1, 3]]  # in-gamut colours (the sine is outside: R > 1)
    mine = np.asarray(jax.jit(spectrum_to_RGB)(specs, w, conv))
    with quiet():
        ref = colour.XYZ_to_sRGB(colour_xyz(specs, wl, 5, "D65", DEFAULT_OBSERVER), illuminant=w.white_xy)
    np.testing.assert_allclose(mine, ref, atol=1e-3)


@pytest.mark.parametrize("colourspace", ["sRGB", "Adobe RGB (1998)", "Display P3"])
def test_xyz_to_display_rgb_is_the_encoding_in_gamut_and_the_paper_mapping_beyond(colourspace):
    w = spectral_weights(np.arange(360.0, 831.0, 5.0))
    conv = rgb_conversion(colourspace, w.white_XYZ, "CAT02")
    rgb = np.random.default_rng(5).uniform(0.02, 0.98, (50, 3))  # inside the gamut: untouched
    XYZ = np.asarray(RGB_to_XYZ(rgb, conv))
    encoded = np.asarray(colour.RGB_COLOURSPACES[colourspace].cctf_encoding(rgb), dtype=float)
    np.testing.assert_allclose(np.asarray(XYZ_to_display_RGB(XYZ, conv)), encoded, atol=1e-9)
    np.testing.assert_allclose(np.asarray(XYZ_to_display_RGB(XYZ, conv, encode=False)), rgb, atol=1e-12)
    beyond = np.array([[1.5, 0.2, -0.1], [0.3, 0.9, 1.4], [2.0, 2.0, 2.0]])
    shown = np.asarray(XYZ_to_display_RGB(RGB_to_XYZ(beyond, conv), conv, encode=False))
    assert np.all((shown >= 0) & (shown <= 1))
    lum = np.asarray(conv.luminance)
    np.testing.assert_allclose(shown @ lum, np.minimum(beyond @ lum, 1), atol=1e-12)  # luminance kept, up to white
    unbounded = np.asarray(XYZ_to_display_RGB(RGB_to_XYZ(beyond, conv), conv, upper=None, encode=False))
    assert unbounded.min() >= 0 and unbounded.max() > 1


def test_eotf_inverse_srgb_matches_colour_and_is_smooth():
    x = np.array([-0.5, -1e-9, 0, 1e-6, 0.0031308, 0.0031309, 0.2, 0.5, 1, 2])
    np.testing.assert_allclose(np.asarray(eotf_inverse_sRGB(x)), colour.models.eotf_inverse_sRGB(x), atol=1e-12)
    g = jax.jit(jax.vmap(jax.grad(eotf_inverse_sRGB)))(jnp.asarray(x))
    assert np.all(np.isfinite(g))


def test_encode_other_colourspaces():
    rgb = np.array([[0.1, 0.5, 0.9]])
    for cs in ("Adobe RGB (1998)", "ProPhoto RGB"):
        ref = colour.RGB_COLOURSPACES[cs].cctf_encoding(rgb)
        np.testing.assert_allclose(encode_RGB(rgb, cs), ref, atol=1e-12)
    np.testing.assert_allclose(np.asarray(encode_RGB(rgb, "ACES2065-1")), rgb)
    np.testing.assert_allclose(np.asarray(encode_RGB(rgb, "Display P3")), colour.models.eotf_inverse_sRGB(rgb), atol=1e-12)
    with pytest.raises(TypeError, match="cannot be traced"):
        jax.jit(lambda x: encode_RGB(x, "Adobe RGB (1998)"))(rgb)


def test_unknown_colourspace_and_adaptation():
    with pytest.raises(ValueError, match="unknown colourspace"):
        rgb_conversion("nope")
    with pytest.raises(ValueError, match="unknown chromatic adaptation"):
        rgb_conversion("sRGB", np.array([0.95, 1.0, 1.09]), "nope")


def test_gradient_through_pipeline_is_finite():
    wl = np.arange(360.0, 831.0, 10)
    w = spectral_weights(wl)
    conv = rgb_conversion("sRGB", w.white_XYZ)
    narrow = np.exp(-(((wl - 520) / 8) ** 2))  # a saturated green, out of the sRGB gamut
    assert np.asarray(XYZ_to_RGB(spectrum_to_XYZ(narrow, w), conv)).min() < 0
    f = jax.jit(jax.vmap(jax.value_and_grad(lambda r: jnp.sum(spectrum_to_RGB(r, w, conv) ** 2))))
    _, g = f(jnp.asarray([np.zeros(wl.size), np.ones(wl.size), narrow, 3 * narrow, cu_f0(wl)]))
    assert np.all(np.isfinite(g))
    # Against central differences on the out-of-gamut colour.
    r0 = 0.3 * narrow + 0.01
    d = np.random.default_rng(0).normal(size=wl.size)
    eps = 1e-6
    (fp, fm, _, _, _), (_, _, g0, _, _) = f(jnp.asarray([r0 + eps * d, r0 - eps * d, r0, r0, r0]))
    assert float(jnp.vdot(g0, d)) == pytest.approx(float((fp - fm) / (2 * eps)), rel=1e-5)


# ---- chromaticity, CIELAB, ΔE2000 ----


def test_xy_and_lab_match_colour():
    rng = np.random.default_rng(1)
    XYZ = np.concatenate([rng.uniform(0, 1, (50, 3)), [[0.0, 0.0, 0.0], [1e-5, 2e-5, 1e-5]]])
    white = np.array([0.9504, 1.0, 1.0888])
    white_xy = white[:2] / white.sum()
    xy, xy_black, lab = jax.jit(lambda x: (XYZ_to_xy(x), XYZ_to_xy(x, white_xy), XYZ_to_Lab(x, white)))(XYZ)
    np.testing.assert_allclose(np.asarray(xy[:-2]), colour.XYZ_to_xy(XYZ[:-2]), atol=1e-14)
    np.testing.assert_allclose(np.asarray(xy_black[-2]), white_xy)
    np.testing.assert_allclose(np.asarray(lab), colour.XYZ_to_Lab(XYZ, white_xy), atol=1e-9)


def test_delta_e_2000_matches_colour():
    rng = np.random.default_rng(2)
    lab1 = np.column_stack([rng.uniform(0, 100, 200), rng.uniform(-80, 80, 200), rng.uniform(-80, 80, 200)])
    lab2 = lab1 + rng.normal(0, 8, lab1.shape)
    lab2[:20] = lab1[:20]  # equal
    lab1[20:30, 1:] = 0  # achromatic
    lab2[30:40, 1] = -lab1[30:40, 1]  # hue differences near 180°
    ref = colour.delta_E(lab1, lab2, method="CIE 2000")
    np.testing.assert_allclose(np.asarray(jax.jit(delta_E_CIE2000)(lab1, lab2)), ref, atol=1e-9)


def test_delta_e_2000_gradient_finite():
    g = jax.jit(jax.vmap(jax.grad(delta_E_CIE2000, argnums=(0, 1))))
    a = jnp.asarray([[50.0, 0, 0], [50.0, 10, 5], [50.0, 0, 0], [40.0, -20, 0]])
    b = jnp.asarray([[50.0, 0, 0], [50.0, 10, 5], [60.0, 20, -5], [40.0, 20, 0]])
    ga, gb = g(a, b)
    assert np.all(np.isfinite(ga)) and np.all(np.isfinite(gb))


# ---- dominant wavelength and purity ----


def test_dominant_wavelength_and_purity_match_colour():
    # Chromaticities of narrow-band spectra mixed with white: a spread of hues, some purples.
    wl = np.arange(360.0, 831.0, 5)
    w = spectral_weights(wl)
    rng = np.random.default_rng(3)
    centres = rng.uniform(420, 680, 40)
    specs = np.exp(-(((wl - centres[:, None]) / 15) ** 2)) + rng.uniform(0.02, 0.5, (40, 1))
    purples = np.exp(-(((wl - 430) / 15) ** 2)) + np.exp(-(((wl - 650) / 15) ** 2)) + 0.1
    specs = np.vstack([specs, purples])
    xy = np.asarray(XYZ_to_xy(spectrum_to_XYZ(specs, w)))
    xy_n = w.white_xy
    mine = dominant_wavelength(xy, xy_n)
    ref = colour.dominant_wavelength(xy, xy_n)[0]
    np.testing.assert_allclose(mine, ref, atol=1.0)
    assert mine[-1] < 0  # purple: −complementary wavelength
    np.testing.assert_allclose(excitation_purity(xy, xy_n), colour.excitation_purity(xy, xy_n), atol=1e-3)


def test_dominant_wavelength_10_degree_and_achromatic():
    xy_n = np.array([0.3138, 0.3310])
    xy = np.array([[0.55, 0.4], [0.2, 0.4], [0.3, 0.2]])
    np.testing.assert_allclose(
        dominant_wavelength(xy, xy_n, OBSERVER_10),
        colour.dominant_wavelength(xy, xy_n, colour.MSDS_CMFS[OBSERVER_10])[0],
        atol=1.0,
    )
    assert np.isnan(dominant_wavelength(xy_n, xy_n))
    assert excitation_purity(xy_n, xy_n) == 0


# ---- colour_report ----


def _spectral_material(fresnel="conductor", lobes=1, diffuse=None):
    wl = CU_NK[:, 0]
    n, k = CU_NK[:, 1], CU_NK[:, 2]
    f0 = ((n - 1) ** 2 + k**2) / ((n + 1) ** 2 + k**2)
    spec = {"f0": dict(f0=f0), "conductor": dict(n=n, k=k)}[fresnel]
    params = ctfit.Params(m=np.array([0.3]) if lobes else None, w=np.array([1.0]) if lobes else None, **spec)
    st = ctfit.Structure(lobes=lobes, fresnel=fresnel, diffuse=diffuse)
    return ctfit.Material(st, params, wavelength_nm=wl, name="Cu")


REPORT_KEYS = {
    "XYZ", "xy", "linear_rgb", "sRGB", "rgb", "hex", "Lab", "dominant_wavelength_nm", "excitation_purity",
    "illuminant", "colourspace", "angle_deg", "observer", "quantity", "in_gamut", "white_XYZ", "white_xy",
}  # fmt: skip


def test_colour_report_copper_matches_colour_science():
    mat = _spectral_material()
    rep = colour_report(mat, 0.0)
    assert REPORT_KEYS <= set(rep)
    json.dumps(rep, allow_nan=False)
    wl = np.arange(360.0, 831.0)
    f0 = cu_f0(wl)
    ref_xyz = colour_xyz(f0, wl, 1, "D65", DEFAULT_OBSERVER)
    np.testing.assert_allclose(rep["XYZ"], ref_xyz, atol=1e-3)
    with quiet():
        ref_srgb = colour.XYZ_to_sRGB(ref_xyz, illuminant=rep["white_xy"])
        ref_lab = colour.XYZ_to_Lab(ref_xyz, rep["white_xy"])
    np.testing.assert_allclose(rep["sRGB"], ref_srgb, atol=1e-3)
    np.testing.assert_allclose(rep["Lab"], ref_lab, atol=1e-2)
    ref_dw = colour.dominant_wavelength(rep["xy"], rep["white_xy"])[0]
    assert rep["dominant_wavelength_nm"] == pytest.approx(float(ref_dw), abs=1.0)
    assert rep["excitation_purity"] == pytest.approx(float(colour.excitation_purity(rep["xy"], rep["white_xy"])), abs=1e-3)
    assert rep["hex"] == "#" + "".join(f"{round(v * 255):02x}" for v in rep["sRGB"])
    # copper is reddish-orange, and its reflection whitens towards grazing
    assert 580 < rep["dominant_wavelength_nm"] < 610
    grazing = colour_report(mat, 90.0)
    np.testing.assert_allclose(grazing["sRGB"], 1, atol=1e-9)
    assert grazing["hex"] == "#ffffff" and grazing["dominant_wavelength_nm"] is None
    assert colour_report(mat, 80.0)["excitation_purity"] < rep["excitation_purity"]


def test_colour_report_f0_and_conductor_agree_at_normal_incidence():
    wl = np.arange(360.0, 831.0)
    n, k = cu_nk(wl)
    st = ctfit.Structure(lobes=1, fresnel="conductor")
    lobe = dict(m=np.array([0.3]), w=np.array([1.0]))
    a = colour_report(ctfit.Material(st, ctfit.Params(n=n, k=k, **lobe), wavelength_nm=wl), 0.0)
    st = ctfit.Structure(lobes=1, fresnel="f0")
    b = colour_report(ctfit.Material(st, ctfit.Params(f0=cu_f0(wl), **lobe), wavelength_nm=wl), 0.0)
    np.testing.assert_allclose(a["XYZ"], b["XYZ"], atol=1e-12)
    # F0 interpolated between the tabulated wavelengths differs a little from F0 of interpolated n, k.
    c = colour_report(_spectral_material("f0"), 0.0)
    np.testing.assert_allclose(a["XYZ"], c["XYZ"], atol=2e-3)


def test_colour_report_options():
    mat = _spectral_material()
    rep = colour_report(mat, 30.0, illuminant="A", colourspace="Adobe RGB (1998)", observer=OBSERVER_10)
    assert rep["illuminant"] == "A" and rep["colourspace"] == "Adobe RGB (1998)"
    np.testing.assert_allclose(colour.Lab_to_XYZ(rep["Lab"], rep["white_xy"]), rep["XYZ"], atol=1e-9)
    assert all(0 <= v <= 1 for v in rep["rgb"] + rep["sRGB"])
    _, r = reflectance_spectrum(mat, 30.0, np.arange(360.0, 831.0))
    w = spectral_weights(np.arange(360.0, 831.0), "A", OBSERVER_10)
    np.testing.assert_allclose(rep["XYZ"], np.asarray(spectrum_to_XYZ(r, w)), atol=1e-12)


def test_colour_report_diffuse_only_and_white():
    mat = _spectral_material("f0", lobes=0, diffuse="F0/pi")
    rep = colour_report(mat, 45.0)
    assert rep["quantity"] == "pi*Rd"
    np.testing.assert_allclose(rep["XYZ"], colour_report(_spectral_material("f0"), 0.0)["XYZ"], atol=1e-12)
    white = ctfit.Material(
        ctfit.Structure(lobes=1), ctfit.Params(m=np.array([0.2]), w=np.array([1.0]), f0=np.ones(2)),
        wavelength_nm=np.array([400.0, 700.0]),
    )  # fmt: skip
    rep = colour_report(white, 0.0)
    np.testing.assert_allclose(rep["XYZ"], rep["white_XYZ"], atol=1e-12)
    np.testing.assert_allclose(rep["Lab"], [100, 0, 0], atol=1e-9)
    assert rep["hex"] == "#ffffff" and rep["excitation_purity"] == 0


def test_colour_report_rgb_material():
    mat = ctfit.Material(
        ctfit.Structure(lobes=0, diffuse="spectrum"),
        ctfit.Params(rd=np.array([0.05, 0.1, 0.8]) / np.pi),
        channels=("B", "G", "R"),
    )
    rep = colour_report(mat)
    np.testing.assert_allclose(rep["linear_rgb"], [0.8, 0.1, 0.05], atol=1e-12)
    np.testing.assert_allclose(rep["sRGB"], colour.models.eotf_inverse_sRGB(np.array([0.8, 0.1, 0.05])), atol=1e-12)


@pytest.mark.parametrize("angle", [-1.0, 91.0, float("nan"), float("inf")])
def test_colour_report_rejects_bad_angles(angle):
    with pytest.raises(ValueError, match="angle_deg"):
        colour_report(_spectral_material(), angle)


def test_importing_colour_science_leaves_numpy_printing_alone():
    """colour-science's import sets ``legacy="1.13"``; through ctfit it does not reach the user."""
    import subprocess
    import sys

    code = ("import numpy as np; before = np.get_printoptions()\n"
            "from ctfit._colour import colour_science; colour_science()\n"
            "print(np.get_printoptions() == before)")
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip() == "True"


def _infrared(wl):
    return ctfit.Material(ctfit.Structure(lobes=1), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.linspace(0.3, 0.9, len(wl))),
                          wavelength_nm=np.asarray(wl, float), name="ir")


@pytest.mark.parametrize("wl, held", [([900.0, 1200.0, 1500.0], "its 900 nm value held flat"), ([250.0, 300.0], "its 300 nm value held flat"),
                                      ([300.0, 900.0], "interpolated between its 300 and 900 nm values")])
def test_a_material_with_no_visible_band_gets_its_colour_with_a_warning(wl, held):
    """docs/formats.md holds a material at its end values: with no band in 380–780 nm, the whole
    colour is held (or interpolated across the visible), and the colour, the render and the RGB
    export say so (they were silent)."""
    from ctfit._export.rgb_bands import band_to_rgb
    from ctfit._render.scene import render_bands

    for make in (lambda m: colour_report(m, 0.0), band_to_rgb, render_bands):
        with pytest.warns(ctfit.SpectralResamplingWarning, match=f"material 'ir': no band in the visible range .*: its colour is {held}"):
            make(_infrared(wl))


@pytest.mark.parametrize("wl", [[700.0, 900.0, 1500.0], [1000.0]])
def test_a_material_with_a_visible_band_or_one_band_is_silent(wl):
    """One visible band among infrared ones gives a colour from data; one band is grey wherever it lies."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        colour_report(_infrared(wl), 0.0)
