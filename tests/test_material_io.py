"""Material files (TOML configs, fit-result JSON): key mapping, errors, round trips."""

import dataclasses
import json
import math
import os
import pathlib
import re
import shutil

import hypothesis.strategies as st
import jax.numpy as jnp
import numpy as np
import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings

import ctfit
from ctfit import Material, MaterialError, Params, Structure, load_material, material_from_dict, material_to_dict, read_optical_constants, save_material_json

ROOT = pathlib.Path(__file__).resolve().parent.parent
CONFIGS = sorted((ROOT / "configs").glob("*.toml"))
CU = ROOT / "ctfit" / "data" / "optical_constants" / "Cu.csv"

BASE = """
s = 0.25
d = 0.75
lobes = [{ m = 0.3, weight = 1.0 }]
wavelength_nm = [400, 500, 600]
"""


def write(tmp_path, text, name="m.toml"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def edit(old, new):
    """BASE with ``old`` replaced by ``new`` (appended when ``old`` is empty), plus F0."""
    return (BASE.replace(old, new) if old else BASE + new) + "F0 = 0.04\n"


def load_text(tmp_path, text, name="m.toml"):
    return load_material(write(tmp_path, text, name))


def assert_same_material(a: Material, b: Material):
    assert a.structure == b.structure
    for field in ("s", "m", "w", "f0", "n", "k", "rd"):
        x, y = getattr(a.params, field), getattr(b.params, field)
        assert (x is None) == (y is None), field
        if x is not None:
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y), err_msg=field)
    if a.wavelength_nm is None:
        assert b.wavelength_nm is None
    else:
        np.testing.assert_array_equal(a.wavelength_nm, b.wavelength_nm)
    assert a.channels == b.channels
    assert a.name == b.name
    assert a.meta == b.meta


# --- key mapping ----------------------------------------------------------------------------------


def test_base_material(tmp_path):
    m = load_text(tmp_path, BASE + "n = [1.5, 1.5, 1.5]\n")
    assert m.structure == Structure(lobes=1, fresnel="n", diffuse="F0/pi")
    assert float(m.params.s) == 0.25
    np.testing.assert_array_equal(m.params.m, [0.3])
    np.testing.assert_array_equal(m.params.w, [1.0])
    np.testing.assert_array_equal(m.params.n, [1.5, 1.5, 1.5])
    assert m.params.f0 is None and m.params.k is None and m.params.rd is None
    np.testing.assert_array_equal(m.wavelength_nm, [400, 500, 600])
    assert m.wavelength_nm.dtype == np.float64
    assert m.name == "m" and m.meta == {}


@pytest.mark.parametrize(
    "fresnel_keys, mode, fields",
    [
        ("F0 = [0.04, 0.05, 0.06]", "f0", {"f0"}),
        ("n = 1.5", "n", {"n"}),
        ("n = [0.2, 0.3, 0.4]\nk = [3.0, 3.5, 4.0]", "conductor", {"n", "k"}),
        ('fresnel = "n"\nn = 1.5\nF0 = 0.04', "n", {"n"}),
        ('fresnel = "f0"\nF0 = 0.04\nn = 1.5', "f0", {"f0"}),
    ],
)
def test_fresnel_forms(tmp_path, fresnel_keys, mode, fields):
    m = load_text(tmp_path, BASE + fresnel_keys + "\n")
    assert m.structure.fresnel == mode
    present = {f for f in ("f0", "n", "k") if getattr(m.params, f) is not None}
    assert present == fields
    for f in fields:
        assert np.shape(getattr(m.params, f)) == (3,)


def test_scalar_is_broadcast_to_bands(tmp_path):
    m = load_text(tmp_path, BASE + "F0 = 0.04\n")
    np.testing.assert_array_equal(m.params.f0, [0.04] * 3)


@pytest.mark.parametrize(
    "rd, diffuse, value",
    [
        (None, "F0/pi", None),
        ('"F0/pi"', "F0/pi", None),
        ("0.1", "constant", 0.1),
        ("[0.1, 0.2, 0.3]", "spectrum", [0.1, 0.2, 0.3]),
    ],
)
def test_rd_forms(tmp_path, rd, diffuse, value):
    m = load_text(tmp_path, BASE + "F0 = 0.04\n" + ("" if rd is None else f"Rd = {rd}\n"))
    assert m.structure.diffuse == diffuse
    if value is None:
        assert m.params.rd is None
    else:
        np.testing.assert_array_equal(m.params.rd, value)
        assert np.ndim(m.params.rd) == np.ndim(value)


def test_d_zero_has_no_diffuse_part(tmp_path):
    m = load_text(tmp_path, BASE.replace("s = 0.25\nd = 0.75", "s = 1\nd = 0") + "F0 = 0.9\n")
    assert m.structure.diffuse is None and m.params.s is None and m.params.rd is None


def test_s_zero_has_no_specular_part(tmp_path):
    text = 's = 0\nd = 1\nwavelength_nm = [400, 500]\nRd = [0.1, 0.2]\n'
    m = load_text(tmp_path, text)
    assert m.structure.lobes == 0 and m.structure.diffuse == "spectrum"
    assert m.params.m is None and m.params.w is None and m.params.s is None and m.params.f0 is None


def test_s_zero_with_f0_over_pi_keeps_fresnel_data(tmp_path):
    m = load_text(tmp_path, "s = 0\nd = 1\nlobes = []\nwavelength_nm = [500]\nF0 = [0.3]\n")
    assert m.structure.lobes == 0 and m.structure.diffuse == "F0/pi"
    np.testing.assert_array_equal(m.params.f0, [0.3])


