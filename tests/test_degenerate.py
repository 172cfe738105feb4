"""Degenerate input is refused, repeated measurements all count, single-band data stays honest.

Each test names the defect it guards against (issue 10): a duplicate (pair, band) row that
overwrote another, data the fit's dtype cannot hold reported as converged, a fit JSON that could
not be read back, a semicolon- or tab-separated file, φ in radians beside θ in degrees, and a
band of unknown wavelength shown as 550 nm or turned into a colour.
"""

import json
import math
import subprocess
import sys

import hypothesis.strategies as st
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from typer.testing import CliRunner

import ctfit
import ctfit._fitting.least_squares as _fit
from ctfit import (
    DataError,
    DataWarning,
    Material,
    MaterialError,
    Measurement,
    Params,
    Structure,
    colour_report,
    fit_result_to_dict,
    format_fit_table,
    load_material,
    material_from_dict,
    material_to_dict,
    render_compare,
    render_materials,
    save_material_json,
)
from ctfit._cli.messages import cli_message
from ctfit._fitting.validate import check_fittable, n_free_parameters, nonfinite_reason, representable_range
from ctfit._sampling.draw_colours import draw_colours
from ctfit.cli import app

runner = CliRunner()
WL = np.array([450.0, 650.0])
TRUTH = Material(Structure(lobes=1), Params(m=np.array([0.25]), w=np.array([1.0]), f0=np.array([0.55, 0.85])), wavelength_nm=WL, name="truth")


def cli(*args):
    return runner.invoke(app, [str(a) for a in args])


def error_lines(result):
    return [line for line in result.output.splitlines() if line.startswith("error:")]


@pytest.fixture(scope="module")
def data():
    return ctfit.simulate(TRUTH, 40, seed=3, max_theta=80)


def _rows(m: Measurement, idx) -> dict:
    return {k: np.asarray(getattr(m, k))[idx] for k in ("theta_i", "phi_i", "theta_o", "phi_o", "band", "brdf")}


def doubled(m: Measurement, spread: float) -> Measurement:
    """Every row twice, at (1 − spread) and (1 + spread) times its value (mean: the value)."""
    cat = {k: np.concatenate([v, v]) for k, v in _rows(m, slice(None)).items()}
    cat["brdf"] = np.concatenate([m.brdf * (1 - spread), m.brdf * (1 + spread)])
    return m.replace(**cat)


def params_of(res):
    p = res.material.params
    return np.concatenate([np.ravel(p.m), np.ravel(p.f0)])


# --- repeated measurements -----------------------------------------------------------------------


def test_repeats_detects_duplicate_cells(data):
    assert not data.repeats and data.grid() is not None
    twice = doubled(data, 0.1)
    assert twice.repeats and twice.grid() is None


def test_every_repeated_row_is_a_sample_and_row_order_does_not_matter(data):
    twice = doubled(data, 0.1)
    res = ctfit.fit(twice, Structure(lobes=1))
    assert res.stats["n_samples"] == len(twice) == 2 * len(data)  # was 80: one sample per (pair, band) cell
    n, p = res.stats["n_samples"], res.stats["n_params"]
    assert res.stats["bic"] == pytest.approx(n * math.log(2 * res.stats["cost"] / n) + p * math.log(n), rel=1e-12)
    perm = np.random.default_rng(0).permutation(len(twice))
    shuffled = twice.replace(**_rows(twice, perm))
    res2 = ctfit.fit(shuffled, Structure(lobes=1))  # the last duplicate used to win: another fit
    assert "samples: 160" in format_fit_table(res2)
    np.testing.assert_allclose(params_of(res2), params_of(res), rtol=1e-6)


def test_duplicates_fit_as_their_mean(data):
    # absolute loss: Σ (v − a)² + (v − b)² = 2 (v − (a + b)/2)² + const, the same minimum as the mean
    twice = ctfit.fit(doubled(data, 0.2), Structure(lobes=1), loss="absolute")
    mean = ctfit.fit(data, Structure(lobes=1), loss="absolute")
    assert twice.stats["converged"] and mean.stats["converged"]
    np.testing.assert_allclose(params_of(twice), params_of(mean), rtol=1e-6)


