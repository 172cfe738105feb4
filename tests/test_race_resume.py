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
