"""Bounds held by the solver: a parameter that belongs on its bound ends there in a few steps,
and the fit converges (a bound that holds is a result, not a failure)."""

import jax.numpy as jnp
import numpy as np
import pytest

import ctfit
from ctfit import load_material, simulate
from ctfit._fitting.coordinates import fraction_weights, lobe_weights, stick_fractions
from ctfit._fitting.solvers import active_set, predicted_decrease

from conftest import ROOT


def test_metal_with_the_default_structure_converges_in_few_steps():
    """Copper (conductor Fresnel, no diffuse part) fitted with the default one lobe + diffuse:
    s runs to its upper bound; it used to crawl there through a sigmoid (156 steps). (36 steps
    with the race's seeds restarted after its first phase, 41 with their solves resumed.)"""
    cu = load_material(ROOT / "configs" / "copper.toml")
    data = simulate(cu, 2000, wavelength_nm=np.arange(400.0, 701.0, 50.0), seed=1, max_theta=50.0)
    res = ctfit.fit(data, ctfit.Structure(lobes=1, diffuse="F0/pi"))  # the paper's homogeneous material
    assert res.converged, res.warnings
    assert res.stats["steps"] <= 45
    assert float(res.material.params.s) > 1 - 1e-4
    np.testing.assert_allclose(res.material.params.m, [0.2], rtol=0.02)


def test_a_lobe_weight_reaches_zero_and_is_reported():
    st = ctfit.Structure(lobes=1)
    truth = ctfit.Material(st, ctfit.Params(m=np.array([0.2]), w=np.array([1.0]), f0=np.full(4, 0.9)), wavelength_nm=np.linspace(400, 700, 4))
    data = simulate(truth, 300, noise=0.01, seed=3)
    res = ctfit.fit(data, ctfit.Structure(lobes=2))
    assert res.converged
    w = np.asarray(res.material.params.w)
    assert np.all(np.isfinite(w)) and np.isclose(w.sum(), 1.0)
    if w.min() == 0.0:  # on its bound: named, and the bound is in the result
        assert any(k.startswith("weight") for k in res.stats["on_bound"])
        assert any("weight 0 (on its bound)" in x for x in res.warnings)
    else:
        assert any("degenerate" in x for x in res.warnings)


@pytest.mark.parametrize("w", [[0.5, 0.5], [0.2, 0.3, 0.5], [0.0, 0.4, 0.6], [0.7, 0.3, 0.0], [0.25] * 4])
def test_stick_breaking_weights_round_trip(w):
    v = stick_fractions(w)
    assert np.all((v >= 0) & (v <= 1))
    np.testing.assert_allclose(lobe_weights(jnp.asarray(v), "box"), w, atol=1e-15)
    np.testing.assert_allclose(fraction_weights(v), np.asarray(lobe_weights(jnp.asarray(v), "box")), rtol=0, atol=1e-16)  # the host's twin


def test_active_set_holds_only_what_pushes_outward():
    y = jnp.array([0.0, 0.0, 1.0, 1.0, 0.5])
    g = jnp.array([1.0, -1.0, -1.0, 1.0, 1.0])
    lo, hi = jnp.zeros(5), jnp.ones(5)
    np.testing.assert_array_equal(active_set(y, g, lo, hi), [True, False, True, False, False])


def test_predicted_decrease_ignores_held_and_undetermined_directions():
    h = jnp.diag(jnp.array([2.0, 1.0, 0.0]))
    g = jnp.array([2.0, 1.0, 0.0])
    assert float(predicted_decrease(h, g)) == pytest.approx(0.5 * (4 / 2 + 1 / 1))
    assert float(predicted_decrease(h, g, jnp.array([True, False, True]))) == pytest.approx(0.5 * 4 / 2)