# --- refused before the fit --------------------------------------------------------------------------


def tiny_measurement(n=3, bands=3, brdf=0.5):
    return Measurement(
        theta_i=np.linspace(10, 60, n), phi_i=np.zeros(n), theta_o=np.linspace(20, 70, n), phi_o=np.full(n, 180.0),
        band=np.arange(n) % bands, wavelength_nm=np.linspace(450, 650, bands), brdf=np.full(n, brdf), source="few.csv",
    )  # fmt: skip


def test_fewer_samples_than_free_parameters():
    # The library speaks of its own arguments; the command line shows its options.
    with pytest.raises(ValueError, match=r"few\.csv: 3 samples, 5 free parameters \(1 lobe, diffuse\): measure more or fit fewer \(structure=: fewer lobes, "
                                         r"no diffuse part\)") as e:
        ctfit.fit(tiny_measurement(), Structure(lobes=1, diffuse="F0/pi"))
    assert cli_message(str(e.value)).endswith("measure more or fit fewer (--lobes, --no-diffuse)")
    assert n_free_parameters(Structure(lobes=3, fresnel="conductor", diffuse="spectrum"), 4) == 1 + 3 + 2 + 4 + 4 + 4
    assert n_free_parameters(Structure(lobes=2), 3, fixed=("m",)) == 1 + 3


def test_select_structure_leaves_out_candidates_with_too_many_parameters():
    m = tiny_measurement(4, 1)
    best, table = ctfit.select_structure(m, [Structure(lobes=1), Structure(lobes=3, diffuse="F0/pi")])
    assert [structure for structure, _ in table] == [Structure(lobes=1)] and best is table[0][1]
    with pytest.raises(ValueError, match="4 samples, 7 free parameters"):
        ctfit.select_structure(m, [Structure(lobes=3, diffuse="F0/pi")])


def write_rows(path, values, bands=(550.0,), header="theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf"):
    rows = [f"{10 + 5 * (i % 12)},0,{15 + 5 * (i % 11)},180,{bands[i % len(bands)]},{v!r}" for i, v in enumerate(values)]
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    return path


def test_cli_fit_of_too_few_samples_exits_2(tmp_path):
    r = cli("fit", write_rows(tmp_path / "few.csv", [0.5, 0.4, 0.3], bands=(450.0, 550.0, 650.0)))
    assert r.exit_code == 2
    assert len(error_lines(r)) == 1 and "3 samples, 4 free parameters (1 lobe)" in error_lines(r)[0]  # the smallest candidate's


@pytest.mark.parametrize(
    "value, pattern, where",
    [
        (1e300, r"row 1 of the data: brdf = 1e\+300 is too large: a fit in float64 takes data whose largest brdf is in \[7\.5e-142, 1\.3e\+150\]",
         "d.csv:2: column 'brdf' (6): 1e+300 is too large: "),
        (1e-300, r"row 1 of the data: brdf = 1e-300, the largest brdf, is too small: a fit in float64 takes data whose largest brdf is in \[7\.5e-142",
         "d.csv:2: column 'brdf' (6): 1e-300, the largest brdf, is too small: "),
        (0.0, "every brdf is 0: there is nothing to fit", "d.csv: every brdf is 0"),
    ],
)
def test_out_of_range_data_is_refused(data, tmp_path, value, pattern, where):
    # brdf = 1e300 was "converged: True, rmse: inf"; 1e-300 wrote a JSON that could not be read back
    with pytest.raises(ValueError, match=pattern):
        ctfit.fit(data.replace(brdf=np.full(len(data), value)), Structure(lobes=1))
    out = tmp_path / "fit.json"
    r = cli("fit", write_rows(tmp_path / "d.csv", [value] * 20), "-o", out)
    assert r.exit_code == 2 and len(error_lines(r)) == 1 and not out.exists()
    assert where in error_lines(r)[0], error_lines(r)  # a file's value by its line and column, as the reader names one ("data row 1" before)


