"""Fit options: solvers, float32, fixed parameters from a material file, model selection, plots."""

import json

import jax.numpy as jnp
import numpy as np
import pytest
from typer.testing import CliRunner

import ctfit
from ctfit.cli import app

WL = np.array([450.0, 650.0])


def one_lobe(m=0.25, f0=(0.6, 0.9), n_pairs=300, seed=0, noise=0.01):
    mat = ctfit.Material(ctfit.Structure(lobes=1), ctfit.Params(m=np.array([m]), w=np.array([1.0]), f0=np.array(f0)), wavelength_nm=WL, name="truth")
    return mat, ctfit.simulate(mat, n_pairs, noise=noise, seed=seed)


@pytest.mark.parametrize("solver", ["gauss-newton", "dogleg", "bfgs"])
def test_other_solvers_recover_one_lobe(solver):
    _, data = one_lobe()
    res = ctfit.fit(data, ctfit.Structure(lobes=1), solver=solver, starts=1)
    assert res.stats["solver"] == solver
    np.testing.assert_allclose(res.material.params.m, [0.25], rtol=0.01)
    np.testing.assert_allclose(res.material.params.f0, [0.6, 0.9], atol=0.005)


def test_float32_fit_recovers_and_reports_its_dtype():
    _, data = one_lobe()
    res = ctfit.fit(data, ctfit.Structure(lobes=1), dtype=jnp.float32, starts=1)
    assert res.stats["dtype"] == "float32"
    assert np.all(np.isfinite(res.material.params.f0))
    np.testing.assert_allclose(res.material.params.m, [0.25], rtol=0.01)


def test_unknown_solver_and_loss_are_rejected():
    _, data = one_lobe(n_pairs=20)
    with pytest.raises(ValueError, match="solver"):
        ctfit.fit(data, ctfit.Structure(lobes=1), solver="newton")
    with pytest.raises(ValueError, match="loss"):
        ctfit.fit(data, ctfit.Structure(lobes=1), loss="huber")


@pytest.mark.parametrize("dtype", [jnp.float16, jnp.bfloat16, jnp.int32])
def test_a_fit_in_another_dtype_than_float32_or_float64_is_refused(dtype):
    """float16 was refused with data "in [3.9e+10, 0.026] sr⁻¹" (an empty range), int32 with
    NumPy's "data type not inexact": the fit is made in float32 or float64, and says so."""
    _, data = one_lobe(n_pairs=20)
    with pytest.raises(ValueError, match=rf"dtype must be float32 or float64, got {np.dtype(dtype).name}$"):
        ctfit.fit(data, ctfit.Structure(lobes=1), dtype=dtype)


def test_bic_keeps_the_structure_the_data_needs():
    st2 = ctfit.Structure(lobes=2)
    mat = ctfit.Material(st2, ctfit.Params(m=np.array([0.08, 0.4]), w=np.array([0.5, 0.5]), f0=np.array([0.6, 0.9])), wavelength_nm=WL)
    two = ctfit.simulate(mat, 600, noise=0.01, seed=1)
    _, one = one_lobe(n_pairs=600, seed=1)
    cands = [ctfit.Structure(lobes=1), ctfit.Structure(lobes=2)]
    best_two, table_two = ctfit.select_structure(two, cands, starts=2)
    best_one, table_one = ctfit.select_structure(one, cands, starts=2)
    assert best_two.material.structure.lobes == 2
    assert best_one.material.structure.lobes == 1
    assert len(table_two) == 2 and all(np.isfinite(r.stats["bic"]) for _, r in table_two)


def test_material_file_fixes_parameters_and_gives_starts(tmp_path):
    _, data = one_lobe(m=0.25)
    csv = tmp_path / "d.csv"
    ctfit.write_csv(data, csv)
    toml = tmp_path / "start.toml"
    toml.write_text(
        'name = "start"\ns = 1.0\nd = 0.0\nlobes = [{ m = 0.3, weight = 1.0 }]\n'
        'wavelength_nm = [450.0, 650.0]\nF0 = [0.6, 0.9]\nfixed = ["f0"]\n'
    )
    out = tmp_path / "fit.json"
    r = CliRunner().invoke(app, ["fit", str(csv), "--material", str(toml), "-o", str(out)])
    assert r.exit_code == 0, r.output
    doc = json.loads(out.read_text())
    assert doc["F0"] == [0.6, 0.9]  # fixed: exactly the file's values
    assert abs(doc["lobes"][0]["m"] - 0.25) < 0.0025  # free: fitted from the file's start
    assert doc["fit"]["n_params"] == 1


