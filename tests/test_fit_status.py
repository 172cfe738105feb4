"""How a fit ended, as one typed value (issue 24): ``FitResult.status`` (``ctfit.FitStatus``),
decided once, in the JSON and the table; ``converged`` is the same verdict."""

import itertools

import numpy as np
import pytest

import ctfit
from ctfit import FitStatus
from ctfit._fitting.status import fit_status, judge_converged

from conftest import ROOT

GOLD = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.4, 0.9])),
                      wavelength_nm=np.array([450.0, 650.0]))


@pytest.fixture(scope="module")
def data():
    return ctfit.simulate(GOLD, n_pairs=300, noise=0.01, seed=1)


def test_a_converged_fit_says_so_in_its_status_json_and_table(data):
    res = ctfit.fit(data, GOLD.structure)
    assert res.status is FitStatus.CONVERGED and res.converged and res.status.converged
    assert ctfit.fit_result_to_dict(res)["fit"]["fit_status"] == "converged"
    assert "  converged: True   steps:" in ctfit.format_fit_table(res)


def test_a_fit_stopped_at_its_step_limit_says_which_limit(data):
    res = ctfit.fit(data, GOLD.structure, max_steps=1, starts=1)
    assert res.status is FitStatus.MAX_STEPS and not res.converged and res.stats["steps"] == 1
    assert "  converged: False (max_steps)   steps: 1" in ctfit.format_fit_table(res)
    assert ctfit.fit_result_to_dict(res)["fit"]["fit_status"] == "max_steps"
    # Its error is that of an unfinished fit, not the model's: no verdict that the model cannot represent the data.
    assert res.stats["quality"]["median_relative_error"] > 0.3
    assert not any("does not represent this material" in w for w in res.warnings), res.warnings


def test_a_fit_of_a_model_that_explains_nothing_says_so(data):
    res = ctfit.fit(data, ctfit.Structure(lobes=2, diffuse="spectrum"), max_steps=2, starts=1)
    assert res.status is FitStatus.EXPLAINS_NOTHING and not res.converged
    assert any(w.startswith("no fit: the model explains almost none of the data") for w in res.warnings)


def test_the_first_failed_test_names_the_status_and_converged_agrees_for_one_fit_or_many():
    cases = list(itertools.product([True, False], [True, False], [1e-12, 0.5, np.nan], [1.0, 9.9], [5, 10]))
    want = []
    for ok, finite, gn, cost, steps in cases:
        status = fit_status(ok, finite, gn, cost, 10.0, "float64", steps=steps, max_steps=10)
        want.append(status.converged)
        if not ok:
            assert status is FitStatus.NUMERICAL_FAILURE
        elif not finite:
            assert status is FitStatus.NON_FINITE
        elif cost == 9.9:  # ≥ NO_SIGNAL of the zero model's cost
            assert status is FitStatus.EXPLAINS_NOTHING
        elif not gn <= 1e-6:
            assert status is (FitStatus.MAX_STEPS if steps == 10 else FitStatus.NOT_A_MINIMUM)
        else:
            assert status is FitStatus.CONVERGED
    ok, finite, gn, cost, _ = (np.array(c) for c in zip(*cases))
    assert judge_converged(ok, finite, gn, cost, np.full(len(cases), 10.0), "float64").tolist() == want


def test_a_result_without_a_status_has_none():
    """A texel's fit keeps only ``converged``; a fit JSON written before the status has none."""
    res = ctfit.FitResult(material=GOLD, stats={"converged": True}, stderr=None, warnings=[], loss="relative", solver="lm")
    assert res.status is None and res.converged


def test_a_solver_without_bounds_stuck_past_one_is_not_converged():
    """optimistix's BFGS knows no bounds: on this plastic it pushed R_d at 400 nm below 0, where the
    model clips it and its gradient is 0, and reported "converged" at 700× the minimum's cost. The
    point is judged where the model takes it (on the bound): converged only at a minimum."""
    olive = ctfit.load_material(ROOT / "configs" / "olive-drab.toml")
    data = ctfit.simulate(olive, n_pairs=1000, noise=0.01, seed=3, wavelength_nm=np.arange(400.0, 701.0, 50.0))
    st = ctfit.Structure(lobes=1, family="plastic", fresnel="n", diffuse="spectrum")
    best = ctfit.fit(data, st, loss="relative")
    assert best.converged
    res = ctfit.fit(data, st, loss="relative", solver="bfgs")
    assert not res.converged or res.stats["cost"] < 1.01 * best.stats["cost"], (res.status, res.stats["cost"], best.stats["cost"])