def test_a_value_a_fit_refuses_is_named_by_its_line_and_column_in_the_file(tmp_path):
    """The checks of the data's scale named "data row N" (the Nth sample), not the file's line:
    comment lines and the header came before it, and the columns may come in any order."""
    rows = [f"0.5,{10 + 5 * (i % 12)},0,{15 + 5 * (i % 11)},180,550,{('1e-09', '2e-09', '3e-09')[i % 3]}" for i in range(20)]
    rows[13] = rows[13].rsplit(",", 1)[0] + ",1e-300"
    path = tmp_path / "s.csv"
    path.write_text("# sample: x\n#\n# note\nsigma,theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n" + "\n".join(rows) + "\n\n\n")
    data = ctfit.read_csv(path)
    assert data.file_place(0, "brdf") == (5, 7) and data.file_place(13, "sigma") == (18, 1) and data.file_place(20, "brdf") is None
    rows = [r.replace("0.5,", "1e-300,", 1) if i == 7 else r for i, r in enumerate(rows)]
    path.write_text("# sample: x\n#\n# note\nsigma,theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n" + "\n".join(rows) + "\n")
    with pytest.raises(DataError) as caught:
        check_fittable(ctfit.read_csv(path), Structure(lobes=1), loss="sigma")
    e = caught.value
    assert (e.path, e.line, e.column, e.index) == (str(path), 12, "sigma", 1), str(e)
    assert str(e).startswith(f"{path}:12: column 'sigma' (1): 1e-300 is too small for brdf values up to 3e-09: (brdf − model)/sigma overflows float64")
    with pytest.raises(DataError, match=r"^s\.csv:7: column 'brdf' \(7\): 3e-09, the largest brdf, is too small: a fit in float32"):
        check_fittable(ctfit.read_csv(path).replace(source="s.csv"), Structure(lobes=1), dtype=jnp.float32)  # a name as shown: the lines stay
    changed = ctfit.read_csv(path)
    changed = changed.replace(brdf=changed.brdf * 1e-300)  # values of its own: no line of the file holds them
    assert changed.file_place(1, "brdf") is None
    with pytest.raises(ValueError, match=r"s\.csv: row 3 of the data: brdf = 3e-309, the largest brdf, is too small") as caught:
        check_fittable(changed, Structure(lobes=1))
    assert not isinstance(caught.value, DataError)


def test_the_data_chosen_structure_names_the_line_of_a_large_file_not_of_its_screening_sample(tmp_path):
    """Above 4,096 samples the candidates are fitted to a sample of the direction pairs, and the
    first candidate's checks named the value's row in that sample ("data row 3397" for line 5003)."""
    rows = [f"{(7 * i) % 800 / 10},0,{(13 * i) % 800 / 10},{(29 * i) % 3600 / 10},550,0.3" for i in range(6000)]
    rows[5000] = rows[5000].rsplit(",", 1)[0] + ",1e200"
    path = write_rows(tmp_path / "large.csv", [])
    path.write_text("# c\ntheta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n" + "\n".join(rows) + "\n")
    with pytest.raises(DataError, match=r"large\.csv:5003: column 'brdf' \(6\): 1e\+200 is too large"):
        ctfit.fit(ctfit.read_csv(path))
    r = cli("fit", path)
    assert r.exit_code == 2 and error_lines(r) == [f"error: {path}:5003: column 'brdf' (6): 1e+200 is too large: a fit in float64 takes data whose "
                                                   "largest brdf is in [7.5e-142, 1.3e+150] sr⁻¹ (squares of larger values overflow); is the unit sr⁻¹?"]


def test_representable_range_depends_on_the_dtype(data):
    lo64, hi64 = representable_range(jnp.float64)
    lo32, hi32 = representable_range(jnp.float32)
    assert lo64 < lo32 < 1e-6 and 1e6 < hi32 < hi64
    small = data.replace(brdf=data.brdf * 1e-12)
    check_fittable(small, Structure(lobes=1), dtype=jnp.float64)
    with pytest.raises(ValueError, match=r"a fit in float32 takes .* \(or fit in float64\)"):
        check_fittable(small, Structure(lobes=1), dtype=jnp.float32)
    with pytest.raises(ValueError, match=r"<simulated>: row 2 of the data: sigma = 1e-200 is too small"):
        check_fittable(data.replace(sigma=np.r_[1.0, 1e-200, np.ones(len(data) - 2)]), Structure(lobes=1), loss="sigma")


