"""A fit's report is made on the host: the light report of the data-chosen default's candidates
(active set, Gauss–Newton decrease, parameters) and the whole one (JᵀJ on the free coordinates,
the Jacobian of the reported quantities, the standard errors) equal the traced ones, including a
parameter held on its bound, in float64 and float32, and a fit on chunks compiles no report program."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ctfit
from ctfit._fitting.coordinates import from_params
from ctfit._fitting.fit_report import light_report_core, report_core, standard_errors
from ctfit._fitting.jacobian import normal_equations
from ctfit._fitting.least_squares import fit_to_tolerance, prepare_fit
from ctfit._fitting.stationarity import predicted_decrease

CASES = [
    (ctfit.Structure(lobes=2, diffuse="F0/pi"), ctfit.Params(s=np.asarray(0.8), m=np.array([0.15, 0.4]), w=np.array([0.6, 0.4]), f0=np.array([0.3, 0.6, 0.9]))),
    (ctfit.Structure(family="plastic", lobes=1, diffuse="spectrum"),  # s = 1: on its bound (the gradient is made to point out of the box below)
     ctfit.Params(s=np.asarray(1.0), m=np.array([0.2]), w=np.ones(1), n=np.full(3, 1.5), rd=np.array([0.1, 0.2, 0.05]))),
    (ctfit.Structure(lobes=1, fresnel="conductor", diffuse=None),
     ctfit.Params(m=np.array([0.25]), w=np.ones(1), n=np.array([0.3, 0.5, 1.1]), k=np.array([3.0, 2.5, 2.2]))),
    (ctfit.Structure(lobes=3, fresnel="n", diffuse="F0/pi"),  # per-band index; three lobes, one weight on its bound 0
     ctfit.Params(s=np.asarray(0.7), m=np.array([0.05, 0.2, 0.6]), w=np.array([0.5, 0.5, 0.0]), n=np.array([1.3, 2.0, 4.0]))),
    (ctfit.Structure(lobes=2, diffuse="F0/pi"),  # F0 at 0 in a band (the effective index's derivative is infinite there) and at 1
     ctfit.Params(s=np.asarray(0.5), m=np.array([0.1, 0.3]), w=np.array([0.2, 0.8]), f0=np.array([0.0, 0.5, 1.0]))),
]
TRUTH = ctfit.Params(s=np.asarray(0.3), m=np.array([0.2]), w=np.ones(1), n=np.full(3, 1.5), rd=np.array([0.1, 0.2, 0.05]))


def _at_case(case: int, dtype):
    """(problem, u, ½‖r‖², Jᵀr, JᵀJ) of case ``case``'s structure at its parameters, on simulated plastic data."""
    st, at = CASES[case]
    truth = ctfit.Material(ctfit.Structure(family="plastic", diffuse="spectrum"), TRUTH, channels=("R", "G", "B"))
    data = ctfit.simulate(truth, n_pairs=300, noise=0.01, seed=2)
    problem = prepare_fit(data, st, start=None, fixed=(), loss="relative", dtype=dtype, starts=1).problem
    u = {k: np.asarray(v, dtype) for k, v in from_params(problem.spec, at).items()}
    cost, jtr, jtj = (np.array(a) for a in jax.jit(normal_equations)(problem, u))
    return problem, u, cost, jtr, jtj


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("case", range(len(CASES)))
def test_the_host_light_report_equals_the_traced_one(case, dtype):
    problem, u, cost, jtr, jtj = _at_case(case, dtype)
    if case == 1:  # the cost falling only above s = 1: held there
        at_s = sum(np.size(u[k]) for k in sorted(u) if k < "s")
        jtr[at_s] = -abs(jtr[at_s])
    zero = np.asarray(10 * cost, dtype)
    traced = jax.device_get(jax.jit(light_report_core)(problem, u, cost, jtr, jtj, zero))
    host_problem = jax.tree.map(np.asarray, problem)
    host = light_report_core(host_problem, u, cost, jtr, jtj, zero, np)
    np.testing.assert_array_equal(host["on_bound"], traced["on_bound"])
    if case == 1:
        assert host["on_bound"].any()  # s held at 1
    assert host["gn_decrease"] == pytest.approx(float(traced["gn_decrease"]), rel=1e-9 if dtype == np.float64 else 2e-3)
    assert np.isfinite(host["gn_decrease"]) and host["gn_decrease"] > 0
    for name, value in traced["params"].items():
        if value is None:
            assert host["params"][name] is None
        else:
            assert np.asarray(host["params"][name]).dtype == dtype
            np.testing.assert_allclose(host["params"][name], value, rtol=1e-13 if dtype == np.float64 else 2e-6)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("case", range(len(CASES)))
