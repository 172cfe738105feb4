"""Fitting: recovery from synthetic data, stiff cases, degeneracy reports, implicit gradients."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

import ctfit
from ctfit import fit, simulate
from ctfit._fitting.coordinates import from_params, to_params
from ctfit._fitting.jacobian import residual
from ctfit._fitting.problem import make_problem

WL8 = np.linspace(400.0, 700.0, 8)
WL31 = np.linspace(400.0, 700.0, 31)


def copper_like(wl):
    """A copper-like F0 spectrum: low in the blue, high in the red."""
    return 0.55 + 0.4 / (1 + np.exp(-(wl - 570.0) / 25.0))


def material(structure, wl, **params):
    return ctfit.Material(structure, ctfit.Params(**params), wavelength_nm=wl, name="truth")


def test_two_lobe_metal_31_wavelengths_recovered():
    st = ctfit.Structure(lobes=2)
    f0 = copper_like(WL31)
    truth = material(st, WL31, m=np.array([0.2, 0.4]), w=np.array([0.6, 0.4]), f0=f0)
    data = simulate(truth, 1500, noise=0.02, seed=3)
    res = fit(data, st)
    p = res.material.params
    assert res.converged
    np.testing.assert_allclose(p.m, [0.2, 0.4], rtol=0.01)
    np.testing.assert_allclose(p.w, [0.6, 0.4], atol=0.02)
    assert np.max(np.abs(p.f0 - f0)) < 0.005
    assert res.stderr is not None and np.all(np.isfinite(res.stderr["F0"]))
    # The reported n is the paper's effective index of the fitted F0.
    np.testing.assert_allclose(p.n, (1 + np.sqrt(p.f0)) / (1 - np.sqrt(p.f0)), rtol=1e-12)


@pytest.mark.parametrize("s, m", [(0.4, 0.30), (0.8, 0.15), (0.2, 0.35)])  # Table I: rubber, obsidian, rust
def test_table1_nonmetals_recovered(s, m):
    st = ctfit.Structure(lobes=1, fresnel="n", diffuse="spectrum")
    rd = np.linspace(0.02, 0.12, 8)
    truth = material(st, WL8, s=np.asarray(s), m=np.array([m]), w=np.array([1.0]), n=np.full(8, 1.5), rd=rd)
    data = simulate(truth, 800, noise=0.01, seed=4)
    res = fit(data, st)
    p = res.material.params
    assert res.converged
    assert abs(float(p.s) - s) < 0.01
    np.testing.assert_allclose(p.m, [m], rtol=0.01)
    f0_true = float(ctfit.f0_from_n(1.5))
    assert np.max(np.abs(np.asarray(ctfit.f0_from_n(p.n)) - f0_true)) < 0.005


def test_lunar_dust_diffuse_only():
    st = ctfit.Structure(lobes=0, diffuse="spectrum")
    rd = np.linspace(0.03, 0.06, 8)
    data = simulate(material(st, WL8, rd=rd), 300, noise=0.01, seed=5)
    res = fit(data, st)
    assert res.converged
    np.testing.assert_allclose(res.material.params.rd, rd, rtol=0.01)
    assert res.material.params.m is None and res.material.params.s is None


def test_chrome_like_narrow_lobe_up_to_89_degrees():
    st = ctfit.Structure(lobes=1)
    f0 = np.full(8, 0.98)
    truth = material(st, WL8, m=np.array([0.00935]), w=np.array([1.0]), f0=f0)
    data = simulate(truth, 800, noise=0.02, seed=6, max_theta=89.0)
    res = fit(data, st)
    assert res.converged
    np.testing.assert_allclose(res.material.params.m, [0.00935], rtol=0.01)
    assert np.max(np.abs(res.material.params.f0 - f0)) < 0.005


def test_close_lobes_are_reported_or_recovered_never_nan():
    st = ctfit.Structure(lobes=2)
    truth = material(st, WL8, m=np.array([0.2, 0.202]), w=np.array([0.5, 0.5]), f0=np.full(8, 0.9))
    data = simulate(truth, 600, noise=0.02, seed=7)
    res = fit(data, st)
    p = res.material.params
    assert np.all(np.isfinite(p.m)) and np.all(np.isfinite(p.w)) and np.all(np.isfinite(p.f0))
    recovered = np.allclose(p.m, [0.2, 0.202], rtol=0.01) and np.allclose(p.w, [0.5, 0.5], atol=0.02)
    reported = any("degenerate" in w for w in res.warnings) or res.stderr is None
    assert recovered or reported


@pytest.mark.parametrize("s_true", [0.0, 1.0])
def test_s_at_its_bounds_is_reported(s_true):
    st = ctfit.Structure(lobes=1, diffuse="F0/pi")
    truth = material(st, WL8, s=np.asarray(s_true), m=np.array([0.3]), w=np.array([1.0]), f0=np.full(8, 0.5))
    data = simulate(truth, 600, noise=0.01, seed=8)
    res = fit(data, st)
    assert abs(float(res.material.params.s) - s_true) < 0.01
    assert any("bound" in w for w in res.warnings)


def test_rows_with_exact_zeros_are_handled_by_relative_and_log_losses():
    st = ctfit.Structure(lobes=1)
    truth = material(st, WL8, m=np.array([0.05]), w=np.array([1.0]), f0=np.full(8, 0.9))
    data = simulate(truth, 600, noise=0.0, seed=9)
    assert np.mean(data.brdf == 0) > 0.01  # far from a narrow peak the BRDF underflows to 0
    for loss in ("relative", "log"):
        res = fit(data, st, loss=loss)
        assert res.converged, loss
        np.testing.assert_allclose(res.material.params.m, [0.05], rtol=1e-3)


def test_gradient_of_fitted_parameters_wrt_data_matches_finite_differences():
    st = ctfit.Structure(lobes=1)
    truth = material(st, WL8[:3], m=np.array([0.3]), w=np.array([1.0]), f0=np.array([0.6, 0.7, 0.8]))
    data = simulate(truth, 150, noise=0.01, seed=10)
    start = ctfit.Params(m=np.array([0.25]), w=np.array([1.0]), f0=np.full(3, 0.5))
    problem = make_problem(st, data, fixed_params=start, loss="absolute")
    u0 = {k: jnp.asarray(v) for k, v in from_params(problem.spec, start).items()}
    solver = optx.LevenbergMarquardt(rtol=1e-12, atol=1e-14)

    def fitted_m(y):
        sol = optx.least_squares(residual, solver, u0, (y, problem), max_steps=200)
        return to_params(problem.spec, sol.value, problem.fixed).m[0]

    y = problem.y
    direction = jnp.asarray(np.random.default_rng(0).standard_normal(y.shape)) * problem.mask * 0.01 * y
    analytic = jax.jvp(fitted_m, (y,), (direction,))[1]
    eps = 1e-4
    numeric = (fitted_m(y + eps * direction) - fitted_m(y - eps * direction)) / (2 * eps)
    assert abs(float(numeric)) > 0
    np.testing.assert_allclose(float(analytic), float(numeric), rtol=1e-4)


def test_custom_jvp_matches_plain_autodiff():
    from ctfit._fitting.losses import loss_residuals
    from ctfit._fitting.problem import model_values

    st = ctfit.Structure(lobes=2, geometry="smith", diffuse="spectrum")
    truth = material(st, WL8[:4], s=np.asarray(0.7), m=np.array([0.1, 0.3]), w=np.array([0.3, 0.7]), f0=np.full(4, 0.6), rd=np.full(4, 0.05))
    data = simulate(truth, 60, noise=0.01, seed=11)

    @eqx.filter_jit
    def both(problem, u):
        plain = jax.jacfwd(lambda uu: loss_residuals(problem, model_values(problem, uu), problem.y))(u)
        custom = jax.jacfwd(lambda uu: residual(uu, (problem.y, problem)))(u)
        return plain, custom

    for loss in ("absolute", "relative", "sigma", "cosine", "log"):
        problem = make_problem(st, data, fixed_params=truth.params, loss=loss)
        u = {k: jnp.asarray(v) * 1.01 for k, v in from_params(problem.spec, truth.params).items()}
        plain, custom = both(problem, u)
        for k in u:
            np.testing.assert_allclose(custom[k], plain[k], rtol=1e-9, atol=1e-12, err_msg=f"{loss} {k}")


@pytest.mark.parametrize("n_pairs", [2000, 5000])
def test_float32_normal_equations_match_float64(n_pairs):
    """Guards against XLA CPU's float32 reduction miscompile (jaxlib 0.10.2) in the fit's sums."""
    from ctfit._fitting.jacobian import normal_equations

    st = ctfit.Structure(lobes=2)
    truth = material(st, WL8, m=np.array([0.1, 0.3]), w=np.array([0.4, 0.6]), f0=np.linspace(0.5, 0.9, 8))
    data = simulate(truth, n_pairs, noise=0.02, seed=1)
    out = []
    for dt in (jnp.float32, jnp.float64):
        problem = make_problem(st, data, fixed_params=truth.params, loss="relative", dtype=dt)
        u = {k: jnp.asarray(v, dt) * 1.02 for k, v in from_params(problem.spec, truth.params).items()}
        out.append([np.asarray(a, float) for a in eqx.filter_jit(normal_equations)(problem, u)])
    (c32, g32, h32), (c64, g64, h64) = out
    assert abs(c32 / c64 - 1) < 1e-4
    assert np.max(np.abs(g32 - g64)) < 1e-4 * np.max(np.abs(g64))
    assert np.max(np.abs(h32 - h64)) < 1e-4 * np.max(np.abs(h64))


@pytest.mark.parametrize(("bands", "scattered", "family"),  # RGB, dense: one JᵀJ of the spread columns; else block by block
                         [(3, False, "metal"), (3, True, "metal"), (16, False, "metal"), (16, True, "metal"), (16, True, "plastic"), (3, False, "plastic")])
def test_normal_equations_are_the_jacobians_products(bands, scattered, family):
    """½‖r‖², Jᵀr and JᵀJ of the fit's chunk kernel against J from ``jax.jacfwd`` of the plain residual."""
    from jax.flatten_util import ravel_pytree

    from ctfit._fitting.jacobian import DENSE_BAND_COLUMNS, normal_equations
    from ctfit._fitting.losses import loss_residuals
    from ctfit._fitting.problem import model_values

    wl = np.linspace(400.0, 700.0, bands)
    if family == "metal":
        st = ctfit.Structure(lobes=2, diffuse="spectrum", fresnel="conductor")
        truth = material(st, wl, s=np.asarray(0.7), m=np.array([0.1, 0.4]), w=np.array([0.6, 0.4]), n=np.linspace(0.3, 1.9, bands),
                         k=np.linspace(2, 4, bands), rd=np.linspace(0.05, 0.2, bands))
    else:
        st = ctfit.Structure(family="plastic", lobes=3, diffuse="transmitted")
        truth = material(st, wl, s=np.asarray(0.7), m=np.array([0.1, 0.3, 0.8]), w=np.array([0.5, 0.3, 0.2]), n=np.full(bands, 1.5),
                         rd=np.linspace(0.05, 0.2, bands))
    data = simulate(truth, 400, noise=0.02, seed=3)
    if scattered:
        keep = np.random.default_rng(0).random(len(data)) < 1.0 / bands
        data = data.replace(**{k: np.asarray(getattr(data, k))[keep] for k in ("theta_i", "phi_i", "theta_o", "phi_o", "band", "brdf", "sigma")})
    problem = make_problem(st, data, fixed_params=truth.params, loss="robust-relative")
    assert problem.spec.grid is not scattered
    u = {k: jnp.asarray(v) * 0.97 + 0.01 for k, v in from_params(problem.spec, truth.params).items()}
    flat, unflat = ravel_pytree(u)
    assert ((3 if family == "metal" else 1) * bands > DENSE_BAND_COLUMNS) is (bands == 16)  # n, k, R_d or R_d per band: dense only with RGB
    plain = lambda pr, f: loss_residuals(pr, model_values(pr, unflat(f)), pr.y)
    r, jac = eqx.filter_jit(lambda pr, f: (plain(pr, f), jax.jacfwd(lambda g: plain(pr, g))(f)))(problem, flat)
    for dense in (False, True):  # block by block, and the chunk kernel's form (stacked columns, or packed sums on samples)
        cost, grad, hess = eqx.filter_jit(lambda pr, uu, d=dense: normal_equations(pr, uu, dense=d))(problem, u)
        np.testing.assert_allclose(cost, 0.5 * r @ r, rtol=1e-12)
        np.testing.assert_allclose(grad, jac.T @ r, rtol=1e-9, atol=1e-12 * np.max(np.abs(jac.T @ r)))
        np.testing.assert_allclose(hess, jac.T @ jac, rtol=1e-9, atol=1e-12 * np.max(np.abs(jac.T @ jac)))