def test_non_finite_values_in_memory_are_refused(data):
    brdf = data.brdf.copy()
    brdf[[1, 5]] = [np.nan, np.inf]
    with pytest.raises(ValueError, match=r"brdf\[1\]: NaN is not allowed \(values must be finite numbers\)"):  # the Measurement refuses them
        ctfit.fit(data.replace(brdf=brdf), Structure(lobes=1))


# --- not finite after the solve ----------------------------------------------------------------------


def test_nonfinite_reason_names_what_is_not_finite():
    assert nonfinite_reason(1.0, 0.1, 0, 3, jnp.float64) is None
    text = nonfinite_reason(math.inf, math.nan, 1, 2, jnp.float32)
    assert text.startswith("not converged: the cost is inf, 1 of 2 model values are not finite, the rmse is nan in float32")


def test_a_fit_that_is_not_finite_has_not_converged_and_says_why(data, monkeypatch):
    # 1e300 sr⁻¹ let through to the solver: the absolute loss's squares overflow.
    monkeypatch.setattr(_fit, "check_fittable", lambda *a, **k: None)
    res = ctfit.fit(data.replace(brdf=np.full(len(data), 1e300)), Structure(lobes=1), loss="absolute")
    assert not res.stats["converged"]
    assert res.warnings[0].startswith("not converged: the cost is inf")
    assert "warning: not converged: the cost is inf" in format_fit_table(res)


# --- a fit JSON that ctfit writes reads back ------------------------------------------------------


def metal(**params):
    base = dict(m=np.array([0.2]), w=np.array([1.0]), f0=np.array([0.5, 0.9]))
    return Material(Structure(lobes=len(np.atleast_1d(params.get("m", base["m"])))), Params(**{**base, **params}), wavelength_nm=WL, name="x")


def test_a_material_with_parameters_that_are_not_finite_is_not_saved(tmp_path):
    # was written with "F0": [null, null], which load_material refused
    with pytest.raises(MaterialError, match=r"parameter F0 is not finite \(\[nan, nan\]\): the fit failed"):
        save_material_json(metal(f0=np.array([np.nan, np.nan])), tmp_path / "r.json")
    assert not (tmp_path / "r.json").exists()


def test_float32_weights_read_back(tmp_path):
    w = np.asarray(jnp.asarray([0.1, 0.7, 0.2], jnp.float32) / jnp.asarray(1.0000001, jnp.float32))
    assert abs(math.fsum(map(float, w)) - 1) > 1e-9  # the format asks 1e-9: this used to be unreadable
    m = metal(m=np.array([0.1, 0.2, 0.4], np.float32), w=w)
    again = load_material(save_material_json(m, tmp_path / "r.json"))
    np.testing.assert_allclose(again.params.w, w, rtol=1e-6)
    assert math.fsum(again.params.w) == pytest.approx(1, abs=1e-12)


def test_a_conductor_on_its_bound_n_0_reads_back(tmp_path):
    m = Material(Structure(lobes=1, fresnel="conductor"), Params(m=np.array([0.2]), w=np.array([1.0]), n=np.array([0.0, 0.3]), k=np.array([2.0, 3.0])),
                 wavelength_nm=WL)
    np.testing.assert_array_equal(load_material(save_material_json(m, tmp_path / "r.json")).params.n, [0.0, 0.3])


def test_what_would_not_read_back_is_refused_on_save():
    with pytest.raises(MaterialError, match=r"key 'Name': unknown key; did you mean 'name'\? \(while saving"):
        material_to_dict(metal(), {"Name": "typo"})


def _dtype_floats(dtype, lo, hi):
    return st.floats(lo, hi, allow_subnormal=False).map(lambda x: float(np.asarray(x, dtype)))