def _gauss_newton_data(rank: int, spread: float, dtype, seed: int = 0):
    """JᵀJ and g = Jᵀr (35 parameters, 400 samples) in ``dtype``; singular values of J from 1 to
    ``spread``, the last 35 − ``rank`` of them zero."""
    rng = np.random.default_rng([seed, rank])
    u, _ = np.linalg.qr(rng.standard_normal((400, 35)))
    v, _ = np.linalg.qr(rng.standard_normal((35, 35)))
    jac = (u * np.geomspace(1.0, spread, 35) * (np.arange(35) < rank)) @ v.T
    r = rng.standard_normal(400)
    return (jac.T @ jac).astype(dtype), (jac.T @ r).astype(dtype)


FREE = np.arange(35) % 4 != 1  # every fourth variable held


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("rank", [35, 30, 1])
@pytest.mark.parametrize("mask", [None, FREE])
def test_predicted_decrease_is_the_regularised_solve(dtype, rank, mask):
    """½ gᵀ(JᵀJ + μI)⁻¹g with μ = 10·P·ε·max diag JᵀJ, against NumPy's solve in float64: full
    rank and ill-conditioned (singular values over 10⁶; 10³ in float32), rank-deficient, rank one;
    with held variables (their rows, columns and gradient left out)."""
    h, g = _gauss_newton_data(rank, 1e-3 if dtype == np.float32 else 1e-6, dtype)
    if mask is not None:
        h, g = np.where(mask[:, None] & mask[None, :], h, 0), np.where(mask, g, 0)
    mu = np.max(np.diag(h)).astype(float) * np.finfo(dtype).eps * 35 * 10
    want = 0.5 * g.astype(float) @ np.linalg.solve(h.astype(float) + mu * np.eye(35), g.astype(float))
    got = float(predicted_decrease(jnp.asarray(h), jnp.asarray(g), None if mask is None else jnp.asarray(mask)))
    assert got == pytest.approx(want, rel=1e-6 if dtype == np.float64 else 1e-3)


@pytest.mark.parametrize("rank", [35, 20, 1])
def test_predicted_decrease_is_the_pseudo_inverse_where_the_data_determines_it(rank):
    """Where every determined direction's eigenvalue is far above μ (here ≥ 10⁻⁶ of the
    largest against μ ≈ 10⁻¹³), the regularised solve is NumPy's pseudo-inverse: the undetermined
    directions left out, the others whole."""
    h, g = _gauss_newton_data(rank, 1e-3, np.float64, seed=1)
    want = 0.5 * g @ np.linalg.pinv(h, rcond=1e-10, hermitian=True) @ g
    assert float(predicted_decrease(jnp.asarray(h), jnp.asarray(g))) == pytest.approx(want, rel=1e-6)


def test_predicted_decrease_where_rounding_makes_the_matrix_indefinite():
    """A matrix no Cholesky factor exists for (an eigenvalue below −μ, as rounding can make
    in float32): the eigendecomposition's answer, negative directions left out, finite."""
    h = jnp.diag(jnp.array([2.0, 1.0, -1e-3]))
    g = jnp.array([2.0, 1.0, 0.5])
    assert float(predicted_decrease(h, g)) == pytest.approx(0.5 * (4 / 2 + 1 / 1))
    assert float(predicted_decrease(jnp.zeros((3, 3)), jnp.zeros(3))) == 0.0