def test_only_one_fraction_given(tmp_path):
    m = load_text(tmp_path, BASE.replace("d = 0.75\n", "") + "F0 = 0.04\n")
    assert float(m.params.s) == 0.25
    m = load_text(tmp_path, BASE.replace("s = 0.25\n", "") + "F0 = 0.04\n")
    assert float(m.params.s) == 0.25


def test_lobes_sorted_by_m(tmp_path):
    text = BASE.replace(
        "lobes = [{ m = 0.3, weight = 1.0 }]",
        "lobes = [{ m = 0.4, weight = 0.4 }, { m = 0.2, weight = 0.6 }]",
    )
    m = load_text(tmp_path, text + "F0 = 0.9\n")
    np.testing.assert_array_equal(m.params.m, [0.2, 0.4])
    np.testing.assert_array_equal(m.params.w, [0.6, 0.4])


def test_single_lobe_weight_defaults_to_one(tmp_path):
    m = load_text(tmp_path, BASE.replace(", weight = 1.0", "") + "F0 = 0.04\n")
    np.testing.assert_array_equal(m.params.w, [1.0])


def test_structure_keys(tmp_path):
    extra = 'distribution = "gaussian"\ngeometry = "smith"\nnormalization = "cook-torrance-1982"\n'
    m = load_text(tmp_path, BASE + extra + "F0 = 0.04\n")
    assert (m.structure.distribution, m.structure.geometry, m.structure.normalization) == (
        "gaussian",
        "smith",
        "cook-torrance-1982",
    )


def test_channels(tmp_path):
    text = BASE.replace("wavelength_nm = [400, 500, 600]", 'channels = ["R", "G", "B"]')
    m = load_text(tmp_path, text + "F0 = [0.9, 0.6, 0.5]\nRd = [0.1, 0.05, 0.02]\n")
    assert m.channels == ("R", "G", "B") and m.wavelength_nm is None and m.is_rgb
    np.testing.assert_array_equal(m.params_at(channels=["B"]).f0, [0.5])


def test_meta_keeps_unknown_keys(tmp_path):
    m = load_text(tmp_path, BASE + "F0 = 0.04\nnote = \"hello\"\n[fit]\nconverged = true\nsteps = 3\n")
    assert m.meta == {"note": "hello", "fit": {"converged": True, "steps": 3}}


def test_name_key(tmp_path):
    assert load_text(tmp_path, BASE + 'F0 = 0.04\nname = "vase"\n').name == "vase"


# --- optical constants ------------------------------------------------------------------------------


def test_optical_constants_by_name_are_the_packaged_tables(tmp_path):
    table = read_optical_constants(CU)
    m = load_text(tmp_path, "s = 1\nd = 0\nlobes = [{ m = 0.2 }]\noptical_constants = \"Cu\"\n")
    assert m.structure.fresnel == "conductor"
    np.testing.assert_array_equal(m.wavelength_nm, table["wavelength_nm"])
    np.testing.assert_array_equal(m.params.n, table["n"])
    np.testing.assert_array_equal(m.params.k, table["k"])


def test_optical_constants_relative_to_file_first(tmp_path):
    (tmp_path / "measurements").mkdir()
    (tmp_path / "measurements" / "Cu.csv").write_text("wavelength_nm,n,k\n500,1.0,2.0\n600,1.5,3.0\n")
    text = 's = 1\nd = 0\nlobes = [{ m = 0.2 }]\noptical_constants = "measurements/Cu.csv"\nfresnel = "f0"\n'
    m = load_text(tmp_path, text)
    np.testing.assert_array_equal(m.wavelength_nm, [500, 600])
    np.testing.assert_allclose(m.params.f0, [(0 + 4) / (4 + 4), (0.25 + 9) / (6.25 + 9)])


def test_read_optical_constants(tmp_path):
    table = read_optical_constants(CU)
    assert set(table) == {"wavelength_nm", "n", "k", "F0", "meta"}
    assert table["meta"]["material"] == "Copper (Cu)"
    assert "CC0" in table["meta"]["licence"]
    path = write(tmp_path, "# a: b\n# free text\n\nwavelength_nm,n,k\n500,1,2\n", "t.csv")
    t = read_optical_constants(path)
    assert t["meta"] == {"a": "b"}
    np.testing.assert_allclose(t["F0"], [0.5])


@pytest.mark.parametrize(
    "text, match",
    [
        ("wavelength_nm,n\n500,1\n", r"t\.csv:1: header lacks column\(s\) \['k'\]"),
        ("wavelength_nm,n,k\n500,1\n", r"t\.csv:2: 2 values, header has 3"),
        ("wavelength_nm,n,k\n500,1,x\n", r"t\.csv:2: column 'k' \(3\): 'x' is not a number"),
        ("wavelength_nm,n,k\n", r"t\.csv: no data rows"),
        ("wavelength_nm,n,k\n600,1,2\n# note\n500,1,2\n", r"t\.csv:4: column 'wavelength_nm' \(1\): 500 is not above the row before's: wavelengths must be "
                                                          "strictly increasing"),
        ("wavelength_nm,n,k\n600,nan,2\n", r"t\.csv:2: column 'n' \(2\): nan is not a finite number"),
        # Values a material file refuses were read here (F0 = 2.08 of n = −1.2, k = 2.1):
        ("wavelength_nm,n,k\n500,1,2\n600,-1.2,2.1\n", r"t\.csv:3: column 'n' \(2\): -1.2 is negative \(a refractive index is ≥ 0\)"),
        ("wavelength_nm,n,k\n500,1,-2\n", r"t\.csv:2: column 'k' \(3\): -2 is negative \(an extinction coefficient is ≥ 0\)"),
        ("wavelength_nm,n,k\n0,1,2\n600,1,2\n", r"t\.csv:2: column 'wavelength_nm' \(1\): 0 is not a wavelength \(a positive number of nm\)"),
        ("wavelength_nm,n,k,F0\n500,1.2,2.1,0.9\n",
         r"t\.csv:2: column 'F0' \(4\): 0.9 is not \(\(n − 1\)² \+ k²\)/\(\(n \+ 1\)² \+ k²\) of its n and k \(0.481081\)"),
    ],
)
def test_read_optical_constants_errors(tmp_path, text, match):
    with pytest.raises(MaterialError, match=match):
        read_optical_constants(write(tmp_path, text, "t.csv"))


