"""The seeds that go on after the race's first phase resume their solves (the solver's state, its
damping included, carried over): every seed takes the steps of one uninterrupted solve and ends
where it would, on chunks (``chunked_fit._race``) and in one compiled program
(``seeded_solve._structured_lm``)."""

from __future__ import annotations

import equinox as eqx
import jax
import numpy as np
import pytest

import ctfit
from ctfit._fitting import chunked_fit, least_squares as _fit, seeded_solve

RACE_STEPS = seeded_solve.RACE_STEPS

GOLD = ctfit.Material(ctfit.Structure(lobes=2), ctfit.Params(s=np.asarray(0.8), m=np.array([0.15, 0.4]), w=np.array([0.6, 0.4]),
                                                              f0=np.array([0.6, 0.9])), wavelength_nm=np.array([450.0, 650.0]))


@pytest.fixture(scope="module")
def data() -> ctfit.Measurement:
    """2,000 samples of GOLD, each its own direction pair and one band, 2 % noise."""
    rng = np.random.default_rng(5)
    n = 2000
    ti, to, po = rng.uniform(0, 75, n), rng.uniform(0, 75, n), 180 + rng.uniform(-60, 60, n)
    band = rng.integers(0, 2, n)
    clean = ctfit.evaluate_at(GOLD, theta_i=ti, theta_o=to, phi_o=po)[np.arange(n), band]
    return ctfit.Measurement(theta_i=ti, phi_i=np.zeros(n), theta_o=to, phi_o=po, band=band, wavelength_nm=GOLD.wavelength_nm,
                             brdf=clean * (1 + 0.02 * rng.standard_normal(n)))


def _prepared(data, chunk):
    return _fit.prepare_fit(data, GOLD.structure, start=None, fixed=(), loss="relative", dtype=jax.numpy.float64, starts=3, chunk=chunk)


def _assert_same_solves(raced: dict, alone: dict) -> None:
    assert len(raced["steps"]) == 3 and np.all(raced["steps"] > RACE_STEPS)  # every seed went on after the first phase
    np.testing.assert_array_equal(raced["steps"], alone["steps"])
    np.testing.assert_allclose(raced["costs"], alone["costs"], rtol=1e-12)
    for k in raced["u"]:
        np.testing.assert_allclose(raced["u"][k], alone["u"][k], rtol=1e-12, atol=1e-14)


def test_a_raced_seed_on_chunks_takes_the_steps_of_one_solve(data, monkeypatch):
    raced = _fit.solve_prepared(_prepared(data, chunked_fit.ROWS), "lm", 256)
    monkeypatch.setattr(chunked_fit, "RACE_STEPS", 10**6)  # no race: every seed solved to the end in one go
    alone = _fit.solve_prepared(_prepared(data, chunked_fit.ROWS), "lm", 256)
    _assert_same_solves(raced, alone)


def test_a_raced_seed_in_one_program_takes_the_steps_of_one_solve(data, monkeypatch):
    prep = _prepared(data, None)
    args = (prep.problem, prep.u0, prep.grid, *prep.options("lm", 256))
    raced = jax.device_get(eqx.filter_jit(lambda *a: _fit.fit_core(*a))(*args))  # traced anew: RACE_STEPS is read when tracing
    monkeypatch.setattr(seeded_solve, "RACE_STEPS", 10**6)
    alone = jax.device_get(eqx.filter_jit(lambda *a: _fit.fit_core(*a))(*args))
    _assert_same_solves(raced, alone)


def test_the_solver_holds_each_seeds_cost_and_normal_equations_at_its_value(data):
    """The cost and normal equations the solver returns per seed (its last accepted point's, which
    ``fit_core`` reports instead of a pass of its own) are those a fresh pass gives there."""
    from jax.flatten_util import ravel_pytree

    from ctfit._fitting.jacobian import normal_equations
    from ctfit._fitting.starts import seed_points

    prep = _prepared(data, None)

    def solve(problem, u0, grid):
        seeds = seed_points(problem, u0, 3, grid)
        values, _, steps, costs, normal = seeded_solve.solve_seeds(problem, seeds, "lm", 256)
        fresh = jax.vmap(lambda u: normal_equations(problem, u))(values)
        return steps, costs, normal, fresh, jax.vmap(lambda u: ravel_pytree(u)[0])(values)

    steps, costs, (jtr, jtj), (cost, jtr_fresh, jtj_fresh), _ = jax.device_get(eqx.filter_jit(solve)(prep.problem, prep.u0, prep.grid))
    assert np.all(steps > 0)
    np.testing.assert_allclose(costs, cost, rtol=1e-12)
    # Jᵀr is near 0 at a minimum, a difference of terms as large as ‖J_k‖‖r‖ (Cauchy–Schwarz): rounding of those.
    bound = np.sqrt(np.diagonal(jtj_fresh, axis1=1, axis2=2) * 2 * cost[:, None])
    np.testing.assert_allclose(jtr, jtr_fresh, rtol=0, atol=1e-12 * np.max(bound))
    np.testing.assert_allclose(jtj, jtj_fresh, rtol=1e-12, atol=1e-14 * np.max(np.abs(jtj_fresh)))


def test_a_fit_without_steps_reports_the_normal_equations_of_its_start(data):
    """``max_steps=0``: no seed takes a step, so the solver holds no normal equations; the report's
    come from a pass of its own (finite, the cost at the best seed)."""
    from ctfit._fitting.jacobian import normal_equations

    prep = _prepared(data, None)
    out = jax.device_get(eqx.filter_jit(lambda *a: _fit.fit_core(*a))(prep.problem, prep.u0, prep.grid, *prep.options("lm", 0)))
    assert np.all(out["steps"] == 0)
    cost, _, jtj = jax.device_get(jax.jit(normal_equations)(prep.problem, out["u"]))
    keep = ~out["on_bound"]
    np.testing.assert_allclose(out["jtj"], np.where(keep[:, None] & keep[None, :], jtj, 0), rtol=1e-12)
    assert np.isfinite(cost) and out["gn_decrease"] > 1e-3  # a seed, not a minimum: a Gauss–Newton step promises much
