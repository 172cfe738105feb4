"""A fit's warnings are values (``ctfit.FitWarning``): the text users read, with its kind, the
parameter and the region of the data it is about; the fit JSON keeps both. Its figures are typed
(``ctfit.FitStats``)."""

import copy
import dataclasses
import json
import pickle

import pytest

import ctfit
from ctfit._fitting.fit_warnings import WARNING_KINDS, FitWarning
from ctfit._fitting.quality import quality_warning

from conftest import ROOT


@pytest.fixture(scope="module")
def matte_plastic_fit():
    """Two lobes of a plastic on the smooth-plastic test-bed file: s ends at 0 (no lobe fits the
    mirror-like peak), so the lobes are not determined, and the residuals are systematic."""
    data = ctfit.read_measurement(ROOT / "measurements" / "testbed" / "plastic.csv")
    return ctfit.fit(data, ctfit.Structure(family="plastic", lobes=2, diffuse="spectrum"))


def test_every_warning_of_a_fit_says_what_it_is_about(matte_plastic_fit):
    res = matte_plastic_fit
    assert res.warnings and all(isinstance(w, FitWarning) and w.kind in WARNING_KINDS for w in res.warnings)
    by_kind = {w.kind: w for w in res.warnings}
    assert by_kind["on_bound"].parameter == "s" and by_kind["on_bound"].startswith("s = 0 (on its bound)")
    assert "m" in by_kind["degenerate"].parameter.split(", ")
    regions = [w.region for w in res.warnings if w.kind == "systematic_residuals"]
    assert regions and all(r and r in w for r, w in zip(regions, (w for w in res.warnings if w.kind == "systematic_residuals")))


def test_the_fit_json_keeps_the_text_and_the_details(matte_plastic_fit):
    doc = json.loads(json.dumps(ctfit.fit_result_to_dict(matte_plastic_fit)))
    texts, details = doc["fit"]["warnings"], doc["fit"]["warning_details"]
    assert texts == [str(w) for w in matte_plastic_fit.warnings]
    assert [d["text"] for d in details] == texts and {d["kind"] for d in details} <= set(WARNING_KINDS)
    assert {"kind", "parameter", "region", "text"} == set(details[0])


def test_a_warning_survives_pickling_and_copying_with_its_fields():
    w = FitWarning("systematic residuals: …", "systematic_residuals", region="max(θ_i, θ_o) in [85°, 90°]")
    for again in (pickle.loads(pickle.dumps(w)), copy.deepcopy(w), copy.copy(w)):
        assert again == w and (again.kind, again.parameter, again.region) == (w.kind, w.parameter, w.region)
    with pytest.raises(ValueError, match="kind must be one of"):
        FitWarning("?", "nonsense")


def test_the_model_does_not_represent_warning_names_the_worst_region():
    quality = {"median_relative_error": 0.45, "p90_relative_error": 0.9,
               "regions": {"peak": {"median_relative_error": 0.2}, "off_peak": {"median_relative_error": 0.5}, "grazing": {"median_relative_error": None}}}
    w = quality_warning(quality)
    assert w.kind == "not_represented" and w.region == "off the peak" and "does not represent this material" in w
    assert quality_warning({**quality, "median_relative_error": 0.05, "p90_relative_error": 0.1}) is None


def test_every_figure_a_fit_reports_is_declared_in_fit_stats_with_its_type():
    """``ctfit.FitStats`` names every key of ``FitResult.stats`` (reported, light and data-chosen
    fits) with the type its value has."""
    import typing

    import numpy as np

    from ctfit._fitting.least_squares import fit_to_tolerance

    hints = typing.get_type_hints(ctfit.FitStats)
    gold = ctfit.Material(ctfit.Structure(lobes=1, diffuse="F0/pi"),
                          ctfit.Params(s=np.asarray(0.7), m=np.array([0.2]), w=np.ones(1), f0=np.array([0.4, 0.9])),
                          wavelength_nm=np.array([450.0, 650.0]))
    data = ctfit.simulate(gold, n_pairs=300, noise=0.01, seed=1)
    fits = [ctfit.fit(data, gold.structure), fit_to_tolerance(data, gold.structure, report=False), ctfit.fit(data)]
    assert "structure_choice" in fits[2].stats and fits[1].stats["report"] is False
    for res in fits:
        for key, value in res.stats.items():
            assert key in hints, key
            kind = typing.get_origin(hints[key]) or hints[key]
            assert isinstance(value, kind) and not (kind is int and isinstance(value, bool)), (key, value, hints[key])