@st.composite
def fitted_materials(draw):
    """Materials a fit can produce: parameters anywhere in their domain (bounds included), in
    float32 or float64, single-band data of unknown wavelength, fit statistics that are not finite."""
    dtype = draw(st.sampled_from([np.float32, np.float64]))
    lobes = draw(st.integers(0, 3))
    diffuse = draw(st.sampled_from(([None] if lobes else []) + ["F0/pi", "spectrum", "constant"]))
    structure = Structure(lobes=lobes, fresnel=draw(st.sampled_from(["f0", "n", "conductor"])) if lobes or diffuse == "F0/pi" else "f0", diffuse=diffuse)
    kind = draw(st.sampled_from(["spectral", "rgb", "unknown"]))
    nb = {"spectral": draw(st.integers(1, 4)), "rgb": 3, "unknown": 1}[kind]
    big = 1e30 if dtype == np.float32 else 1e300

    def arr(lo, hi, shape=(nb,)):
        return np.asarray(draw(st.lists(_dtype_floats(dtype, lo, hi), min_size=int(np.prod(shape)), max_size=int(np.prod(shape)))), dtype).reshape(shape)

    fields = {}
    if lobes:
        fields["m"] = np.sort(arr(1e-5, 4.0, (lobes,)))
        a = np.concatenate([[1.0], arr(0.0, 1e4, (lobes - 1,))]).astype(dtype)
        fields["w"] = (a / a.sum()).astype(dtype)
    if structure.has_s:
        fields["s"] = np.asarray(draw(st.sampled_from([0.0, 1.0]) | _dtype_floats(dtype, 0.0, 1.0)), dtype)
    if structure.needs_fresnel_params:
        if structure.fresnel == "f0":
            fields["f0"] = arr(0.0, 1.0)
        else:
            fields["n"] = arr(1.0 if structure.fresnel == "n" else 0.0, big)
        if structure.fresnel == "conductor":
            fields["k"] = arr(0.0, big)
    if diffuse == "spectrum":
        fields["rd"] = arr(0.0, big)
    elif diffuse == "constant":
        fields["rd"] = np.asarray(arr(0.0, big, (1,))[0])
    bands = {"rgb": dict(channels=("R", "G", "B")), "unknown": dict(wavelength_nm=np.array([550.0]), band_unknown=True)}.get(kind)
    bands = bands or dict(wavelength_nm=np.cumsum(arr(1.0, 100.0).astype(float)) + 300)
    fit = {"cost": draw(st.sampled_from([math.inf, math.nan, 1.5])), "converged": False}
    return Material(structure, Params(**fields), name="fit", meta={"fit": fit}, **bands)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(material=fitted_materials())
def test_what_save_writes_load_reads(tmp_path, material):
    path = save_material_json(material, tmp_path / "r.json")
    text = path.read_text()
    assert "NaN" not in text and "Infinity" not in text
    again = load_material(path)
    assert again.band_unknown == material.band_unknown and again.meta["fit"]["cost"] in (None, 1.5)
    assert material_to_dict(again) == json.loads(text)  # saving what was read writes the same document
    s = None if material.params.s is None else float(material.params.s)
    if s not in (0.0, 1.0):  # a part with no weight is left out (the BRDF is the same)
        assert again.structure == material.structure
        for name in ("s", "m", "w", "f0", "n", "k", "rd"):
            x, y = getattr(material.params, name), getattr(again.params, name)
            assert (x is None) == (y is None), name
            if x is not None:  # exact but for float32 weights, renormalised to sum to 1
                np.testing.assert_allclose(np.asarray(y, float), np.asarray(x, float), rtol=3e-7 if name == "w" else 0, err_msg=name)


# --- the separator ------------------------------------------------------------------------------------