# --- errors -----------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "text, match",
    [
        (edit("weight = 1.0", "weight = 0.9"), r"key 'lobes\[0\]\.weight': weights sum to 0\.9, must sum to 1"),
        (
            edit("{ m = 0.3, weight = 1.0 }", "{ m = 0.3, weight = 0.5 }, { m = 0.2, weight = 0.4 }"),
            r"key 'lobes\[1\]\.weight': weights sum to 0\.9, must sum to 1",
        ),
        (BASE.replace("d = 0.75", "d = 0.7") + "F0 = 0.04\n", r"key 'd': s \+ d = 0\.95, must be 1"),
        (BASE.replace("s = 0.25", "s = 1.5") + "F0 = 0.04\n", r"key 's': 1\.5 is outside \[0, 1\]"),
        (BASE.replace("s = 0.25\nd = 0.75\n", "") + "F0 = 0.04\n", r"key 's': missing"),
        (BASE.replace("m = 0.3", "m = 0") + "F0 = 0.04\n", r"key 'lobes\[0\]\.m': 0\.0 is outside \(0, inf\]"),
        (BASE.replace("m = 0.3", "m = true") + "F0 = 0.04\n", r"key 'lobes\[0\]\.m': must be a number"),
        (BASE.replace("weight", "wieght") + "F0 = 0.04\n", r"key 'lobes\[0\]\.wieght': unknown key"),
        (BASE.replace("lobes = [{ m = 0.3, weight = 1.0 }]", "lobes = []") + "F0 = 0.04\n", r"key 'lobes': missing"),
        (edit("lobes = [{ m = 0.3, weight = 1.0 }]", "lobes = 3"), r"key 'lobes': must be a list"),
        ("s = 0\nd = 1\nlobes = [{ m = 0.3 }]\nwavelength_nm = [500]\nRd = 0.1\n", r"key 'lobes': must be absent"),
        ("s = 0\nd = 1\nwavelength_nm = [500]\nRd = 0.1\nn = 1.5\n", r"key 'n': not used"),
        (BASE.replace("s = 0.25\nd = 0.75", "s = 1\nd = 0") + "F0 = 0.04\nRd = 0.1\n", r"key 'Rd': not used: d = 0"),
        (BASE + 'F0 = 0.04\nRd = "F0"\n', r"key 'Rd': must be \"F0/pi\""),
        (BASE + "F0 = 0.04\nRd = [0.1]\n", r"key 'Rd': has 1 values, wavelength_nm has 3"),
        (BASE + 'F0 = 0.04\ndistribution = "ggx"\n', r"key 'distribution': must be one of \['beckmann', 'gaussian'\]"),
        (BASE + 'F0 = 0.04\ngeometry = "x"\n', r"key 'geometry': must be one of"),
        (BASE + 'F0 = 0.04\nnormalization = "x"\n', r"key 'normalization': must be one of"),
        (BASE + 'F0 = 0.04\nfresnel = "x"\n', r"key 'fresnel': must be one of"),
        (BASE, r"key 'F0': missing"),
        (BASE + "F0 = [0.04, 1.2, 0.1]\n", r"key 'F0\[1\]': 1\.2 is outside \[0, 1\]"),
        (BASE + "n = [1.5, -1, 1.5]\n", r"key 'n\[1\]': -1\.0 is outside \(0, inf\]"),
        (BASE + "n = 1.5\nk = -1\n", r"key 'k': -1\.0 is outside \[0, inf\]"),
        (BASE + 'fresnel = "conductor"\nn = 1.5\n', r"key 'k': missing: fresnel = \"conductor\" needs n and k"),
        (BASE + 'fresnel = "n"\nn = 1.5\nk = 1\n', r"key 'k': only with fresnel = \"conductor\""),
        (BASE + "F0 = 0.04\nn = 2.0\n", r"key 'n\[0\]': 2\.0 is inconsistent with fresnel = \"f0\""),
        (BASE + "n = 1.5\nk = 1\nF0 = 0.5\n", r"key 'F0\[0\]': 0\.5 is inconsistent"),
        (edit("[400, 500, 600]", "[400, 400, 600]"), r"key 'wavelength_nm': must be strictly increasing"),
        (BASE.replace("[400, 500, 600]", "[]") + "F0 = 0.04\n", r"key 'wavelength_nm': must be a non-empty list"),
        (BASE.replace("wavelength_nm = [400, 500, 600]", "") + "F0 = 0.04\n", r"key 'wavelength_nm': missing"),
        (BASE + 'F0 = 0.04\nchannels = ["R"]\n', r"key 'channels': give only one of"),
        (BASE.replace("wavelength_nm = [400, 500, 600]", 'channels = ["R", "R"]') + "F0 = 0.04\n", r"unique"),
        (edit("", 'distrbution = "beckmann"\n'), r"key 'distrbution': unknown key; did you mean 'distribution'\?"),
        (BASE + "F0 = 0.04\nrd = 0.1\n", r"key 'rd': unknown key; did you mean 'Rd'\?"),
        (BASE + "F0 = 0.04\nname = 3\n", r"key 'name': must be a string"),
        (
            "s = 1\nd = 0\nlobes = [{ m = 0.2 }]\noptical_constants = \"measurements/none.csv\"\n",
            r"key 'optical_constants': no file 'measurements/none.csv' \(looked for .*\); ctfit ships Ag, Al, Au, Cu, Fe, stainless-steel",
        ),
        (
            "s = 1\nd = 0\nlobes = [{ m = 0.2 }]\noptical_constants = \"Cux\"\n",
            r"key 'optical_constants': 'Cux': no such optical constants table; ctfit ships Ag, Al, Au, Cu, Fe, stainless-steel",
        ),
        (
            "s = 1\nd = 0\nlobes = [{ m = 0.2 }]\noptical_constants = \"Cu\"\nF0 = 0.5\n",
            r"key 'F0': give either optical_constants or F0/n/k",
        ),
        (
            BASE.replace("lobes = [{ m = 0.3, weight = 1.0 }]", "lobes = [" + "{ m = 0.3, weight = 0.1 }, " * 9 + "]"),
            r"key 'lobes': 9 lobes, at most 8",
        ),
    ],
)
def test_semantic_errors_name_file_and_key(tmp_path, text, match):
    path = write(tmp_path, text)
    with pytest.raises(MaterialError, match=match) as info:
        load_material(path)
    assert str(info.value).startswith(f"{path}: key '")
    assert isinstance(info.value, ValueError)


