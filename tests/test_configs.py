"""The bundled configs/*.toml: every one loads, evaluates finite and ≥ 0, and says what it claims."""

import pathlib

import numpy as np
import pytest

import ctfit
from ctfit import load_material, read_optical_constants

ROOT = pathlib.Path(__file__).resolve().parent.parent
CONFIGS = sorted((ROOT / "configs").glob("*.toml"))
EXPECTED = {
    "copper-vase", "copper-vase-conductor", "copper-plastic-vase",
    "carbon", "rubber", "obsidian", "lunar-dust", "olive-drab", "rust",
    "copper", "gold", "silver", "aluminium", "iron", "stainless-steel",
}  # fmt: skip
# The paper's nonmetals: (s, d, m); m None: no specular part.
TABLE_I = {
    "carbon": (0.3, 0.7, 0.40),
    "rubber": (0.4, 0.6, 0.30),
    "obsidian": (0.8, 0.2, 0.15),
    "lunar-dust": (0.0, 1.0, None),
    "olive-drab": (0.3, 0.7, 0.50),
    "rust": (0.2, 0.8, 0.35),
}
METALS = {
    "copper": "Cu", "gold": "Au", "silver": "Ag", "aluminium": "Al", "iron": "Fe",
    "stainless-steel": "stainless-steel",
}  # fmt: skip


def test_all_configs_present():
    assert EXPECTED <= {p.stem for p in CONFIGS}


def _grid():
    t = np.array([0.0, 20.0, 45.0, 70.0, 89.0])
    ti, to, po = np.meshgrid(t, t, np.array([0.0, 90.0, 180.0]), indexing="ij")
    return ctfit.geometry_from_angles_deg(ti.ravel(), 0.0, to.ravel(), po.ravel())


@pytest.mark.parametrize("config", CONFIGS, ids=lambda p: p.stem)
def test_config_evaluates_finite_nonnegative(config):
    material = load_material(config)
    assert material.name
    params = material.params_at(material.wavelength_nm)
    r = np.asarray(ctfit.brdf(material.structure, params, _grid()))
    assert r.shape[0] == 75 and r.shape[-1] in (1, len(material.wavelength_nm))
    assert np.all(np.isfinite(r)) and np.all(r >= 0)
    assert np.any(r > 0)


@pytest.mark.parametrize("stem", sorted(TABLE_I))
def test_table_one_nonmetals(stem):
    s, d, m = TABLE_I[stem]
    material = load_material(ROOT / "configs" / f"{stem}.toml")
    st, p = material.structure, material.params
    assert st.diffuse == "spectrum" and np.all(p.rd > 0) and np.all(p.rd < 1 / np.pi)
    if m is None:
        assert st.lobes == 0 and p.m is None
        return
    assert float(p.s) == s and st.lobes == 1
    np.testing.assert_array_equal(p.m, [m])
    assert st.fresnel == "n" and np.all((p.n > 1.3) & (p.n < 2.5))


@pytest.mark.parametrize("stem", sorted(METALS))
def test_metals_use_their_tables(stem):
    material = load_material(ROOT / "configs" / f"{stem}.toml")
    table = read_optical_constants(METALS[stem])
    assert material.structure.fresnel == "conductor" and material.structure.diffuse is None
    np.testing.assert_array_equal(material.params.n, table["n"])
    np.testing.assert_array_equal(material.params.k, table["k"])


def test_copper_vase_is_the_papers():
    vase = load_material(ROOT / "configs" / "copper-vase.toml")
    table = read_optical_constants("Cu")
    assert vase.structure.lobes == 2 and vase.structure.diffuse is None and vase.structure.fresnel == "f0"
    np.testing.assert_array_equal(vase.params.m, [0.2, 0.4])
    np.testing.assert_array_equal(vase.params.w, [0.6, 0.4])
    np.testing.assert_array_equal(vase.params.f0, table["F0"])
    conductor = load_material(ROOT / "configs" / "copper-vase-conductor.toml")
    assert conductor.structure.fresnel == "conductor"
    np.testing.assert_array_equal(conductor.params.m, vase.params.m)
    # Both Fresnel forms agree at normal incidence: same colour head-on.
    head_on = ctfit.geometry_from_angles_deg(0.0, 0.0, 0.0, 0.0)
    np.testing.assert_allclose(
        ctfit.brdf(vase.structure, vase.params, head_on),
        ctfit.brdf(conductor.structure, conductor.params, head_on),
        rtol=1e-5,
    )


def test_copper_plastic_vase_diffuse_is_copper():
    vase = load_material(ROOT / "configs" / "copper-plastic-vase.toml")
    table = read_optical_constants("Cu")
    assert float(vase.params.s) == 0.1 and vase.structure.diffuse == "spectrum"
    np.testing.assert_array_equal(vase.params.m, [0.15])
    expected = np.interp(vase.wavelength_nm, table["wavelength_nm"], table["F0"]) / np.pi
    np.testing.assert_allclose(vase.params.rd, expected, atol=5e-6)
    f0 = ((vase.params.n - 1) / (vase.params.n + 1)) ** 2
    assert np.all((f0 > 0.04) & (f0 < 0.05))  # a vinyl (PVC) mirror
