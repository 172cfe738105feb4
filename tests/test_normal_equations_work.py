"""The compiled normal equations do the work of their parts: the Jacobian's columns are made once
and the products read them (``jacobian._fenced``). Without the fence XLA fused the columns'
elementwise work into every product that reads them: 4.0 MFLOP where the parts take 1.2 on a
chunk of 2,048 samples, 0.39 ms instead of 0.21 ms. Checked with XLA's own count of the compiled
program's floating-point operations (its cost analysis), not with a timing."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ctfit
from ctfit._fitting import jacobian
from ctfit._fitting.least_squares import prepare_fit


def _flops(fn, *args) -> float:
    cost = jax.jit(fn).lower(*args).compile().cost_analysis()
    cost = cost[0] if isinstance(cost, list) else cost
    return float(cost["flops"])


def _data() -> ctfit.Measurement:
    """2,000 samples, each its own direction pair and one of 31 bands: a two-lobe metal, R_d = F0/π."""
    truth = ctfit.Material(ctfit.Structure(lobes=2, diffuse="F0/pi"),
                           ctfit.Params(s=np.asarray(0.9), m=np.array([0.2, 0.4]), w=np.array([0.6, 0.4]), f0=np.linspace(0.5, 0.95, 31)),
                           wavelength_nm=np.linspace(400.0, 700.0, 31))
    grid = ctfit.simulate(truth, n_pairs=200, noise=0.02, seed=0)
    keep = np.random.default_rng(1).choice(len(grid), 2000, replace=False)
    return grid.replace(sigma=None, **{c: np.asarray(getattr(grid, c))[keep] for c in ("theta_i", "phi_i", "theta_o", "phi_o", "band", "brdf")})


@pytest.mark.parametrize("dense", [False, True])
def test_the_normal_equations_do_no_more_work_than_their_parts(dense):
    prep = prepare_fit(_data(), ctfit.Structure(lobes=2, diffuse="F0/pi"), start=None, fixed=(), loss="relative", dtype=jnp.float64, starts=3)
    problem, u = prep.problem, prep.u0
    kinds = {k: kind for k, (kind, _) in jacobian._columns(problem, u, problem.y)[2].items()}

    def columns(uu, pr):
        res, _, cols = jacobian._columns(pr, uu, pr.y)
        return res, {k: col for k, (_, col) in cols.items()}

    def products(res, arrays, pr):
        return jacobian._normal_equations_from(pr, res, {k: (kinds[k], a) for k, a in arrays.items()}, sorted(u), dense)

    res, arrays = jax.jit(columns)(u, problem)
    parts = _flops(columns, u, problem) + _flops(products, res, arrays, problem)
    whole = _flops(lambda uu, pr: jacobian.normal_equations(pr, uu, dense=dense), u, problem)
    assert whole <= 1.2 * parts, (whole, parts)
    # and the same values as the parts
    got = jax.jit(lambda uu, pr: jacobian.normal_equations(pr, uu, dense=dense))(u, problem)
    want = jax.jit(products)(res, arrays, problem)
    for g, w in zip(got, want):
        np.testing.assert_allclose(g, w, rtol=1e-12, atol=1e-12 * float(np.max(np.abs(w))))


def test_the_model_s_values_come_with_the_normal_equations_at_no_more_work():
    """``fit_ne`` returns the chunk's model values beside (½‖r‖², Jᵀr, JᵀJ), for the report's
    residual summary (made from them on the host): they are the model's values, and returning
    them adds no floating-point work (the pass computes them anyway; fenced, they are not
    computed twice). The sums equal those of the pass alone to rounding: the two programs may
    order a reduction differently (one entry of Jᵀr of 35 differs in its last bit)."""
    from ctfit._fitting.problem import model_values

    prep = prepare_fit(_data(), ctfit.Structure(lobes=2, diffuse="F0/pi"), start=None, fixed=(), loss="relative", dtype=jnp.float64, starts=3)
    problem, u = prep.problem, prep.u0
    with_values = lambda uu, pr: jacobian.normal_equations_and_values(pr, uu, dense=True)
    alone = lambda uu, pr: jacobian.normal_equations(pr, uu, dense=True)
    assert _flops(with_values, u, problem) <= 1.02 * _flops(alone, u, problem)
    *sums, values = jax.jit(with_values)(u, problem)
    for g, w in zip(sums, jax.jit(alone)(u, problem)):
        np.testing.assert_allclose(g, w, rtol=4 * np.finfo(np.float64).eps, atol=4 * np.finfo(np.float64).eps * float(np.max(np.abs(w))))
    want = jax.jit(model_values)(problem, u)
    assert values.shape == problem.y.shape
    np.testing.assert_allclose(values, want, rtol=1e-13, atol=0)