def test_toml_syntax_error_has_line_and_column(tmp_path):
    path = write(tmp_path, "s = 1\nd = 0\nlobes = [{ m = 0.2 },, ]\n")
    with pytest.raises(MaterialError, match=r"m\.toml:3:\d+: TOML syntax error: ") as info:
        load_material(path)
    assert "(at line" not in str(info.value)


def test_toml_error_at_end_of_document(tmp_path):
    with pytest.raises(MaterialError, match=r"m\.toml:3:1: TOML syntax error: Invalid value$"):
        load_material(write(tmp_path, "s = 1\nlobes = [\n"))


def test_json_syntax_error_has_line_and_column(tmp_path):
    path = write(tmp_path, '{\n  "s": 1,\n  "d": 0,,\n}\n', "m.json")
    with pytest.raises(MaterialError, match=r"m\.json:3:\d+: JSON syntax error: "):
        load_material(path)


def test_json_top_level_must_be_object(tmp_path):
    with pytest.raises(MaterialError, match=r"m\.json: the top level must be a JSON object"):
        load_material(write(tmp_path, "[1, 2]", "m.json"))


def test_missing_file_and_unknown_suffix(tmp_path):
    with pytest.raises(MaterialError, match=r"none\.toml: no such file"):
        load_material(tmp_path / "none.toml")
    with pytest.raises(MaterialError, match=r"unknown material file type '\.yaml'"):
        load_material(write(tmp_path, "s: 1", "m.yaml"))


def test_material_from_dict_source_in_errors():
    with pytest.raises(MaterialError, match=r"^<material>: key 's'"):
        material_from_dict({"wavelength_nm": [500]})
    with pytest.raises(MaterialError, match=r"^cli: a material is a table"):
        material_from_dict([1], source="cli")


# --- writing and round trips ------------------------------------------------------------------------


@pytest.mark.parametrize("config", CONFIGS, ids=lambda p: p.stem)
def test_config_round_trip(tmp_path, config):
    m = load_material(config)
    path = save_material_json(m, tmp_path / "result.json", extra={"fit": {"converged": True, "steps": 7}})
    again = load_material(path)
    assert again.meta == {"fit": {"converged": True, "steps": 7}}
    assert_same_material(dataclasses.replace(m, meta=again.meta), again)
    assert_same_material(again, load_material(save_material_json(again, tmp_path / "again.json")))


def test_result_json_carries_wavelengths_n_and_f0(tmp_path):
    for config in ("copper-vase.toml", "copper.toml", "rubber.toml"):
        d = json.loads(save_material_json(load_material(ROOT / "configs" / config), tmp_path / "r.json").read_text())
        assert {"wavelength_nm", "n", "F0", "fresnel", "s", "d", "lobes"} <= set(d)
        if d.get("family") == "plastic":  # one real index for every band: one number
            assert isinstance(d["n"], float) and isinstance(d["F0"], float)
        else:
            assert len(d["n"]) == len(d["F0"]) == len(d["wavelength_nm"])
        assert ("k" in d) == (d["fresnel"] == "conductor")


def test_result_lists_lobes_in_ascending_m():
    m = Material(
        Structure(lobes=2),
        Params(m=np.array([0.4, 0.2]), w=np.array([0.3, 0.7]), f0=np.array([0.9])),
        wavelength_nm=np.array([500.0]),
    )
    assert material_to_dict(m)["lobes"] == [{"m": 0.2, "weight": 0.7}, {"m": 0.4, "weight": 0.3}]