def test_as_many_samples_as_parameters_give_no_standard_errors_and_say_why():
    """Three noisy samples, three free parameters (s, m, F0): the fit goes through every sample, so
    nothing is left to estimate the noise from. The errors were ~1e-16 (rounding, 10¹⁴ below the
    scatter over noise seeds); now there are none, and a warning says why. A sigma column gives them."""
    import numpy as np

    gold = ctfit.Material(ctfit.Structure(diffuse="F0/pi"), ctfit.Params(s=np.array(0.8), m=np.array([0.2]), w=np.ones(1), f0=np.array([0.9])),
                          wavelength_nm=np.array([550.0]))
    data = ctfit.simulate(gold, n_pairs=3, seed=1, noise=0.05, wavelength_nm=[550.0])
    res = ctfit.fit(data.replace(sigma=None), gold.structure)
    assert res.stats["n_samples"] == res.stats["n_params"] == 3 and res.stderr is None
    warned = [w for w in res.warnings if w.kind == "no_standard_errors"]
    assert len(warned) == 1 and "3 samples for 3 free parameters leave no residual" in warned[0]
    assert {"s[0]", "m[0]", "F0[0]"} <= set(res.stats["no_stderr"])  # docs/fitting.md: every entry without one (it was [])
    with_sigma = ctfit.fit(data.replace(sigma=np.full(3, 0.01)), gold.structure, loss="sigma")
    assert with_sigma.stderr is not None and not any(w.kind == "no_standard_errors" for w in with_sigma.warnings)


def test_s_near_one_with_a_grown_diffuse_part_says_they_trade_not_that_there_is_none():
    """A metal with its own R_d(λ): s → 1 with R_d → 200 sr⁻¹ keeps a diffuse part of albedo
    0.05–0.25 (Mitsuba's blend of a Lambertian and silver); "almost no diffuse part" was false there."""
    import numpy as np

    from ctfit._fitting.fit_report import fit_warnings

    grown = ctfit.Params(s=np.array(0.99992), m=np.array([0.02]), w=np.ones(1), f0=np.full(3, 0.9), rd=np.array([1000.0, 200.0, 200.0]) / np.pi)
    texts = [str(w) for w in fit_warnings(grown, None)]
    assert any("s and R_d are not determined apart" in t and "up to 0.08" in t for t in texts), texts
    assert not any("almost no diffuse part" in t for t in texts)
    small = ctfit.Params(s=np.array(0.99992), m=np.array([0.02]), w=np.ones(1), f0=np.full(3, 0.9), rd=np.array([0.02, 0.05, 0.08]))
    assert any("almost no diffuse part" in w for w in fit_warnings(small, None))


def test_f0_near_a_bound_but_determined_away_from_it_is_not_at_a_bound():
    """F0 = 9.986·10⁻⁷ ± 9.6·10⁻¹⁰ (the truth 10⁻⁶) was warned to be "at a bound (0 or 1)"."""
    import numpy as np

    from ctfit._fitting.fit_report import fit_warnings

    params = ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([9.986e-7, 0.5]))
    assert not any("F0 at a bound" in w for w in fit_warnings(params, {"F0": np.array([9.6e-10, 1e-3])}))
    assert any("F0 at a bound" in w for w in fit_warnings(params, {"F0": np.array([np.nan, 1e-3])}))  # on its bound: no error
    assert any("F0 at a bound" in w for w in fit_warnings(dataclasses.replace(params, f0=np.array([0.0, 0.5])), None))


def test_held_parameters_have_no_standard_error():
    """A material file's ``fixed = ["m", "n"]`` printed "m = 0.3 ± 0", as if measured exactly;
    held parameters now have none (null, listed in no_stderr), and the table shows their value alone."""
    import numpy as np

    rubber = ctfit.load_material(ROOT / "configs" / "rubber.toml")
    data = ctfit.simulate(rubber, n_pairs=200, noise=0.02, seed=2)
    res = ctfit.fit(data, rubber.structure, start=rubber.params, fixed=("m", "n"))
    assert np.isnan(res.stderr["m"]).all() and np.isnan(res.stderr["n"]).all() and np.isfinite(res.stderr["s"])
    assert "m[0]" in res.stats["no_stderr"] and "n[0]" in res.stats["no_stderr"]
    table = ctfit.format_fit_table(res)
    assert "± 0 " not in table and f"m = {float(res.material.params.m[0]):.6g}   " in table