@pytest.mark.parametrize("sep, word", [(";", "semicolon"), ("\t", "tab")])
def test_semicolon_or_tab_separated_file_gets_a_hint(tmp_path, sep, word):
    path = tmp_path / "d.csv"
    path.write_text(sep.join(["theta_i", "phi_i", "theta_o", "phi_o", "wavelength_nm", "brdf"]) + "\n" + sep.join("10 0 10 180 550 0.5".split()) + "\n")
    with pytest.raises(DataError, match=rf"d\.csv:1: .*the file seems to be {word}-separated; ctfit reads comma-separated CSV "
                                        r"\(docs/measurement-formats\.md\)"):
        ctfit.read_measurement(path)
    r = cli("fit", path)
    assert r.exit_code == 2 and len(error_lines(r)) == 1 and f"{word}-separated" in error_lines(r)[0]


# --- φ in radians -------------------------------------------------------------------------------------


def phi_file(path, phi_i, phi_o, meta=""):
    rows = [f"{10 + 7 * i},{a!r},{20 + 6 * i},{b!r},550,0.5" for i, (a, b) in enumerate(zip(phi_i, phi_o))]
    path.write_text(meta + "theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n" + "\n".join(rows) + "\n")
    return path


def test_phi_in_radians_beside_theta_in_degrees_is_refused(tmp_path):
    phi_o = [math.pi, 0.5, -1.2, 2.0, 3.0, math.pi / 2]
    with pytest.raises(DataError, match=r"d\.csv:2: column 'phi_o' \(4\): 3\.14159\d+: every phi_i and phi_o is within ±2π .*\(degrees = radians × 180/π ≈ "
                                        r"radians × 57\.2958"):
        ctfit.read_measurement(phi_file(tmp_path / "d.csv", [0] * 6, phi_o))
    confirmed = ctfit.read_measurement(phi_file(tmp_path / "d.csv", [0] * 6, phi_o, "# angle_unit: degrees\n"))
    assert confirmed.phi_o[0] == pytest.approx(math.pi)


@pytest.mark.parametrize(
    "phi_i, phi_o",
    [
        ([0] * 6, [180, 180, 0, 180, 180, 180]),  # in-plane, degrees
        ([0] * 6, [0] * 6),  # every φ 0
        ([0] * 6, [0, 1, 2, 3, 4, 5]),  # small whole degrees
        ([0] * 3, [0.5, 1.5, 2.5]),  # too few rows to tell
        ([180] * 6, [0.5, -1.5, 2.5, 3.5, -4.5, 5.5]),  # near-specular, light at φ = 180°
    ],
)
def test_phi_that_reads_as_degrees_is_accepted(tmp_path, phi_i, phi_o):
    assert len(ctfit.read_measurement(phi_file(tmp_path / "d.csv", phi_i, phi_o))) == len(phi_o)


# --- a band of unknown wavelength --------------------------------------------------------------------


@pytest.fixture(scope="module")
def alta(tmp_path_factory):
    """A single-band ALTA file (no wavelength) of TRUTH at 550 nm, and its fit (JSON)."""
    d = tmp_path_factory.mktemp("alta")
    m = ctfit.simulate(TRUTH, 60, wavelength_nm=np.array([550.0]), seed=5, max_theta=80, noise=0.02)
    dphi = np.deg2rad(m.phi_o - m.phi_i)
    to = np.deg2rad(m.theta_o)
    columns = np.stack([np.deg2rad(m.theta_i), to * np.cos(dphi), to * np.sin(dphi), m.brdf], axis=1)
    rows = [" ".join(map(repr, row)) for row in columns.tolist()]
    path = d / "one.alta"
    path.write_text("#DIM 3 1\n#PARAM_IN ISOTROPIC_TL_TV_PROJ_DPHI\n#PARAM_OUT INV_STERADIAN\n" + "\n".join(rows) + "\n")
    data = ctfit.read_measurement(path)
    res = ctfit.fit(data, Structure(lobes=1))
    out = save_material_json(res.material, d / "one.fit.json", extra=fit_result_to_dict(res, material_keys=False))
    return data, res, out


def test_alta_single_band_is_unknown(alta):
    data, _, _ = alta
    assert data.band_unknown and data.band_labels == ["unknown band"]
    assert TRUTH.band_labels == ["450 nm", "650 nm"] and not TRUTH.band_unknown
    with pytest.raises(ValueError, match="band_unknown is for single-band data"):
        data.replace(wavelength_nm=WL, band_unknown=True)