def test_derived_n_of_f0_one_is_null(tmp_path):
    params = Params(m=np.array([0.2]), w=np.array([1.0]), f0=np.array([0.5, 1.0]))
    m = Material(Structure(), params, wavelength_nm=np.array([400.0, 500.0]))
    d = material_to_dict(m)
    assert d["n"][1] is None and math.isfinite(d["n"][0])
    assert_same_material(m, load_material(save_material_json(m, tmp_path / "r.json")))


def test_meta_and_extra_are_json_ready(tmp_path):
    m = load_material(ROOT / "configs" / "rubber.toml")
    m = dataclasses.replace(m, meta={"fit": {"rmse": np.float32(0.5)}, "note": "x"})
    extra = {"fit": {"cost": np.float64(1.5), "se": jnp.array([1.0, 2.0]), "bad": float("nan"), "ok": np.bool_(True)}}
    d = material_to_dict(m, extra)
    assert d["fit"] == {"cost": 1.5, "se": [1.0, 2.0], "bad": None, "ok": True}  # extra replaces meta
    assert d["note"] == "x"
    json.dumps(d, allow_nan=False)
    with pytest.raises(MaterialError, match="extra key 's' would replace a model key"):
        material_to_dict(m, {"s": 1})
    with pytest.raises(TypeError, match="cannot write a object"):
        material_to_dict(m, {"x": object()})


def test_material_to_dict_is_toml_ready(tmp_path):
    m = load_material(ROOT / "configs" / "copper-plastic-vase.toml")
    path = tmp_path / "m.toml"
    path.write_text(tomli_w.dumps(material_to_dict(m)))
    assert_same_material(m, load_material(path))


def test_save_is_atomic(tmp_path, monkeypatch):
    m = load_material(ROOT / "configs" / "rubber.toml")
    path = save_material_json(m, tmp_path / "r.json")
    before = path.read_bytes()
    assert oct(path.stat().st_mode & 0o777) == "0o644"
    with pytest.raises(TypeError):
        save_material_json(m, path, extra={"x": object()})
    monkeypatch.setattr(os, "replace", lambda *a: (_ for _ in ()).throw(OSError("disk full")))
    with pytest.raises(OSError, match="disk full"):
        save_material_json(m, path, extra={"y": 1})
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]  # no temporary files left


def test_save_overwrites(tmp_path):
    m = load_material(ROOT / "configs" / "rubber.toml")
    path = tmp_path / "r.json"
    path.write_text("old")
    save_material_json(m, path, extra={"fit": {"steps": 1}})
    assert json.loads(path.read_text())["fit"] == {"steps": 1}


def test_copied_config_still_finds_its_table(tmp_path):
    shutil.copy(ROOT / "configs" / "copper.toml", tmp_path / "copper.toml")
    assert load_material(tmp_path / "copper.toml").structure.fresnel == "conductor"


@pytest.mark.parametrize("s", [0.0, 1.0])
@pytest.mark.parametrize("diffuse", ["F0/pi", "spectrum", "constant"])
def test_fraction_at_bound_drops_the_empty_part(tmp_path, s, diffuse):
    rd = {"F0/pi": None, "spectrum": np.array([0.1, 0.2]), "constant": np.asarray(0.1)}[diffuse]
    m = Material(
        Structure(lobes=1, fresnel="n", diffuse=diffuse),
        Params(s=np.asarray(s), m=np.array([0.3]), w=np.array([1.0]), n=np.array([1.5, 1.6]), rd=rd),
        wavelength_nm=np.array([400.0, 600.0]),
    )
    again = load_material(save_material_json(m, tmp_path / "r.json"))
    assert again.structure.has_specular == (s > 0) and again.structure.has_diffuse == (s < 1)
    geom = ctfit.geometry_from_angles_deg(np.array([10.0, 40.0]), 0.0, np.array([30.0, 20.0]), 180.0)
    expected = ctfit.brdf(m.structure, m.params, geom)
    got = ctfit.brdf(again.structure, again.params, geom)  # (2, 1) for a constant R_d alone
    np.testing.assert_allclose(np.broadcast_to(got, expected.shape), expected, rtol=1e-12)


# --- property: any valid material survives save → load ---------------------------------------------

_pos = st.floats(0.01, 2.0)


@st.composite
def materials(draw):
    lobes = draw(st.integers(0, 3))
    diffuse = draw(st.sampled_from(([None] if lobes else []) + ["F0/pi", "spectrum", "constant"]))
    fresnel = draw(st.sampled_from(["f0", "n", "conductor"]))
    rgb = draw(st.booleans())
    nb = 3 if rgb else draw(st.integers(1, 4))
    bands = lambda el: np.asarray(draw(st.lists(el, min_size=nb, max_size=nb)))
    structure = Structure(
        lobes=lobes,
        distribution=draw(st.sampled_from(["beckmann", "gaussian"])),
        geometry=draw(st.sampled_from(["v-cavity", "smith"])),
        fresnel=fresnel if (lobes or diffuse == "F0/pi") else "f0",
        diffuse=diffuse,
        normalization=draw(st.sampled_from(["normalized", "cook-torrance-1982"])),
    )
    fields = {}
    if lobes:
        w = np.asarray(draw(st.lists(st.floats(0.05, 1.0), min_size=lobes, max_size=lobes)))
        w = w / w.sum()
        w[-1] = 1 - math.fsum(w[:-1])
        fields["m"] = np.sort(np.asarray(draw(st.lists(_pos, min_size=lobes, max_size=lobes, unique=True))))
        fields["w"] = w
    if structure.has_s:
        fields["s"] = np.asarray(draw(st.floats(0.0, 1.0, exclude_min=True, exclude_max=True)))
    if structure.needs_fresnel_params:
        if structure.fresnel == "f0":
            fields["f0"] = bands(st.floats(0.0, 1.0))
        else:
            fields["n"] = bands(st.floats(0.05, 5.0))
        if structure.fresnel == "conductor":
            fields["k"] = bands(st.floats(0.0, 8.0))
    if diffuse == "spectrum":
        fields["rd"] = bands(st.floats(0.0, 1.0))
    elif diffuse == "constant":
        fields["rd"] = np.asarray(draw(st.floats(0.0, 1.0)))
    wl = None if rgb else np.cumsum(draw(st.lists(st.floats(1.0, 100.0), min_size=nb, max_size=nb))) + 300
    return Material(
        structure,
        Params(**fields),
        wavelength_nm=wl,
        channels=("R", "G", "B") if rgb else None,
        name=draw(st.text(max_size=5)),
        meta={"fit": {"steps": draw(st.integers(0, 9))}},
    )


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(materials())
def test_any_material_round_trips(tmp_path, material):
    assert_same_material(material, load_material(save_material_json(material, tmp_path / "r.json")))