def _fit_fixing(tmp_path, fixed: str):
    """``ctfit fit`` of a one-lobe file with a material file whose ``fixed`` is ``fixed`` (TOML):
    the data, its path and the command's result."""
    _, data = one_lobe(n_pairs=20)
    csv = tmp_path / "d.csv"
    ctfit.write_csv(data, csv)
    toml = tmp_path / "start.toml"
    toml.write_text(f's = 1.0\nd = 0.0\nlobes = [{{ m = 0.3, weight = 1.0 }}]\nwavelength_nm = [450.0, 650.0]\nF0 = [0.6, 0.9]\nfixed = {fixed}\n')
    return data, csv, CliRunner().invoke(app, ["fit", str(csv), "--material", str(toml)])


def test_fixing_an_unknown_parameter_is_an_error(tmp_path):
    r = _fit_fixing(tmp_path, '["k"]')[2]
    assert r.exit_code == 2 and "fixed" in r.output


def test_fixing_every_parameter_leaves_nothing_to_fit(tmp_path):
    """Every parameter fixed: one error line naming the file (it was a StopIteration traceback),
    from the command and from ``ctfit.fit``."""
    data, csv, r = _fit_fixing(tmp_path, '["m", "f0"]')
    assert r.exit_code == 2 and r.output.strip() == (f"error: {csv}: nothing to fit: every parameter of the structure is fixed (fixed = ['m', 'f0']); "
                                                     "ctfit eval evaluates the material as it is")
    with pytest.raises(ValueError, match="nothing to fit"):
        ctfit.fit(data, ctfit.Structure(lobes=1), fixed=("m", "f0"))


def test_folder_of_files_and_plots(tmp_path):
    folder = tmp_path / "data"
    folder.mkdir()
    for seed in (1, 2):
        _, data = one_lobe(n_pairs=120, seed=seed)
        ctfit.write_csv(data, folder / f"s{seed}.csv")
    out, plots = tmp_path / "fits", tmp_path / "plots"
    r = CliRunner().invoke(app, ["fit", str(folder), "--no-diffuse", "--lobes", "1", "-o", str(out), "--plot", str(plots)])
    assert r.exit_code == 0, r.output
    for seed in (1, 2):
        doc = json.loads((out / f"s{seed}.fit.json").read_text())
        assert doc["fit"]["converged"]
        png = (plots / f"s{seed}.fit.png").read_bytes()
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000


def test_starts_and_fixed_names_that_do_not_fit_the_structure_are_refused():
    """``start`` of two lobes for a one-lobe structure gave a result of two lobes reported as
    converged; a start of other bands failed inside JAX; ``fixed=("F0",)`` (the files' name) or a
    misspelt name was ignored, the parameter fitted. Each is now an error naming the argument;
    the files' names are accepted."""
    truth, data = one_lobe()
    st = truth.structure
    with pytest.raises(ValueError, match=r"start\.m has 2 values; this fit takes one per lobe: 1"):
        ctfit.fit(data, st, start=ctfit.Params(m=np.array([0.3, 0.1]), w=np.array([0.5, 0.5])))
    with pytest.raises(ValueError, match=r"start\.f0 has 3 values; this fit takes one per band \(2\) or one for all"):
        ctfit.fit(data, st, start=ctfit.Params(f0=np.full(3, 0.5)))
    with pytest.raises(TypeError, match="start must be a ctfit.Params"):
        ctfit.fit(data, st, start=truth)
    with pytest.raises(ValueError, match=r"fixed names \['roughness'\]: this structure's parameters are \['m', 'F0'\]"):
        ctfit.fit(data, st, fixed=("roughness",))
    with pytest.raises(TypeError, match="not the string 'F0'"):
        ctfit.fit(data, st, fixed="F0")
    held = ctfit.fit(data, st, fixed=("F0",), start=ctfit.Params(f0=np.array([0.5, 0.5])))
    assert held.material.params.f0.tolist() == [0.5, 0.5] and held.stats["n_params"] == 1


@pytest.mark.parametrize(("start", "fixed", "message"), [
    (ctfit.Params(f0=np.array([2.0, 0.5])), ("F0",), r"start\.F0\[0\] = 2\.0 is outside \[0, 1\]"),
    (ctfit.Params(m=np.array([-0.2])), ("m",), r"start\.m\[0\] = -0\.2 is outside \(0, inf\)"),
    (ctfit.Params(m=np.array([np.nan])), (), r"start\.m\[0\] = nan is not a finite number"),
])
def test_starts_and_fixed_values_outside_their_domain_are_refused(start, fixed, message):
    """A fixed F0 = 2 was fitted and reported as converged (its n 1.8e16), a fixed m = −0.2
    too, and a NaN start ended in NumPy's 'Eigenvalues did not converge': each is now a
    ``ValueError`` naming the value, before any work."""
    truth, data = one_lobe(n_pairs=40)
    with pytest.raises(ValueError, match=message):
        ctfit.fit(data, truth.structure, start=start, fixed=fixed, starts=0 if not fixed else 3)