def test_fit_of_unknown_band_records_it(alta):
    _, res, path = alta
    assert res.stats["converged"] and res.material.band_unknown
    table = format_fit_table(res)
    assert "unknown band" in table and "550" not in table
    assert fit_result_to_dict(res)["band_unknown"] is True
    again = load_material(path)
    assert again.band_unknown and again.band_labels == ["unknown band"]
    assert json.loads(path.read_text())["band_unknown"] is True


@pytest.mark.parametrize(
    "doc, pattern",
    [
        ({"wavelength_nm": [500.0, 600.0], "band_unknown": True}, "key 'band_unknown': true needs exactly one wavelength_nm"),
        ({"channels": ["R", "G", "B"], "band_unknown": True}, "key 'band_unknown': true needs exactly one wavelength_nm"),
        ({"wavelength_nm": [550.0], "band_unknown": "yes"}, "key 'band_unknown': must be true or false"),
    ],
)
def test_band_unknown_key_is_checked(doc, pattern):
    with pytest.raises(MaterialError, match=pattern):
        material_from_dict({"s": 1, "lobes": [{"m": 0.2}], "F0": 0.5, **doc})


def test_no_colour_for_an_unknown_band(alta):
    _, res, path = alta
    with pytest.raises(ValueError, match="its band's wavelength is unknown .* no colour"):
        colour_report(res.material)
    with pytest.raises(ValueError, match="wavelength is unknown"):
        draw_colours(res.material, {})  # the sampler's colour summary
    r = cli("color", path)
    assert r.exit_code == 2 and len(error_lines(r)) == 1 and "no colour" in error_lines(r)[0]


def _is_grey(image):
    rgb = image.astype(int)
    return np.abs(rgb[..., 0] - rgb[..., 1]).max() <= 1 and np.abs(rgb[..., 1] - rgb[..., 2]).max() <= 1


def test_render_of_an_unknown_band_is_grey_labelled_and_warned(alta):
    data, res, _ = alta
    with pytest.warns(DataWarning, match="band's wavelength is unknown; rendered in grey"):
        image = render_materials([res.material], 32, labels=False)
    assert _is_grey(image)
    with pytest.warns(DataWarning):
        pair = render_compare(res.material, data, 32, labels=False, supersample=1)
    assert _is_grey(pair)  # both tiles, in the one band (was an error: no colour weights for one wavelength)
    with pytest.raises(ValueError, match="wavelength is unknown, so it cannot be shown beside"):
        render_compare(TRUTH, data, 32)


def test_cli_render_warns_in_one_line(alta, tmp_path):
    _, _, path = alta
    out = subprocess.run(
        [sys.executable, "-m", "ctfit.cli", "render", str(path), "-o", str(tmp_path / "x.png"), "--size", "32"],
        capture_output=True, text=True,
    )
    assert out.returncode == 0, out.stderr
    warned = [line for line in out.stderr.splitlines() if "wavelength is unknown" in line]
    assert len(warned) == 1 and warned[0].startswith("warning:")


def test_noisy_simulation_of_a_material_invisible_to_its_samples_is_refused_by_the_fit_not_by_simulate():
    """m = 10⁻⁴ under simulate's sampling (docs/stability.md): every sample is 0 or a subnormal
    number. A noisy simulation is still a valid measurement (its sigma positive, where 10⁻⁶ of a
    subnormal maximum is 0); the fit then refuses it in one line."""
    metal = ctfit.Material(Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([1e-4]), w=np.ones(1), f0=np.array([0.55, 0.7, 0.85, 0.95])),
                           wavelength_nm=np.array([400.0, 500.0, 600.0, 700.0]))
    data = ctfit.simulate(metal, n_pairs=300, noise=0.01, seed=1)
    assert np.max(data.brdf) < 1e-300 and np.all(data.sigma > 0)
    with pytest.raises(ValueError, match="every brdf is (0: there is nothing to fit|at most)"):
        ctfit.fit(data, metal.structure)