def test_one_sample_in_ten_dropped_to_zero_does_not_make_the_fit_zero():
    """A rubber (configs/rubber.toml, 300 pairs × 7 bands, 2 % noise) with every tenth brdf set to 0,
    fitted with its own structure and the default loss: R_d, s and the quality are those of the
    clean data. With a dark sample's residual capped at 10 (``ROBUST_CAP`` before), a zero cost as
    much as ten bright samples the model misses entirely, and a model that is 0 everywhere was the
    cheaper fit (median error 99.5 %, R_d 10⁻⁴ against 0.019); every twentieth gave R_d 0.0186. From
    about a third of the values 0 the model that is 0 everywhere is the cheaper fit."""
    from conftest import ROOT

    rubber = ctfit.load_material(ROOT / "configs" / "rubber.toml")
    data = simulate(rubber, 300, noise=0.02, seed=1).replace(sigma=None)
    y = np.array(data.brdf)
    y[9::10] = 0.0
    res = fit(data.replace(brdf=y), rubber.structure)
    clean = fit(data, rubber.structure)
    assert res.converged and res.stats["quality"]["median_relative_error"] < 1.05 * clean.stats["quality"]["median_relative_error"]
    np.testing.assert_allclose(res.material.params.rd, clean.material.params.rd, rtol=0.01)
    assert abs(float(res.material.params.s) - float(clean.material.params.s)) < 0.01
    # One in five: the fit from the seeds finds the rubber too (its seeds collapsed, and it explained
    # nothing, while they were scored with the zeros and started R_d at 0.05: tests/test_dropouts.py).
    y[4::5] = 0.0
    res = fit(data.replace(brdf=y), rubber.structure)
    assert res.converged, res.warnings
    np.testing.assert_allclose(res.material.params.rd, clean.material.params.rd, rtol=0.02)
    assert [w for w in res.warnings if "are exactly 0" in w][0].startswith("systematic residuals: 420 samples (20%) are exactly 0 where the model is not")
    # And one in three (47 % in all): a model that is 0 everywhere is the cheaper fit under the loss; the fit says so, and why.
    y[::3] = 0.0
    res = fit(data.replace(brdf=y), rubber.structure)
    assert not res.converged and res.stats["fit_status"] == "explains_nothing"
    assert any(w.startswith("systematic residuals: ") and f"({np.mean(y == 0):.0%}) are exactly 0" in w for w in res.warnings), res.warnings