def test_the_host_report_equals_the_traced_one(case, dtype):
    """The whole report: the Jacobian of the reported quantities (``jax.jacfwd`` traced; the chain
    rule on the host), JᵀJ on the free coordinates, and the standard errors made from them."""
    problem, u, cost, jtr, jtj = _at_case(case, dtype)
    zero = np.asarray(10 * cost, dtype)
    traced = jax.device_get(jax.jit(report_core)(problem, u, cost, jtr, jtj, zero))
    host = report_core(jax.tree.map(np.asarray, problem), u, cost, jtr, jtj, zero, np)
    np.testing.assert_array_equal(host["on_bound"], traced["on_bound"])
    np.testing.assert_array_equal(host["jtj"], traced["jtj"])
    assert set(host["jt"]) == set(traced["jt"])
    tight = dict(rtol=1e-12, atol=1e-14) if dtype == np.float64 else dict(rtol=2e-5, atol=1e-6)
    for name, value in traced["jt"].items():
        assert host["jt"][name].shape == value.shape and host["jt"][name].dtype == dtype, name
        finite = np.isfinite(value)
        np.testing.assert_array_equal(np.isfinite(host["jt"][name]), finite, err_msg=name)
        np.testing.assert_allclose(host["jt"][name][finite], value[finite], **tight, err_msg=name)
    if case == 4:
        assert not np.isfinite(host["jt"]["n"]).all()  # dn/dF0 at F0 = 0
    free = ~host["on_bound"]
    errors = [standard_errors(r["jtj"], r["jt"], 0.01, None, free) for r in (host, traced)]
    assert (errors[0] is None) == (errors[1] is None)
    for name, value in (errors[1] or {}).items():
        np.testing.assert_allclose(errors[0][name], value, rtol=1e-9 if dtype == np.float64 else 1e-3, err_msg=name)


def test_the_decrease_on_the_host_falls_back_to_the_eigenvalues_where_cholesky_fails():
    """JᵀJ made indefinite by more than μ (rounding can do it): NumPy's Cholesky raises where JAX's
    gives NaN; both then take the truncated pseudo-inverse of the eigendecomposition."""
    h = np.array([[4.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1e-3]])
    g = np.array([2.0, 1.0, 0.0])
    host = predicted_decrease(h, g, xp=np)
    assert host == pytest.approx(float(predicted_decrease(jnp.asarray(h), jnp.asarray(g))), rel=1e-12)
    assert host == pytest.approx(0.5 * (4 / 4 + 1 / 1))
    assert predicted_decrease(np.zeros((3, 3)), np.zeros(3), xp=np) == 0.0