# --- encodings -------------------------------------------------------------------------------------

JSON_DOC = '{"s": 1, "d": 0, "lobes": [{"m": 0.2}], "wavelength_nm": [500], "F0": 0.5}'


@pytest.mark.parametrize("name, text", [("m.toml", BASE + "F0 = 0.04\n"), ("m.json", JSON_DOC)])
def test_byte_order_mark_is_ignored(tmp_path, name, text):
    path = tmp_path / name
    path.write_bytes(b"\xef\xbb\xbf" + text.encode())
    assert load_material(path).structure.has_specular


@pytest.mark.parametrize("read, name", [(load_material, "m.toml"), (read_optical_constants, "t.csv")])
def test_undecodable_file(tmp_path, read, name):
    path = tmp_path / name
    path.write_bytes(b"# x\nwavelength_nm,n,k\n500,1,2 # \xff\n")
    with pytest.raises(MaterialError, match=rf"{name.replace('.', '[.]')}:3: byte 0xff at byte offset \d+ \(byte 11 of the line\) is not UTF-8"):
        read(path)


@pytest.mark.parametrize("read, name", [(load_material, "none.toml"), (read_optical_constants, "none.csv")])
def test_missing_and_unreadable_files_are_named(tmp_path, read, name):
    with pytest.raises(MaterialError, match=rf"{name.replace('.', '[.]')}: no such file"):
        read(tmp_path / name)
    folder = tmp_path / ("folder" + pathlib.Path(name).suffix)
    folder.mkdir()
    with pytest.raises(MaterialError, match=rf"{folder.name.replace('.', '[.]')}: not a regular file but a folder"):
        read(folder)


# --- hostile material files ----------------------------------------------------------------------

_OC = "s = 1\nd = 0\nlobes = [{{ m = 0.2 }}]\noptical_constants = \"{}\"\n"


@pytest.mark.parametrize("name", ["/etc/passwd", "../secret.csv", "/etc/../tmp/x.csv", "link.csv"])
def test_optical_constants_lead_nowhere_outside_the_material_files_folder(tmp_path, monkeypatch, name):
    """Only a .csv in the material file's folder (or below it, links resolved) is read, so a
    material file cannot make ctfit show a line of another file (/etc/shadow)."""
    (tmp_path / "secret.csv").write_text("wavelength_nm,n,k\n500,1,1\n# TOP-SECRET-LINE\n")
    folder = tmp_path / "materials"
    folder.mkdir()
    (folder / "link.csv").symlink_to(tmp_path / "secret.csv")
    with pytest.raises(MaterialError) as err:
        load_text(folder, _OC.format(name))
    assert "TOP-SECRET" not in str(err.value) and str(err.value).count("key 'optical_constants'") == 1
    assert re.search(r"is outside the material file's folder|nor the path of an optical constants CSV", str(err.value))


def test_optical_constants_from_a_folder_named_in_the_environment(tmp_path, monkeypatch):
    shared = tmp_path / "shared"
    shared.mkdir()
    (shared / "Cu2.csv").write_text("wavelength_nm,n,k\n500,1.0,2.0\n600,1.5,3.0\n")
    folder = tmp_path / "materials"
    folder.mkdir()
    for name in ("Cu2.csv", str(shared / "Cu2.csv")):
        with pytest.raises(MaterialError, match="no file|is outside"):
            load_text(folder, _OC.format(name))
        monkeypatch.setenv("CTFIT_OPTICAL_CONSTANTS", str(shared))
        assert load_text(folder, _OC.format(name)).wavelength_nm.tolist() == [500, 600]
        monkeypatch.delenv("CTFIT_OPTICAL_CONSTANTS")


def test_a_csv_that_is_no_optical_constants_table_is_not_quoted(tmp_path):
    (tmp_path / "notes.csv").write_text("private,words\n1,2\n")
    with pytest.raises(MaterialError) as err:
        load_text(tmp_path, _OC.format("notes.csv"))
    assert "header lacks column(s) ['wavelength_nm', 'n', 'k']: not an optical constants table" in str(err.value)
    assert "private" not in str(err.value) and str(err.value).count("key 'optical_constants'") == 1


def test_a_missing_table_is_named_once(tmp_path):
    with pytest.raises(MaterialError) as err:
        load_text(tmp_path, _OC.format("none.csv"))
    assert str(err.value).count("key 'optical_constants'") == 1