def test_a_stray_zero_at_a_bright_sample_keeps_its_band():
    """robust-relative (the default without σ): one dropped sample (brdf 1e-310) where the model is
    bright does not take its band's F0 to 0 (it did, reported converged: its relative residual of
    thousands cost more than the band); for a sample below the floor the model's value over
    ROBUST_CAP floors the relative residual's denominator. Elsewhere the residual is soft-L1's of
    the relative one, and the structured normal equations are the Jacobian's where the cap acts."""
    from types import SimpleNamespace

    from jax.flatten_util import ravel_pytree

    from ctfit._fitting.jacobian import normal_equations
    from ctfit._fitting.losses import RESIDUALS, ROBUST_CAP, ROBUST_SCALE
    from ctfit._fitting.problem import model_values

    wl = np.array([450.0, 550.0, 650.0])
    st = ctfit.Structure(lobes=1, diffuse=None)
    truth = ctfit.Material(st, ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.5, 0.7, 0.9])), wavelength_nm=wl)
    data = simulate(truth, 200, noise=0.02, seed=1).replace(sigma=None)
    y = np.asarray(data.brdf).copy()
    peak = np.flatnonzero(data.band == 0)[np.argmax(y[data.band == 0])]
    y[peak] = 1e-310
    clean, stray = fit(data, st), fit(data.replace(brdf=y), st)
    assert stray.loss == "robust-relative" and stray.converged
    np.testing.assert_allclose(stray.material.params.f0, clean.material.params.f0, rtol=0.01)

    soft_l1 = lambda r: np.sign(r) * np.sqrt(2 * ROBUST_SCALE**2 * (np.sqrt(1 + (r / ROBUST_SCALE) ** 2) - 1))
    # capped only below the floor (a dark sample under a bright model); a sample at or above it keeps its relative residual
    got = RESIDUALS["robust-relative"](SimpleNamespace(floor=0.1), jnp.array([50.0, 0.5, 0.05, 0.0, 5.0]), jnp.array([1e-310, 0.4, 0.06, 0.02, 0.2]))
    np.testing.assert_allclose(got, soft_l1(np.array([ROBUST_CAP * (1 - 1e-310 / 50), 0.25, -0.1, -0.2, 24.0])), rtol=1e-12)

    problem = make_problem(st, data.replace(brdf=y), fixed_params=truth.params, loss="robust-relative")
    u = {k: jnp.asarray(v) for k, v in from_params(problem.spec, truth.params).items()}
    assert float(model_values(problem, u).reshape(-1)[np.argmax(np.asarray(problem.y).reshape(-1) == 1e-310)]) > ROBUST_CAP * float(problem.floor)
    flat, unflat = ravel_pytree(u)
    r, jac = jax.jit(lambda f: (residual(unflat(f), (problem.y, problem)), jax.jacfwd(lambda g: residual(unflat(g), (problem.y, problem)))(f)))(flat)
    cost, grad, hess = jax.jit(lambda uu: normal_equations(problem, uu))(u)
    np.testing.assert_allclose(cost, 0.5 * r @ r, rtol=1e-12)
    np.testing.assert_allclose(grad, jac.T @ r, rtol=1e-9, atol=1e-12 * np.max(np.abs(jac.T @ r)))


