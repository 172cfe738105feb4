"""The reflected intensity of eq. 1: closed forms, linearity, frames, silhouettes, gradients."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import make_params, structure_id

import ctfit
from ctfit import Light, Params, Structure, reflected_intensity

intensity = eqx.filter_jit(reflected_intensity)

Z = np.array([0.0, 0.0, 1.0])
RD = np.array([0.05, 0.1, 0.2])
LAMBERT = Structure(lobes=0, diffuse="spectrum")
METAL = Structure(lobes=2, fresnel="f0")
# A few structures that between them use every term (each costs a compilation).
SOME = [
    Structure(lobes=2, distribution="beckmann", geometry="v-cavity", fresnel="f0"),
    Structure(lobes=2, distribution="gaussian", geometry="smith", fresnel="conductor", diffuse="F0/pi", normalization="cook-torrance-1982"),
    Structure(lobes=2, distribution="beckmann", geometry="smith", fresnel="n", diffuse="spectrum"),
    Structure(lobes=0, diffuse="constant"),
]


def unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_lambertian_at_normal_incidence_is_I_domega_Rd():
    spectrum = np.array([0.7, 1.0, 1.3])
    light = Light(Z, spectrum, 1e-4)
    for view in (Z, unit([0.3, -0.2, 0.9]), unit([-0.9, 0.1, 0.2])):
        got = intensity(LAMBERT, Params(rd=jnp.asarray(RD)), Z, view, [light])
        np.testing.assert_allclose(got, spectrum * 1e-4 * RD, rtol=1e-15)


def test_lambertian_follows_cosine_law():
    light = Light(unit([1.0, 0.0, 1.0]), 2.0, 3e-4)
    got = intensity(LAMBERT, Params(rd=jnp.asarray(RD)), Z, Z, [light])
    np.testing.assert_allclose(got, 2.0 * 3e-4 * np.cos(np.pi / 4) * RD, rtol=1e-14)


def test_ambient_only_is_I_ia_pi_Rd():
    ambient = np.array([0.01, 0.02, 0.03])
    got = intensity(LAMBERT, Params(rd=jnp.asarray(RD)), Z, Z, [], ambient)
    np.testing.assert_allclose(got, ambient * np.pi * RD, rtol=1e-15)
    # A metal without a diffuse part reflects ambient light with its normal reflectance
    # (R_d = F0/π, so π R_d = F0).
    f0 = np.array([0.5, 0.6, 0.9])
    metal = make_params(METAL, f0=f0)
    normals = unit([[0.0, 0.0, 1.0], [0.5, 0.5, 0.7]])
    got = intensity(METAL, metal, normals, Z, [], ambient)
    np.testing.assert_allclose(got, np.broadcast_to(ambient * f0, (2, 3)), rtol=1e-14)


def test_ambient_adds_to_the_lights():
    params = make_params(SOME[0])
    light = Light(unit([0.2, 0.1, 1.0]), np.ones(3), 1e-4)
    n = unit([0.1, 0.0, 1.0])
    amb = np.array([0.01, 0.01, 0.02])
    with_amb = intensity(SOME[0], params, n, Z, [light], amb)
    without = intensity(SOME[0], params, n, Z, [light])
    np.testing.assert_allclose(with_amb - without, amb * np.asarray(ctfit.ambient_reflectance(SOME[0], params)), rtol=1e-12)


@pytest.mark.parametrize("structure", SOME[1::2], ids=structure_id)
def test_linear_in_the_lights(structure):
    params = make_params(structure)
    rng = np.random.default_rng(3)
    normals = unit(rng.normal(size=(50, 3)) * [1, 1, 0.3] + [0, 0, 0.8])
    view = unit([0.1, -0.2, 1.0])
    a = Light(unit([-0.4, 0.5, 0.7]), np.array([0.9, 1.0, 1.1]), 1e-4)
    b = Light(unit([0.7, 0.2, 0.6]), np.array([1.2, 1.0, 0.8]), 2e-4)
    ia = intensity(structure, params, normals, view, [a])
    ib = intensity(structure, params, normals, view, [b])
    np.testing.assert_allclose(intensity(structure, params, normals, view, [a, b]), ia + ib, rtol=1e-13, atol=1e-300)
    doubled = Light(a.direction, 2 * a.spectrum, a.solid_angle)
    np.testing.assert_allclose(intensity(structure, params, normals, view, [doubled]), 2 * ia, rtol=1e-14, atol=1e-300)
    wider = Light(a.direction, a.spectrum, 3 * a.solid_angle)
    np.testing.assert_allclose(intensity(structure, params, normals, view, [wider]), 3 * ia, rtol=1e-14, atol=1e-300)


def _rotation(axis, angle):
    axis = unit(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


@pytest.mark.parametrize("structure", SOME[:2], ids=structure_id)
def test_world_frame_equals_local_frame(structure):
    """Rotating normal, light and viewer together changes nothing; N = z matches brdf directly."""
    params = make_params(structure)
    l_loc = unit([0.3, 0.2, 0.9])
    v_loc = unit([-0.5, 0.1, 0.8])
    spectrum = np.array([1.0, 0.8, 0.6])
    expect = spectrum * 1e-4 * l_loc[2] * np.asarray(ctfit.brdf(structure, params, ctfit.geometry(l_loc, v_loc)))
    got = intensity(structure, params, Z, v_loc, [Light(l_loc, spectrum, 1e-4)])
    np.testing.assert_allclose(got, expect, rtol=1e-13)
    rot = _rotation([0.3, -1.0, 0.4], 1.1)
    got_rot = intensity(structure, params, rot @ Z, rot @ v_loc, [Light(rot @ l_loc, spectrum, 1e-4)])
    np.testing.assert_allclose(got_rot, expect, rtol=1e-12)


def test_light_behind_the_surface_adds_nothing():
    params = make_params(SOME[0])
    behind = Light(unit([0.3, 0.0, -0.5]), np.ones(3), 1e-4)
    got = intensity(SOME[0], params, Z, unit([0.2, 0.1, 1.0]), [behind])
    assert np.all(np.asarray(got) == 0)


def _silhouette_normals():
    """Normals around the rim of a sphere seen along +z: N·V = 0, tiny, and negative."""
    phi = np.linspace(0, 2 * np.pi, 17)
    out = []
    for z in (0.0, 1e-300, 1e-12, 1e-6, -1e-9):
        r = np.sqrt(1 - z * z)
        out.append(np.stack([r * np.cos(phi), r * np.sin(phi), np.full_like(phi, z)], axis=-1))
    return np.concatenate(out)


LIGHTS = [Light(unit([-0.45, 0.55, 0.7]), np.ones(3), 1e-4), Light(unit([0.75, 0.25, 0.61]), np.ones(3), 2e-4)]


@pytest.mark.parametrize("structure", SOME, ids=structure_id)
def test_no_nan_on_the_silhouette(structure):
    params = make_params(structure)
    got = np.asarray(intensity(structure, params, _silhouette_normals(), Z, LIGHTS, np.full(3, 0.01)))
    assert np.all(np.isfinite(got))
    assert np.all(got >= 0)


# Gradients at the silhouette, through the renderer: tests/test_render.py::test_rendered_pixel_gradients_are_finite.


def test_broadcasts_over_an_image():
    params = make_params(SOME[0])
    normals = np.broadcast_to(unit([0.1, 0.2, 1.0]), (4, 5, 3))
    got = intensity(SOME[0], params, normals, Z, [Light(Z, np.ones(3), 1e-4)])
    assert got.shape == (4, 5, 3)
    np.testing.assert_allclose(got, np.broadcast_to(got[0, 0], (4, 5, 3)), rtol=0)


def test_gradients_finite_and_match_finite_differences():
    structure = Structure(lobes=1, fresnel="f0", diffuse="spectrum")
    params = make_params(structure, m=(0.3,))
    normal = unit([0.2, 0.1, 1.0])
    light = Light(unit([0.3, -0.2, 1.0]), np.ones(3), 1e-4)

    def pixel(m):
        p = eqx.tree_at(lambda q: q.m, params, m)
        return reflected_intensity(structure, p, normal, Z, [light])[1]

    pixel = jax.jit(pixel)
    m0 = jnp.asarray(params.m)
    g = float(jax.jit(jax.grad(pixel))(m0)[0])
    h = 1e-6
    fd = (float(pixel(m0 + h)) - float(pixel(m0 - h))) / (2 * h)
    assert np.isfinite(g) and g == pytest.approx(fd, rel=1e-6)


def test_float32_stays_float32():
    params = make_params(SOME[0], dtype=np.float32)
    n = jnp.asarray(unit([0.1, 0.0, 1.0]), jnp.float32)
    got = intensity(SOME[0], params, n, jnp.asarray(Z, jnp.float32), [Light(jnp.asarray(Z, jnp.float32), jnp.ones(3, jnp.float32), jnp.float32(1e-4))])
    assert got.dtype == jnp.float32 and np.all(np.isfinite(np.asarray(got)))


def test_light_validation_and_no_terms():
    with pytest.raises(ValueError, match="direction"):
        Light(np.ones(2), np.ones(3), 1e-4)
    with pytest.raises(ValueError, match="solid_angle"):
        Light(Z, np.ones(3), np.ones(2))
    np.testing.assert_allclose(Light([0.0, 0.0, 2.0], 1.0, 1e-4).direction, Z)
    with pytest.raises(ValueError, match="at least one light"):
        reflected_intensity(LAMBERT, Params(rd=jnp.asarray(RD)), Z, Z, [])