def test_a_step_through_a_bound_near_by_promises_only_what_it_can_take():
    """A conductor's k of 2.6·10⁻⁸ (F depends on k², so its curvature vanishes at k = 0) with a
    gradient towards 0: its own Newton step, −g/H, goes 5·10⁸ times past the bound. The step
    held there gains |g|·k at most, not the g²/(H + μ) that :func:`predicted_decrease` reads with
    k free; a variable far from its bound keeps its share. NumPy and JAX agree."""
    from ctfit._fitting.stationarity import held_by_bound, stationary_decrease

    y, g = np.array([2.55e-8, 0.5]), np.array([1.31e-4, 3.0])
    h = np.diag([2.76e-7, 2.0e8])
    lo, hi = np.array([0.0, 0.0]), np.array([np.inf, 1.0])
    free = predicted_decrease(h, g, xp=np)
    np.testing.assert_array_equal(held_by_bound(y, g, np.diag(h), lo, hi, np), [True, False])
    want = 1.31e-4 * 2.55e-8 + 0.5 * 9 / (2.0e8 * (1 + np.finfo(float).eps * 20))
    assert stationary_decrease(y, g, h, lo, hi, np) == pytest.approx(want, rel=1e-9)
    assert free > 1e4 * want  # the promise that kept a fit at the truth running to its step limit
    traced = stationary_decrease(jnp.asarray(y), jnp.asarray(g), jnp.asarray(h), jnp.asarray(lo), jnp.asarray(hi))
    assert float(traced) == pytest.approx(want, rel=1e-9)
    # Undetermined (H ≈ 0) and near a bound: no more than its regularised share, as free.
    y2, g2, h2 = np.array([0.3]), np.array([1e-9]), np.array([[0.0]])
    assert stationary_decrease(y2, g2, h2, np.zeros(1), np.ones(1), np) <= predicted_decrease(h2, g2, xp=np) + 1e-30


def test_a_conductor_fit_started_at_the_truth_stops_there():
    """n(λ) crossing 1 with k = 0 (docs/stability.md), started at the truth: it ran to its step
    limit and read 'not a minimum' (k of one band 2.6·10⁻⁸ above its bound, promising a step
    through it); it stops in a few steps."""
    mat = ctfit.Material(ctfit.Structure(lobes=1, fresnel="conductor"),
                         ctfit.Params(m=np.array([0.2]), w=np.array([1.0]), n=np.array([1.3, 1.1, 1.0, 0.8]), k=np.zeros(4)),
                         wavelength_nm=np.array([400.0, 500.0, 600.0, 700.0]))
    data = simulate(mat, 300, noise=0.01, seed=1, max_theta=85.0)
    res = ctfit.fit(data, mat.structure, start=mat.params, dtype=jnp.float64)
    assert res.converged and res.stats["steps"] <= 10, (res.stats["steps"], res.warnings)
    assert not any(w.startswith("not a minimum") for w in res.warnings)


def test_the_solver_evaluates_the_cost_without_linearising_it(monkeypatch):
    """A Levenberg–Marquardt step evaluates the cost and, once accepted, forms the normal
    equations: it never linearises the objective (optimistix's own step does, a second
    Jacobian-sized pass per step)."""
    import jax

    from ctfit._runtime import stored_programs as _aot

    monkeypatch.setattr(_aot, "_memory", {})
    monkeypatch.setattr(_aot, "_store", lambda: None)

    def no_linearize(*a, **k):
        raise AssertionError("the objective was linearised")

    monkeypatch.setattr(jax, "linearize", no_linearize)
    st = ctfit.Structure(lobes=1)
    truth = ctfit.Material(st, ctfit.Params(m=np.array([0.25]), w=np.array([1.0]), f0=np.array([0.6, 0.8])), wavelength_nm=np.array([450.0, 650.0]))
    res = ctfit.fit(simulate(truth, 150, noise=0.01, seed=4), st, starts=1)
    assert res.converged
    np.testing.assert_allclose(res.material.params.m, [0.25], rtol=0.02)


def test_a_fit_that_explains_none_of_the_data_has_not_converged():
    """A stationary point where the model is (almost) 0 — here m held at 10⁻⁴, a lobe that
    reaches no sample — is not a converged fit, and the result says why."""
    st = ctfit.Structure(lobes=1)
    truth = ctfit.Material(st, ctfit.Params(m=np.array([0.3]), w=np.array([1.0]), f0=np.array([0.6, 0.8])), wavelength_nm=np.array([450.0, 650.0]))
    data = simulate(truth, 200, noise=0.01, seed=5)
    res = ctfit.fit(data, st, start=ctfit.Params(m=np.array([1e-4]), w=np.array([1.0]), f0=np.array([0.5, 0.5])), fixed=("m",))
    assert not res.converged
    assert any("explains almost none of the data" in w for w in res.warnings)