def test_every_loss_has_its_residual_in_the_table():
    from ctfit._fitting.losses import LOSSES, RESIDUALS

    assert tuple(RESIDUALS) == LOSSES


def test_a_fit_result_names_its_values_and_errors_alike():
    """``parameters`` and ``parameter_errors``: the fit JSON's names and layout, key for key."""
    import json

    from ctfit import fit_result_to_dict

    mat = ctfit.Material(ctfit.Structure(lobes=2, diffuse="F0/pi"),
                         ctfit.Params(s=np.asarray(0.8), m=np.array([0.1, 0.3]), w=np.array([0.6, 0.4]), f0=np.array([0.5, 0.8])),
                         wavelength_nm=np.array([450.0, 650.0]))
    res = ctfit.fit(ctfit.simulate(mat, 800, noise=0.01, seed=2), ctfit.Structure(lobes=2, diffuse="F0/pi"))
    values, errors = res.parameters, res.parameter_errors
    assert set(values) == {"s", "lobes", "F0", "n"} and set(errors) <= set(values) and {"s", "lobes", "F0"} <= set(errors)
    assert [set(lobe) for lobe in values["lobes"]] == [set(lobe) for lobe in errors["lobes"]] == [{"m", "weight"}] * 2
    assert len(values["F0"]) == len(errors["F0"]) == 2
    assert values["lobes"][0]["m"] < values["lobes"][1]["m"]
    assert abs(values["lobes"][0]["m"] - 0.1) < 5 * errors["lobes"][0]["m"] + 1e-3
    doc = json.loads(json.dumps(fit_result_to_dict(res)))
    assert doc["fit"]["stderr"] == errors and doc["lobes"] == values["lobes"] and doc["F0"] == values["F0"]
    # A plastic's one index (and its F0) is one value in both (its errors were a list, one per band).
    from conftest import ROOT

    rubber = ctfit.load_material(ROOT / "configs" / "rubber.toml")
    res = ctfit.fit(ctfit.simulate(rubber, 200, noise=0.02, seed=1), rubber.structure)
    values, errors = res.parameters, res.parameter_errors
    for name in ("F0", "n", "Rd"):
        assert type(values[name]) is type(errors[name]) and np.size(values[name]) == np.size(errors[name]), name


@pytest.mark.slow
@pytest.mark.parametrize("lobes", [6, 8])  # 8: ctfit._model.MAX_LOBES
def test_every_lobe_count_up_to_max_lobes_fits(lobes):
    """The seed grid has points for every lobe count the structure allows (it had none past 5)."""
    from ctfit._fitting.starts import m_grid
    from ctfit._model import MAX_LOBES

    for j in range(1, MAX_LOBES + 1):
        grid = m_grid(j)
        assert grid.ndim == 2 and grid.shape[0] >= 1 and grid.shape[1] == j and np.all(np.diff(grid, axis=1) > 0)
    st = ctfit.Structure(lobes=2, diffuse=None)
    truth = material(st, WL8[:2], m=np.array([0.1, 0.3]), w=np.array([0.5, 0.5]), f0=np.array([0.6, 0.9]))
    data = simulate(truth, 60, noise=0.01, seed=1)
    res = fit(data, ctfit.Structure(lobes=lobes, diffuse=None), starts=2, max_steps=3)
    assert res.material.structure.lobes == lobes and res.material.params.m.shape == (lobes,)
    assert np.isfinite(res.stats["cost"])