@pytest.mark.parametrize(
    "text, match",
    [
        (BASE + 'F0 = "' + "x" * 10_000_000 + '"\n', r"key 'F0': must be a number or a list over wavelength_nm, got 'x{80}'…$"),
        (BASE.replace("weight = 1.0", "weight = 1.0, " + "z" * 200 + " = 1") + "F0 = 0.04\n", r"key 'lobes\[0\]\.z{71}…': unknown key"),
        (BASE + "F0 = 0.04\nname = [" + "1, " * 100_000 + "]\n", r"key 'name': must be a string, got \[1, 1, .{60,}…$"),
    ],
    ids=["10 MB string", "long key", "long list"],
)
def test_errors_quote_at_most_80_characters_of_a_value(tmp_path, text, match):
    with pytest.raises(MaterialError, match=match) as err:
        load_text(tmp_path, text)
    assert len(str(err.value)) < len(str(tmp_path)) + 200


def test_a_material_file_larger_than_64_mib_is_not_read(tmp_path):
    path = tmp_path / "huge.toml"
    with open(path, "wb") as f:
        f.truncate((64 << 20) + 1)
    with pytest.raises(MaterialError, match=r"huge\.toml: 67108865 bytes: larger than the 64 MiB"):
        load_material(path)


@pytest.mark.parametrize("name", ["m.toml", "m.json"])
def test_a_note_nested_deeper_than_64_levels_is_refused_when_read(tmp_path, name):
    """Nesting the parser reads (900 levels of JSON) but that writing the material back could not
    walk (Python's recursion limit) is refused on reading; 60 levels read and write back."""
    def text(depth):
        doc = {"s": 1, "lobes": [{"m": 0.3}], "wavelength_nm": [550], "F0": 0.5}
        note = "[" * depth + "]" * depth
        return json.dumps(doc)[:-1] + f', "note": {note}}}' if name.endswith(".json") else tomli_w.dumps(doc) + f"note = {note}\n"

    with pytest.raises(MaterialError, match=r"m\.(toml|json): nested too deeply to read"):
        load_text(tmp_path, text(900 if name.endswith(".json") else 300), name)
    material = load_text(tmp_path, text(60), name)
    assert load_material(save_material_json(material, tmp_path / "back.json")).meta == material.meta


def test_a_plastic_with_no_specular_part_is_written_and_read_back():
    """A plastic fit can end at s = 0 (the data shows no specular part): written without the
    specular part (and so without its index, which a Lambertian R_d does not use), it reads back
    as the same material. It used to be refused while saving, so the fit was lost."""
    mat = Material(Structure(family="plastic", lobes=2, diffuse="spectrum"),
                   Params(s=np.asarray(0.0), m=np.array([0.1, 0.3]), w=np.array([0.5, 0.5]), n=np.full(3, 1.5), rd=np.array([0.02, 0.06, 0.14])),
                   channels=["R", "G", "B"], name="matte")
    doc = material_to_dict(mat)
    assert doc["s"] == 0.0 and "lobes" not in doc and "n" not in doc and doc["family"] == "plastic"
    back = material_from_dict(doc)
    assert back.structure.family == "plastic" and back.structure.diffuse == "spectrum"
    geom = ctfit.geometry_from_angles_deg(np.array([10.0, 40.0]), np.zeros(2), np.array([20.0, 60.0]), np.array([180.0, 90.0]))
    np.testing.assert_allclose(ctfit.brdf(back.structure, back.params, geom), ctfit.brdf(mat.structure, mat.params, geom), rtol=1e-12)


LIST_ERRORS = [
    ("F0", [0.5, True], r"key 'F0\[1\]': must be a number, got True"),
    ("F0", [0.5, float("nan")], r"key 'F0\[1\]': nan is outside \[0, 1\]"),
    ("F0", [0.5, 1.5], r"key 'F0\[1\]': 1\.5 is outside \[0, 1\]"),
    ("F0", [0.5, None], r"key 'F0\[1\]': must be a number, got None"),
    ("F0", [0.5, "0.2"], r"key 'F0\[1\]': must be a number, got '0\.2'"),
    ("F0", [10**400, 0.5], r"key 'F0\[0\]': inf is outside \[0, 1\]"),
    ("wavelength_nm", [0, 500], r"key 'wavelength_nm\[0\]': 0\.0 is outside \(0, inf\]"),
    ("wavelength_nm", [450, float("inf")], r"key 'wavelength_nm\[1\]': inf is outside \(0, inf\]"),
    ("wavelength_nm", [450, 450.0], r"key 'wavelength_nm': must be strictly increasing"),
]


@pytest.mark.parametrize("key, values, message", LIST_ERRORS)
def test_a_bad_number_in_a_list_is_named_by_its_index(key, values, message):
    """A list of plain numbers in range is checked at once; any other list is looked through
    number by number, and the first bad one is named as ever."""
    doc = {"name": "x", "s": 1, "lobes": [{"m": 0.2}], "wavelength_nm": [450, 550], "F0": [0.5, 0.6]} | {key: values}
    with pytest.raises(MaterialError, match=message):
        material_from_dict(doc)