def test_a_fit_on_chunks_makes_no_report_program(monkeypatch):
    made = []
    from ctfit._fitting import chunked_fit

    real = chunked_fit._program  # every program a fit on chunks asks for, made or kept
    monkeypatch.setattr(chunked_fit, "_program", lambda name, *a: (made.append(name), real(name, *a))[1])
    st = ctfit.Structure(family="plastic", lobes=1, diffuse="spectrum")
    data = ctfit.simulate(ctfit.Material(st, TRUTH, channels=("R", "G", "B")), n_pairs=300, noise=0.01, seed=3)
    light = fit_to_tolerance(data, st, report=False)
    full = ctfit.fit(data, st)
    assert made and "fit_light" not in made and "fit_report" not in made
    assert full.stderr is not None and np.all(np.isfinite(full.stderr["Rd"]))
    assert light.stats["cost"] == pytest.approx(full.stats["cost"], rel=1e-12)
    assert light.stats["gauss_newton_decrease"] == pytest.approx(full.stats["gauss_newton_decrease"], rel=1e-6, abs=1e-15)
    np.testing.assert_allclose(light.material.params.rd, full.material.params.rd, rtol=1e-12)


def _reference_standard_errors(jtj, jt, scale2, order, free):
    """The standard errors as they were computed before (each quantity on its own; the SVD's
    condition number always), to compare the one-product form with."""
    sub = jtj[np.ix_(free, free)]
    if sub.size:
        cond = np.linalg.cond(sub)
        if not np.isfinite(cond) or cond > 1e12:
            return None
    cov_u = np.zeros_like(jtj)
    if sub.size:
        cov_u[np.ix_(free, free)] = np.linalg.inv(sub) * scale2
    se = {}
    for k, jk in jt.items():
        jk = np.asarray(jk).reshape(-1, jtj.shape[0])
        with np.errstate(invalid="ignore", over="ignore"):
            var = np.sum((jk @ cov_u) * jk, axis=1)
        v = np.sqrt(np.maximum(var, 0))
        nonzero = jk != 0
        v = np.where(~nonzero[:, free].any(axis=1), np.nan, v)  # no free coordinate (held ones, or none at all): no error
        se[k] = v[order] if k in ("m", "weight") and order is not None else v
    return se


@pytest.mark.parametrize("log_cond", [0, 6, 10, 10.9, 11.5, 11.99, 12.01, 13, 17])
def test_standard_errors_are_the_per_quantity_ones_at_any_conditioning(log_cond):
    """One product over every quantity's rows, and the SVD skipped where ‖A‖_F‖A⁻¹‖_F already
    bounds the condition number ten times below 1e12: the same numbers (a row in a product of
    many may round in its last bit otherwise than alone: BLAS's kernels for one row differ), NaN
    in the same places, and None exactly where ``np.linalg.cond`` is above 1e12."""
    rng = np.random.default_rng(int(log_cond * 100))
    p = 9
    q, _ = np.linalg.qr(rng.normal(size=(p, p)))
    jtj = (q * np.logspace(0, -log_cond, p)) @ q.T
    jtj = (jtj + jtj.T) / 2
    jt = {"s": rng.normal(size=p), "m": rng.normal(size=(2, p)), "weight": rng.normal(size=(2, p)), "F0": rng.normal(size=(4, p))}
    jt["F0"][1, :] = 0.0  # depends on nothing (n held at its cap where F0 = 1): NaN, not 0
    jt["F0"][2, 3:] = 0.0  # depends only on coordinates held below
    jt["F0"][3, 0] = np.inf  # dn/dF0 at F0 = 0
    free = np.ones(p, bool)
    free[:3] = [False, True, True] if log_cond < 11 else [True, True, True]
    order = np.array([1, 0])
    want = _reference_standard_errors(jtj, jt, 0.7, order, free)
    got = standard_errors(jtj, jt, 0.7, order, free)
    if want is None:
        assert got is None
        return
    assert got is not None and list(got) == list(want)
    for k in want:
        np.testing.assert_array_equal(np.isnan(got[k]), np.isnan(want[k]))
        np.testing.assert_allclose(got[k], want[k], rtol=1e-13, atol=0)


def test_standard_errors_of_a_singular_matrix_are_none():
    jtj = np.ones((3, 3))
    assert standard_errors(jtj, {"s": np.ones(3)}, 1.0, None) is None