def test_lists_of_ints_floats_and_negative_zero_read_as_numbers():
    m = material_from_dict({"name": "x", "s": 1, "lobes": [{"m": 0.2}], "wavelength_nm": [450, 550.5], "F0": [0, -0.0]})
    np.testing.assert_array_equal(m.wavelength_nm, [450.0, 550.5])
    assert m.wavelength_nm.dtype == float and m.params.f0.tolist() == [0.0, 0.0]


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.floats(allow_nan=True, allow_infinity=True, width=64), max_size=20), st.text(max_size=10))
def test_material_json_reads_back_to_the_same_document(values, name):
    """msgspec writes each float with the digits that read back to it; a number that is not
    finite is null; NumPy scalars are numbers; the text is indented by 2 and ends with a newline."""
    from ctfit._io import material_json

    doc = {"name": name, "values": values, "np": np.float64(0.25), "count": np.int64(3), "nested": {"empty": [], "none": None}}
    text = material_json(doc)
    assert text.endswith("}\n") and text.startswith('{\n  "name": ')
    back = json.loads(text)
    assert back["values"] == [v if math.isfinite(v) else None for v in values]
    assert (back["np"], back["count"], back["nested"], back["name"]) == (0.25, 3, {"empty": [], "none": None}, name)


@pytest.mark.parametrize("value", ["5", '[["m"]]', '"f0"', "{m = 1}", '["m", 2]'])
def test_fixed_must_be_a_list_of_names(tmp_path, value):
    """A malformed ``fixed`` key is refused naming the file and the key (it raised a TypeError, or
    a string was split into characters, or a table was taken)."""
    path = write(tmp_path, edit("", f"fixed = {value}\n"))
    with pytest.raises(MaterialError, match=r"m\.toml.*key 'fixed': must be a list of parameter names"):
        load_material(path)
    assert load_material(write(tmp_path, edit("", "fixed = [\"m\"]\n"))).meta["fixed"] == ["m"]


def test_a_key_given_twice_in_a_json_material_is_refused(tmp_path):
    """JSON leaves which of two equal keys counts to the reader (Python keeps the last; TOML
    refuses): ctfit refuses, naming the file, the place of the repeat and the key."""
    path = tmp_path / "dup.json"
    path.write_text('{"s": 1,\n "d": 0,\n "s": 0.5, "lobes": [{"m": 0.2}], "wavelength_nm": [400], "F0": 0.5}')
    with pytest.raises(ValueError, match=r"dup\.json:3:2: key 's' given twice in one object"):
        ctfit.load_material(path)
    nested = tmp_path / "nested.json"
    nested.write_text('{"s": 1, "lobes": [{"m": 0.2, "m": 0.3}], "wavelength_nm": [400], "F0": 0.5}')
    with pytest.raises(ValueError, match=r"nested\.json:1:31: key 'm' given twice"):
        ctfit.load_material(nested)
    lobes = tmp_path / "lobes.json"  # "m" in every lobe: which two share an object is not told, so no place is guessed
    lobes.write_text('{"s": 1, "lobes": [{"m": 0.2, "weight": 0.5}, {"m": 0.3, "m": 0.4, "weight": 0.5}], "wavelength_nm": [400], "F0": 0.5}')
    with pytest.raises(ValueError, match=r"lobes\.json: key 'm' given twice"):
        ctfit.load_material(lobes)


@pytest.mark.parametrize("text, where, key", [('name = "t"\ns = 1\nname = "x"\n', "3:11", "name"), ('name = "t"\n[a]\nx = 1\n[a]\n', "4:3", "a")])
def test_a_key_given_twice_in_a_toml_material_is_named(tmp_path, text, where, key):
    """TOML's own error ("Cannot overwrite a value") names no key; the message now does, as JSON's (docs/formats.md)."""
    path = tmp_path / "dup.toml"
    path.write_text(text)
    with pytest.raises(MaterialError, match=rf"dup\.toml:{where}: TOML syntax error: .*\(key '{key}' given twice\)"):
        load_material(path)


def test_saving_refuses_what_would_change_the_material():
    """Weights that do not sum to 1 were renormalised on saving (a different BRDF, said nowhere);
    values of m for another number of lobes than the structure's were written as that many lobes.
    Both are refused; float32 rounding of the weights' sum is still renormalised."""
    st = ctfit.Structure(lobes=2)
    made = lambda w, m=(0.1, 0.3): ctfit.Material(st, ctfit.Params(m=np.array(m), w=np.array(w), f0=np.array([0.5])), wavelength_nm=np.array([550.0]))
    with pytest.raises(ctfit.MaterialError, match=r"lobe weights \[0.5, 0.3\] sum to 0.8, not 1"):
        ctfit.material_to_dict(made([0.5, 0.3]))
    with pytest.raises(ctfit.MaterialError, match="m has 1 values; its structure has 2 lobes"):
        ctfit.material_to_dict(made([1.0], m=(0.2,)))
    w32 = np.array([0.7, 0.3], dtype=np.float32).astype(float)  # sums to 1 within float32's rounding
    assert math.fsum(ctfit.material_to_dict(made(w32))["lobes"][i]["weight"] for i in range(2)) == pytest.approx(1, abs=1e-12)


def test_numpy_numbers_in_a_document_and_a_numpy_lobe_count_are_numbers():
    """A dict made in a notebook holds NumPy scalars (np.float32, np.int64): they were refused as
    "must be a number"; ``Structure(lobes=np.int64(2))`` was refused as not an integer. Both are
    the numbers they hold; a bool is still no lobe count."""
    made = material_from_dict({"s": 1, "lobes": [{"m": np.float32(0.25)}], "wavelength_nm": [np.int64(400), np.int64(500)], "F0": np.float64(0.5)})
    assert made.params.m.tolist() == [0.25] and made.wavelength_nm.tolist() == [400.0, 500.0]
    st = Structure(lobes=np.int64(2))
    assert st == Structure(lobes=2) and hash(st) == hash(Structure(lobes=2)) and type(st.lobes) is int
    with pytest.raises(ValueError, match="lobes must be an integer"):
        Structure(lobes=True)
