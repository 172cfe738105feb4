"""Posterior sampling: a known Gaussian posterior, synthetic Cook–Torrance data, priors and their
Jacobians, reproducibility, resuming an interrupted run, the JSON section, plots and the command body.

Small data and short chains; every test of one kind shares the data shapes and structure, so
each log-probability compiles once.
"""

import json
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ctfit
from ctfit._fitting.coordinates import from_params, to_params
from ctfit._fitting.problem import make_problem
from ctfit._model.evaluation import simulate
from ctfit._sampling.chain_diagnostics import ChainTooShortWarning
from ctfit._sampling.draw_colours import draw_colours
from ctfit._sampling.emcee_run import sample
from ctfit._sampling.engine import Engine
from ctfit._sampling.logprob import Layout
from ctfit._sampling.posterior_density import default_walkers
from ctfit._sampling.priors import normalise_priors

WL3 = np.array([450.0, 550.0, 650.0])
WL4 = np.linspace(400.0, 700.0, 4)
NOISE = 0.004  # sr⁻¹, absolute, for the diffuse toy
short = pytest.mark.filterwarnings("ignore::ctfit._sampling.chain_diagnostics.ChainTooShortWarning")


# --- a linear toy with a known Gaussian posterior -----------------------------------------------


@pytest.fixture(scope="module")
def diffuse_toy():
    """Diffuse only, R = R_d(λ) in every direction: the model is linear in R_d.

    With Gaussian noise of known σ and a prior flat in R_d (far from 0), the posterior of each
    R_d(λ) is Gaussian with mean = the band's sample mean and sd = σ/√n_band.
    """
    st = ctfit.Structure(lobes=0, diffuse="spectrum")
    truth = ctfit.Material(st, ctfit.Params(rd=np.array([0.05, 0.08, 0.12])), wavelength_nm=WL3, name="toy")
    base = simulate(truth, 100, seed=3)
    y = base.brdf + NOISE * np.random.default_rng(5).standard_normal(len(base))
    data = base.replace(brdf=y, sigma=np.full(len(base), NOISE))
    n = np.bincount(data.band, minlength=3)
    mean = np.bincount(data.band, weights=y, minlength=3) / n
    return truth, data, mean, NOISE / np.sqrt(n)


@short
def test_linear_gaussian_posterior_mean_and_sd(diffuse_toy):
    """emcee's own acceptance test (emcee/tests/integration/test_proposal.py, ``_test_normal``:
    32 walkers, 2000 steps, |mean| < 0.08 and |sd − 1| < 0.05 for a unit normal, acceptance in
    (0.1, 0.9)), applied to the standardised posterior of R_d(λ)."""
    truth, data, mean, sd = diffuse_toy
    res = sample(truth, data, walkers=32, steps=2000, seed=1, colour=False)
    draws = (res.chain["Rd"] - mean) / sd
    assert np.all(np.abs(draws.mean(axis=0)) < 0.08), draws.mean(axis=0)
    assert np.all(np.abs(draws.std(axis=0) - 1) < 0.05), draws.std(axis=0)
    acc = res.diagnostics["acceptance_fraction"]
    assert 0.1 < acc["min"] and acc["max"] < 0.9
    # Laplace = exact here.
    np.testing.assert_allclose(res.laplace_stderr["Rd"], sd, rtol=1e-3)
    assert res.likelihood["loss"] == "sigma" and "sigma_noise" not in res.chain
    # The summary is the chain's quantiles.
    np.testing.assert_allclose([s["median"] for s in res.summary["Rd"]], np.median(res.chain["Rd"], axis=0))


@short
def test_unknown_noise_scale_is_sampled(diffuse_toy):
    """Without sigma (loss 'absolute'), σ_noise is a parameter: recovered, and R_d's posterior
    (a Student t with ~100 degrees of freedom) still has sd ≈ σ/√n."""
    truth, data, mean, sd = diffuse_toy
    res = sample(truth, data.replace(sigma=None), walkers=32, steps=1500, seed=2, loss="absolute", colour=False)
    assert "sigma_noise" in res.chain and res.labels[-1] == "sigma_noise"
    s = res.summary["sigma_noise"]
    assert s["p2.5"] < NOISE < s["p97.5"]
    draws = (res.chain["Rd"] - mean) / sd
    assert np.all(np.abs(draws.mean(axis=0)) < 0.15)
    assert np.all(np.abs(draws.std(axis=0) - 1) < 0.1)
    assert res.priors["parameters"]["sigma_noise"]["kind"] == "log-uniform"
    assert "σ_noise" in res.likelihood["log_likelihood"]
    assert res.diagnostics["residual_scale_ratio"] < 1.5 and not any(w.startswith("one noise scale") for w in res.warnings)


@short
def test_noise_of_several_scales_is_reported(diffuse_toy):
    """Relative noise (sd ∝ R_d, ×2.4 between bands) with absolute residuals: one σ_noise does
    not fit; the posterior is not usable, and the problem line says why (it read usable, with a
    note). The same data sampled with the relative likelihood has one scale."""
    truth, data, _, _ = diffuse_toy
    clean = np.repeat(truth.params.rd[None], len(data), axis=0)[np.arange(len(data)), data.band]
    noisy = clean * (1 + 0.05 * np.random.default_rng(9).standard_normal(len(data)))
    res = sample(truth, data.replace(brdf=noisy, sigma=None), steps=50, seed=0, loss="absolute", colour=False)
    assert res.diagnostics["residual_scale_ratio"] > 2
    line = next(p for p in res.problems if p.startswith("one noise scale does not fit"))
    assert not res.usable and line in res.warnings and "loss 'absolute'" in line and "'relative'" in line
    other = sample(truth, data.replace(brdf=noisy, sigma=None), steps=50, seed=0, loss="relative", colour=False)
    assert other.diagnostics["residual_scale_ratio"] < 2 and not any(p.startswith("one noise scale") for p in other.problems)


# --- synthetic Cook–Torrance data ---------------------------------------------------------------


@pytest.fixture(scope="module")
def metal():
    st = ctfit.Structure(lobes=1)
    truth = ctfit.Material(st, ctfit.Params(m=np.array([0.25]), w=np.array([1.0]), f0=np.array([0.55, 0.7, 0.85, 0.95])), wavelength_nm=WL4, name="metal")
    data = simulate(truth, 150, noise=0.03, seed=12)
    fitted = ctfit.fit(data, st, starts=1)
    return truth, data, fitted


@short
def test_metal_posterior_covers_truth_and_matches_laplace(metal):
    truth, data, fitted = metal
    assert fitted.converged and fitted.stderr is not None
    res = sample(fitted, data, steps=4000, seed=3, colour=False)  # 50 τ after burn-in: mixed
    ch = res.chain
    sd_m, sd_f0 = ch["m"].std(axis=0), ch["F0"].std(axis=0)
    # Medians within 2σ of the truth.
    assert np.all(np.abs(np.median(ch["m"], axis=0) - truth.params.m) < 2 * sd_m)
    assert np.all(np.abs(np.median(ch["F0"], axis=0) - truth.params.f0) < 2 * sd_f0)
    # Near-Gaussian here: posterior sd within 20 % of the Laplace approximation of the fit.
    np.testing.assert_allclose(sd_m, fitted.stderr["m"], rtol=0.2)
    np.testing.assert_allclose(sd_f0, fitted.stderr["F0"], rtol=0.2)
    # The walkers start at the fit's optimum (no second optimiser), and the Laplace errors are the fit's.
    np.testing.assert_array_equal(res.optimum["m"], fitted.material.params.m)
    np.testing.assert_allclose(res.optimum["F0"], fitted.material.params.f0, rtol=1e-12)
    np.testing.assert_allclose(res.laplace_stderr["F0"], fitted.stderr["F0"], rtol=1e-3)
    assert not any("fitted with loss" in w for w in res.warnings)
    # n is the effective index of each draw's F0.
    np.testing.assert_allclose(ch["n"], (1 + np.sqrt(ch["F0"])) / (1 - np.sqrt(ch["F0"])), rtol=1e-12)
    d = res.diagnostics
    assert d["walkers"] == default_walkers(5) == 32
    assert d["draws"] == 32 * (4000 - d["burn"])
    assert set(d["autocorr_time"]) == set(res.labels) == {"m[0]", "F0[0]", "F0[1]", "F0[2]", "F0[3]"}
    assert all(v > 0 for v in d["ess_emcee"].values())
    assert set(d["ess_bulk"]) == set(d["r_hat"]) == {"m[0]", "F0[0]", "F0[1]", "F0[2]", "F0[3]", "n[0]", "n[1]", "n[2]", "n[3]"}
    assert all(v > 400 for v in d["ess_bulk"].values()) and all(v < 1.05 for v in d["r_hat"].values())
    assert res.usable and res.problems == [] and res.checks["mixing"]["flag"] is False


def test_same_seed_same_chain_and_short_chain_warns(metal):
    truth, data, _ = metal
    with pytest.warns(ChainTooShortWarning, match="50 τ"):
        a = sample(truth, data, steps=60, seed=7, colour=False)
    with pytest.warns(ChainTooShortWarning):
        b = sample(truth, data, steps=60, seed=7, colour=False)
    with pytest.warns(ChainTooShortWarning):
        c = sample(truth, data, steps=60, seed=8, colour=False)
    np.testing.assert_array_equal(a.chain_u, b.chain_u)
    np.testing.assert_array_equal(a.log_prob, b.log_prob)
    assert not np.array_equal(a.chain_u, c.chain_u)
    # Too short to have mixed: not usable, and the first problem (and warning) says how long to run,
    # instead of the note on a short chain that it says again.
    assert a.diagnostics["chain_long_enough"] is False and not a.usable and a.checks["mixing"]["flag"]
    assert a.problems[0] == a.warnings[0] and a.problems[0].startswith("not mixed: ")
    assert f"run at least {a.checks['mixing']['steps_needed']:,} steps in all" in a.problems[0]
    assert a.checks["mixing"]["steps_needed"] > 60 and not any(w.startswith("the chain is too short") for w in a.warnings)
    # A material that is not a fit is fitted first (the same loss as sample() uses), and says so.
    assert any("fitted with loss 'sigma' first, from the material's values" in w for w in a.warnings)


@pytest.mark.filterwarnings("ignore::ctfit._sampling.chain_diagnostics.ChainTooShortWarning")
def test_resume_after_interruption_gives_the_uninterrupted_chain(metal, tmp_path, monkeypatch):
    truth, data, _ = metal
    ref = sample(truth, data, steps=80, seed=4, backend=tmp_path / "ref.h5", colour=False)

    # Interrupt a run after 30 of its 80 steps (a Ctrl-C inside the log-probability).
    path = tmp_path / "run.h5"
    calls = {"n": 0}
    original = Engine.__call__

    def interrupted(self, coords):
        calls["n"] += 1
        if calls["n"] > 1 + 2 * 30:  # the start, then two half-ensemble calls per step
            raise KeyboardInterrupt
        return original(self, coords)

    monkeypatch.setattr(Engine, "__call__", interrupted)
    with pytest.raises(KeyboardInterrupt):
        sample(truth, data, steps=80, seed=4, backend=path, colour=False)
    monkeypatch.setattr(Engine, "__call__", original)

    import emcee

    done = emcee.backends.HDFBackend(str(path), name="ctfit", read_only=True).iteration
    assert 20 < done < 80  # the steps before the interruption are on disk
    res = sample(truth, data, steps=80, seed=4, backend=path, resume=True, colour=False)
    assert res.diagnostics["resumed_from"] == done and res.diagnostics["steps_run_now"] == 80 - done
    assert res.chain_u.shape == ref.chain_u.shape == (80, 32, 5)
    np.testing.assert_array_equal(res.chain_u, ref.chain_u)  # no gap, nothing repeated
    assert emcee.backends.HDFBackend(str(path), name="ctfit", read_only=True).iteration == 80

    # Resuming a finished run runs nothing; other data is refused.
    again = sample(truth, data, steps=80, seed=4, backend=path, resume=True, colour=False)
    assert again.diagnostics["steps_run_now"] == 0
    np.testing.assert_array_equal(again.chain_u, ref.chain_u)
    with pytest.raises(ValueError, match="other data"):
        sample(truth, data.replace(brdf=data.brdf * 1.01), steps=80, backend=path, resume=True, colour=False)
    with pytest.raises(ValueError, match="other data"):  # the same values, another sigma column: another likelihood (it was continued)
        sample(truth, data.replace(sigma=data.sigma / 3), steps=80, seed=4, backend=path, resume=True, colour=False)
    with pytest.raises(ValueError, match="other data"):  # another prior
        sample(truth, data, steps=80, seed=4, backend=path, resume=True, colour=False, priors={"m": ("uniform", 0.1, 0.5)})
    # Another seed is refused: the chain goes on from its own random state, and would be reported with a seed it never had.
    with pytest.raises(ValueError, match=r"started with seed=4, this one asks for seed=5; pass seed=4"):
        sample(truth, data, steps=80, seed=5, backend=path, resume=True, colour=False)


def _stored_steps(path) -> int:
    import emcee

    return int(emcee.backends.HDFBackend(str(path), name="ctfit", read_only=True).iteration)


@short
def test_overwrite_replaces_the_stored_chain_only_when_the_new_one_has_run(metal, tmp_path, monkeypatch):
    """``overwrite=True`` writes the new chain beside the file and moves it over it at the end: a
    run that fails (here its start) or a Ctrl-C before the first step leaves the stored chain as
    it was; a Ctrl-C after some steps leaves the new chain there (resumable); a link is kept."""
    import subprocess
    import sys

    import ctfit._sampling.emcee_run as emcee_run

    truth, data, _ = metal
    real = tmp_path / "chains" / "run.h5"
    real.parent.mkdir()
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True, check=True).stdout.strip()
    stale = real.parent / f".ctfit-{dead}-0123abcd.tmp"  # a temporary that a killed run left
    sample(truth, data, steps=12, seed=4, backend=real, colour=False)
    link = tmp_path / "run.h5"
    link.symlink_to(real)
    real.chmod(0o600)
    before = real.read_bytes()
    stale.write_bytes(b"left by a killed run")

    def hidden():  # the new chain's temporary file (atomic_write's names), if any
        return sorted(real.parent.glob(".ctfit-*.tmp"))

    def fails(*args, **kwargs):
        raise ValueError("could not start every walker")

    for error, raiser in ((ValueError, fails), (KeyboardInterrupt, lambda *a, **k: (_ for _ in ()).throw(KeyboardInterrupt))):
        monkeypatch.setattr(emcee_run, "start_walkers", raiser)
        with pytest.raises(error):
            sample(truth, data, steps=30, seed=5, backend=link, overwrite=True, colour=False)
        monkeypatch.undo()
        assert real.read_bytes() == before and link.is_symlink() and not hidden()  # the stale one swept too

    # A Ctrl-C after 10 of the new run's steps: the new chain is in the file, and resumes.
    calls, original = {"n": 0}, Engine.__call__

    def interrupted(self, coords):
        calls["n"] += 1
        if calls["n"] > 1 + 2 * 10:
            raise KeyboardInterrupt
        return original(self, coords)

    monkeypatch.setattr(Engine, "__call__", interrupted)
    with pytest.raises(KeyboardInterrupt):
        sample(truth, data, steps=30, seed=5, backend=link, overwrite=True, colour=False)
    monkeypatch.setattr(Engine, "__call__", original)
    assert link.is_symlink() and not hidden() and 5 < _stored_steps(real) < 30
    res = sample(truth, data, steps=30, seed=5, backend=link, resume=True, colour=False)
    ref = sample(truth, data, steps=30, seed=5, backend=tmp_path / "ref.h5", colour=False)
    np.testing.assert_array_equal(res.chain_u, ref.chain_u)

    # A whole run replaces it.
    res = sample(truth, data, steps=12, seed=6, backend=link, overwrite=True, colour=False)
    assert _stored_steps(real) == 12 and res.chain_u.shape[0] == 12 and link.is_symlink() and not hidden()
    assert real.stat().st_mode & 0o777 == 0o600  # the file's permissions kept
    assert res.diagnostics["backend"] == str(link)


@short
def test_a_chain_is_started_through_a_link_to_a_file_not_made_yet(metal, tmp_path):
    """A backend that is a symbolic link to a file that does not exist yet gets the chain at its
    target, as ``-o`` does; HDF5 refused it ("Unable to synchronously create file … File exists",
    naming neither the file nor the option)."""
    truth, data, _ = metal
    link = tmp_path / "run.h5"
    link.symlink_to("chains.h5")
    res = sample(truth, data, steps=6, seed=4, backend=link, colour=False)
    assert link.is_symlink() and _stored_steps(tmp_path / "chains.h5") == 6 and res.chain_u.shape[0] == 6
    again = sample(truth, data, steps=8, seed=4, backend=link, resume=True, colour=False)
    assert again.diagnostics["resumed_from"] == 6 and _stored_steps(tmp_path / "chains.h5") == 8


def test_a_new_chain_interrupted_in_the_command_says_what_the_file_holds(tmp_path, monkeypatch):
    """The command's Ctrl-C (its cleanups, ``ctfit._io.interrupt``): a new chain with steps
    replaces the file and the line says so; one without keeps the file and says that."""
    import emcee

    from ctfit._io import interrupt
    from ctfit._sampling.backend import open_run

    for steps_first in (0, 3):
        path = tmp_path / f"run{steps_first}.h5"
        path.write_bytes(b"the chain of before")
        be, done, new = open_run(path, resume=False, overwrite=True, steps=10, shape=(4, 2), fingerprint="f", labels=["a", "b"], seed=0)
        assert done == 0 and new is not None and path.read_bytes() == b"the chain of before"
        assert interrupt.resumable() is None  # nothing to resume yet: the file holds what it held
        if steps_first:
            sampler = emcee.EnsembleSampler(4, 2, lambda x: -0.5 * np.sum(x * x), backend=be)
            sampler.run_mcmc(np.random.default_rng(0).standard_normal((4, 2)), steps_first)
            assert interrupt.resumable() == str(path)
        said = interrupt.run_cleanups()
        if steps_first:
            assert said == [f"{path} now holds the new chain (3 steps)"] and _stored_steps(path) == 3
        else:
            assert said == [f"{path} keeps what it held (the new chain had no step)"] and path.read_bytes() == b"the chain of before"
        assert not list(tmp_path.glob(".ctfit-*.tmp")) and interrupt.run_cleanups() == []


def test_relative_noise_likelihood_is_that_of_noise_proportional_to_the_model(metal):
    """loss 'relative': y_i ~ N(R_i, (σ_noise R_i)²) — scaled by the model R_i(θ), not by the
    data with the fit's floor — checked against a direct evaluation (flat priors: the log-prior
    is the log-Jacobian of m = exp(u), F0 = sigmoid(u); for σ_noise, 1/σ times |dσ/dv| = σ: 0)."""
    from jax.flatten_util import ravel_pytree

    from ctfit._fitting.problem import model_values

    truth, data, _ = metal
    problem = make_problem(truth.structure, data.replace(sigma=None), fixed_params=truth.params, loss="relative", space="unconstrained")
    u0 = {k: jnp.asarray(v) for k, v in from_params(problem.spec, truth.params).items()}
    layout = Layout(("f0", "m"), ((4,), (1,)), True, False, False, relative=True)
    eng = Engine(problem, layout, normalise_priors(None, layout.names, layout.noise), 4)

    rng = np.random.default_rng(1)
    flat0 = np.asarray(ravel_pytree(u0)[0])
    xs = np.concatenate([flat0 + 1e-3 * rng.standard_normal((3, flat0.size)), np.log([[0.02], [0.03], [0.05]])], axis=1)
    for x, lp in zip(xs, eng(xs)):
        u = {"f0": jnp.asarray(x[:4]), "m": jnp.asarray(x[4:5])}
        r_model = np.asarray(model_values(problem, u)).reshape(-1)
        y = np.asarray(problem.y).reshape(-1)
        keep = np.asarray(problem.mask).reshape(-1) > 0
        sd = np.exp(x[-1]) * r_model[keep]
        log_l = np.sum(-np.log(sd) - 0.5 * ((y[keep] - r_model[keep]) / sd) ** 2)
        log_jac = x[4] + np.sum(-np.logaddexp(0, -x[:4]) - np.logaddexp(0, x[:4]))
        np.testing.assert_allclose(lp, log_l + log_jac, rtol=1e-10)


@short
def test_relative_noise_scale_is_not_shrunk_by_the_floor(metal):
    """Relative noise of 3 % (ctfit simulate's), relative loss, no sigma column: two thirds of the
    samples lie below the fit's relative floor. The likelihood scaled by the model recovers
    σ_noise = 0.03 (scaled by max(y, floor) it came out ≈ 0.017, and the intervals too narrow),
    one noise scale fits every residual, and the truth is inside the 95 % intervals."""
    truth, data, _ = metal
    plain = data.replace(sigma=None)
    fitted = ctfit.fit(plain, truth.structure, loss="relative", starts=1)
    res = sample(fitted, plain, steps=400, seed=2, colour=False)
    assert res.likelihood["loss"] == "relative" and "/R_i" in res.likelihood["residual"]
    assert "−Σ log R_i" in res.likelihood["log_likelihood"] and "note" in res.likelihood
    s = res.summary["sigma_noise"]
    assert s["p2.5"] < 0.03 < s["p97.5"] and abs(s["median"] / 0.03 - 1) < 0.15
    assert res.diagnostics["residual_scale_ratio"] < 1.5 and not any(w.startswith("one noise scale") for w in res.warnings)
    for key, true in (("m", truth.params.m), ("F0", truth.params.f0)):
        lo, hi = np.percentile(res.chain[key], [0.5, 99.5], axis=0)
        assert np.all((lo < true) & (true < hi)), (key, lo, hi, true)


# --- priors, Jacobians and lobe order -----------------------------------------------------------


def _engine(material, data, loss, priors=None):
    st = material.structure
    problem = make_problem(st, data, fixed_params=material.params, loss=loss, space="unconstrained")
    u0 = {k: jnp.asarray(v) for k, v in from_params(problem.spec, material.params).items()}
    names = tuple(sorted(u0))
    layout = Layout(names, tuple(np.shape(u0[k]) for k in names), loss != "sigma", st.fresnel == "conductor", st.lobes > 1)
    prior = normalise_priors(priors, layout.names, layout.noise)
    return problem, layout, Engine(problem, layout, prior, 4), u0


def test_log_prior_is_flat_in_the_constrained_parameters(diffuse_toy):
    """log p(u) − log L(u) = log |det ∂θ/∂u| for the default priors, with θ the free constrained
    values (s, m, w_2..w_J, F0): checked against the determinant of jax.jacfwd of the transforms."""
    st = ctfit.Structure(lobes=2, diffuse="F0/pi")
    mat = ctfit.Material(st, ctfit.Params(s=np.asarray(0.6), m=np.array([0.1, 0.3]), w=np.array([0.3, 0.7]), f0=np.array([0.5, 0.6, 0.7])), wavelength_nm=WL3)
    data = diffuse_toy[1]  # any values do: the test is about the prior
    problem, layout, eng, u0 = _engine(mat, data, "sigma")
    from jax.flatten_util import ravel_pytree

    flat0, unravel = ravel_pytree(u0)

    def theta(f):
        p = to_params(problem.spec, unravel(f), problem.fixed)
        return jnp.concatenate([jnp.atleast_1d(p.s), p.m, p.w[1:], p.f0])

    @jax.jit
    def chi2_and_logdet(x):
        r = ctfit._fitting.jacobian.residual(unravel(x), (problem.y, problem))
        return jnp.sum(r * r), jnp.linalg.slogdet(jax.jacfwd(theta)(x))[1]

    rng = np.random.default_rng(0)
    xs = np.asarray(flat0) + 0.3 * rng.standard_normal((4, flat0.size))
    xs = xs[[bool(np.all(np.diff(np.asarray(unravel(jnp.asarray(x))["m"])) > 0)) for x in xs]]
    assert len(xs) >= 2
    lp = eng(xs)
    for x, lp_x in zip(xs, lp):
        chi2, logdet = chi2_and_logdet(jnp.asarray(x))
        np.testing.assert_allclose(lp_x - (-0.5 * float(chi2)), float(logdet), rtol=1e-9, atol=1e-9)
    # Lobes out of order have probability 0.
    swapped = {**u0, "m": u0["m"][::-1]}
    assert eng(np.asarray(ravel_pytree(swapped)[0])[None])[0] == -np.inf


def test_user_priors(diffuse_toy):
    truth, data, mean, sd = diffuse_toy
    problem, layout, eng, u0 = _engine(truth, data, "sigma", {"Rd": ("normal", 0.0, 1.0)})
    _, _, flat_eng, _ = _engine(truth, data, "sigma")
    x = np.log(np.expm1(np.array([[0.05, 0.08, 0.12]])))
    diff = eng(x)[0] - flat_eng(x)[0]
    np.testing.assert_allclose(diff, np.sum(-0.5 * np.array([0.05, 0.08, 0.12]) ** 2), rtol=1e-9)
    # Every prior is cut to the value's physical range (here R_d ≤ 1000 sr⁻¹): proper.
    assert flat_eng(np.array([[x[0, 0], x[0, 1], 1500.0]]))[0] == -np.inf  # softplus(1500) = 1500
    # A uniform prior excludes what it excludes.
    _, _, eng_u, _ = _engine(truth, data, "sigma", {"Rd": ("uniform", 0.0, 0.1)})
    assert eng_u(x)[0] == -np.inf
    with pytest.raises(ValueError, match="not a sampled parameter"):
        _engine(truth, data, "sigma", {"m": ("lognormal", -1.0, 0.5)})
    with pytest.raises(ValueError, match="kind one of"):
        _engine(truth, data, "sigma", {"Rd": ("cauchy", 0.0, 1.0)})
    with pytest.raises(ValueError, match="standard deviation"):
        _engine(truth, data, "sigma", {"rd": ("normal", 0.0, -1.0)})


@short
def test_informative_prior_pulls_the_posterior(metal):
    """A log-normal prior on m as tight as the likelihood: the posterior median lies between the
    two, near the precision-weighted mean (both near-Gaussian in log m)."""
    truth, data, fitted = metal
    m_ls, se = float(fitted.material.params.m[0]), float(fitted.stderr["m"][0])
    centre, width = m_ls * np.exp(3 * se / m_ls), se / m_ls  # prior 3σ above, same width in log m
    res = sample(fitted, data, steps=400, seed=5, colour=False, priors={"m": ("lognormal", float(np.log(centre)), width)})
    med = float(np.median(res.chain["m"]))
    expected = np.exp(0.5 * (np.log(m_ls) + np.log(centre)))
    assert m_ls < med < centre
    assert abs(np.log(med / expected)) < 0.5 * width
    assert res.priors["parameters"]["m"]["kind"] == "lognormal"


# --- output: JSON section, colour, plots, command body ------------------------------------------


@short
def test_uncertainty_section_colour_plots_and_command_body(metal, tmp_path):
    from ctfit._cli.sample_command import sample_command_body
    from ctfit._colour.report import colour_report
    from ctfit._fitting.results import fit_result_to_dict
    from ctfit._io.material_files import load_material, save_material_json
    from ctfit._sampling.plots import plot_corner, plot_spectra
    from ctfit._sampling.table import format_uncertainty_table

    truth, data, fitted = metal
    # The colour of a draw is colour_report's colour of that material.
    opt = {"F0": np.asarray(fitted.material.params.f0)[None]}
    c = draw_colours(fitted.material, opt)
    rep = colour_report(fitted.material)
    np.testing.assert_allclose(c["sRGB"][0], rep["sRGB"], atol=1e-9)
    np.testing.assert_allclose(c["Lab"][0], rep["Lab"], atol=1e-7)

    # The command body: fit JSON in, the same document with an uncertainty section out.
    from ctfit._io.csv_files import write_csv

    csv = tmp_path / "metal.csv"
    write_csv(data, csv)
    fit_json = tmp_path / "metal.fit.json"
    save_material_json(fitted.material, fit_json, extra=fit_result_to_dict(fitted, material_keys=False))
    before = fit_json.read_bytes()
    doc = sample_command_body(fit_json, csv, walkers=None, steps=200, burn=None, thin=2, seed=0, backend=None, resume=False, plot_dir=tmp_path / "plots",
                              output=None)
    assert fit_json.read_bytes() == before  # the input is not written: the result goes beside it
    posterior = tmp_path / "metal.fit.posterior.json"
    on_disk = json.loads(posterior.read_text())
    assert on_disk == doc and on_disk["fit"] == json.loads(before)["fit"]
    assert on_disk["fit"]["loss"] == "sigma" and on_disk["F0"] == json.loads(json.dumps(doc))["F0"]
    u = on_disk["uncertainty"]
    keys = {"median", "p16", "p84"}
    assert keys <= set(u["lobes"][0]["m"]) and keys <= set(u["lobes"][0]["weight"])
    assert len(u["F0"]) == len(u["n"]) == 4 and all(keys <= set(e) for e in u["F0"] + u["n"])
    assert all(e["p16"] <= e["median"] <= e["p84"] for e in u["F0"])
    assert u["diagnostics"]["thin"] == 2 and u["diagnostics"]["walkers"] == 32
    assert u["likelihood"]["model"] == "gaussian" and "F0" in u["priors"]["parameters"]
    assert len(u["colour"]["sRGB"]) == 3 and len(u["colour"]["Lab"]) == 3
    assert [pathlib.Path(p).name for p in u["plots"]] == ["metal.fit.posterior.corner.png", "metal.fit.posterior.spectra.png"]
    for p in u["plots"]:
        assert pathlib.Path(p).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert load_material(posterior).meta["uncertainty"]["diagnostics"]["steps"] == 200
    table = format_uncertainty_table(doc, "metal")
    assert "lobe 0: m =" in table and "τ_max" in table
    assert "priors: uniform in F0 on [0, 1]; uniform in m on [1e-05, 4]" in table
    # 200 steps are about 4 τ: the walkers have not mixed, and the table says so and how long to run.
    assert "posterior: NOT usable" in table and "problem: not mixed: " in table and "steps in all" in table
    # The uncertainty section names the bands it was sampled on (the data's); without them, bands are numbered, not "0 nm".
    assert u["wavelength_nm"] == data.wavelength_nm.tolist()
    assert f"{data.wavelength_nm[0]:g} nm" in format_uncertainty_table({"uncertainty": u}, "metal")
    bare = format_uncertainty_table({"uncertainty": {k: v for k, v in u.items() if k != "wavelength_nm"}}, "metal")
    assert "band 0" in bare and " 0 nm" not in bare

    # Data of two of the fit's four bands: sampled there, and the section says which (it held the
    # data's two entries beside the material's four wavelengths, and the table raised IndexError).
    two = csv.with_name("two.csv")
    keep = data.band < 2
    write_csv(data.replace(**{k: getattr(data, k)[keep] for k in ("theta_i", "phi_i", "theta_o", "phi_o", "band", "brdf", "sigma")},
                           wavelength_nm=data.wavelength_nm[:2]), two)
    doc2 = sample_command_body(fit_json, two, walkers=None, steps=20, burn=None, thin=1, seed=0, backend=None, resume=False, plot_dir=None,
                               output=tmp_path / "two.posterior.json")
    u2 = doc2["uncertainty"]
    assert u2["wavelength_nm"] == data.wavelength_nm[:2].tolist() and len(u2["F0"]) == 2 and doc2["wavelength_nm"] == data.wavelength_nm.tolist()
    assert any(w.startswith("sampled on the data's 2 bands") for w in u2["warnings"])
    table2 = format_uncertainty_table(doc2, "metal")
    assert all(f"{w:g} nm" in table2 for w in data.wavelength_nm[:2]) and f"{data.wavelength_nm[2]:g} nm" not in table2

    # Plots of a result directly (a diffuse-only material has no global parameter but R_d).
    res = sample(truth, data, steps=100, seed=0, colour=False)
    assert plot_corner(res, tmp_path / "c.png").stat().st_size > 1000
    assert plot_spectra(res, tmp_path / "s.png", truth={"F0": truth.params.f0}).stat().st_size > 1000


@pytest.mark.parametrize("steps", [1, 2, 10])
def test_a_short_chain_runs_and_says_it_is_too_short(metal, tmp_path, steps):
    """A few steps (too few for emcee's τ, which is then NaN) give a result, a warning and a table."""
    from ctfit._cli.sample_command import sample_command_body
    from ctfit._fitting.results import fit_result_to_dict
    from ctfit._io.csv_files import write_csv
    from ctfit._io.material_files import save_material_json
    from ctfit._sampling.table import format_uncertainty_table

    _, data, fitted = metal
    csv, fit_json = tmp_path / "metal.csv", tmp_path / "metal.fit.json"
    write_csv(data, csv)
    save_material_json(fitted.material, fit_json, extra=fit_result_to_dict(fitted, material_keys=False))
    with pytest.warns(ChainTooShortWarning, match="too short"):
        doc = sample_command_body(fit_json, csv, walkers=None, steps=steps, burn=None, thin=1, seed=0, backend=None, resume=False,
                                  plot_dir=None, output=None)
    d = doc["uncertainty"]["diagnostics"]
    assert d["steps"] == steps and d["chain_long_enough"] is False
    table = format_uncertainty_table(doc, "metal")
    assert "τ_max" in table and "lobe 0: m =" in table


@short
def test_thin_near_steps_shortens_the_default_burn_in_and_keeps_the_run(metal):
    """``thin`` up to ``steps`` is taken before the run, so the default burn-in leaves it a draw:
    thin=19 of 20 steps ran the whole chain, then was refused ("thin must be at most steps − burn
    = 18"), and the run was lost."""
    truth, data, _ = metal
    res = sample(truth, data, steps=20, thin=19, seed=3, colour=False)
    d = res.diagnostics
    assert d["burn"] == 1 and d["thin"] == 19 and d["draws"] == res.chain["m"].shape[0] == 32


def test_a_fit_file_with_an_unknown_loss_is_refused_naming_its_key(metal, tmp_path):
    """A fit JSON whose ``fit.loss`` is no loss of ctfit was refused as the argument's: "loss must
    be one of …", which the command showed as "--loss must be one of …" with no --loss given and
    no file named."""
    from ctfit._cli.messages import cli_message
    from ctfit._cli.sample_command import sample_command_body
    from ctfit._fitting.results import fit_result_to_dict
    from ctfit._io.csv_files import write_csv
    from ctfit._io.material_files import load_material, save_material_json

    _, data, fitted = metal
    csv, fit_json = tmp_path / "metal.csv", tmp_path / "metal.fit.json"
    write_csv(data, csv)
    extra = fit_result_to_dict(fitted, material_keys=False)
    save_material_json(fitted.material, fit_json, extra={**extra, "fit": {**extra["fit"], "loss": "banana"}})
    with pytest.raises(ValueError, match=r"^key 'fit.loss': 'banana' is not a loss of ctfit \(absolute, .*\); choose the likelihood with loss="):
        sample(load_material(fit_json), data, steps=5, colour=False)
    with pytest.raises(ValueError, match=rf"^{fit_json}: key 'fit.loss': 'banana'") as e:
        sample_command_body(fit_json, csv, steps=5, output=tmp_path / "out.json")
    assert cli_message(str(e.value)).endswith("choose the likelihood with --loss") and not (tmp_path / "out.json").exists()


def test_resume_refuses_an_hdf5_file_without_a_chain(metal, tmp_path):
    """--resume on another program's HDF5 file neither starts a chain inside it nor changes it."""
    import h5py

    _, data, fitted = metal
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["x"] = np.arange(3)
    before = other.read_bytes()
    with pytest.raises(ValueError, match="no chain of ctfit.*name another file .it holds groups 'x', which a new chain would replace"):
        sample(fitted, data, steps=5, backend=other, resume=True, colour=False)
    assert other.read_bytes() == before
    empty = tmp_path / "empty.h5"
    h5py.File(empty, "w").close()  # nothing in it to lose: starting a chain there is offered
    with pytest.raises(ValueError, match=r"no chain of ctfit.*or start a chain in this one \(overwrite=True\)"):
        sample(fitted, data, steps=5, backend=empty, resume=True, colour=False)


@short
def test_resume_names_the_file_of_a_damaged_chain_and_what_differs(metal, tmp_path):
    """A group ``ctfit`` that is not a whole chain (another program's, a damaged file) is refused
    naming the file: HDF5's "can't locate attribute: 'iteration'" named none. A run that samples
    other coordinates (another loss) was told to "pass the same walkers", which it did."""
    import shutil

    import h5py

    _, data, fitted = metal
    good = tmp_path / "good.h5"
    sample(fitted, data, steps=5, seed=0, backend=good, colour=False)
    damage = {
        "empty": lambda f: [f.pop("ctfit"), f.create_group("ctfit")],
        "no_chain": lambda f: f["ctfit"].pop("chain"),
        "past_end": lambda f: f["ctfit"].attrs.__setitem__("iteration", 999),
    }
    for name, harm in damage.items():
        bad = tmp_path / f"{name}.h5"
        shutil.copy(good, bad)
        with h5py.File(bad, "a") as f:
            harm(f)
        with pytest.raises(ValueError, match=rf"^{bad}: the group 'ctfit' holds no chain that can be continued"):
            sample(fitted, data, steps=1000, seed=0, backend=bad, resume=True, colour=False)
    with pytest.raises(ValueError, match=r"samples 5 coordinates, this one 6: it was sampled for another structure, loss or parameters"):
        sample(fitted, data, steps=10, seed=0, backend=good, resume=True, loss="absolute", colour=False)
    with pytest.raises(ValueError, match=r"has 32 walkers, this one 40; pass walkers=32"):
        sample(fitted, data, steps=10, seed=0, walkers=40, backend=good, resume=True, colour=False)


def test_a_new_chain_never_replaces_a_file_with_more_than_ctfits_chain(metal, tmp_path):
    """A new chain is written beside the file and renamed over it: an HDF5 file of the user's (a
    calibration group beside, or instead of, a chain) lost everything else to overwrite=True, which
    the resume error itself suggested. It is refused, and the file kept."""
    import h5py

    truth, data, _ = metal
    lab = tmp_path / "lab.h5"
    with h5py.File(lab, "w") as f:
        f["calibration"] = np.arange(5.0)
    before = lab.read_bytes()
    with pytest.raises(ValueError, match=r"holds no chain of ctfit .* name another file \(it holds groups 'calibration'"):
        sample(truth, data, steps=10, backend=lab, resume=True, colour=False)
    with pytest.raises(ValueError, match=r"holds 'calibration' beside ctfit's chain, which a new chain would replace"):
        sample(truth, data, steps=10, backend=lab, overwrite=True, colour=False)
    text = tmp_path / "notes.h5"
    text.write_text("my notes\n")
    with pytest.raises(ValueError, match="not an HDF5 file"):
        sample(truth, data, steps=10, backend=text, overwrite=True, colour=False)
    assert lab.read_bytes() == before and text.read_text() == "my notes\n"


def test_a_log_ratio_posterior_is_described_and_written(metal):
    """``loss="log-ratio"`` ran the whole chain, then failed (KeyError) describing its likelihood,
    and the CLI lost the fit's JSON with it; every loss the sampler takes has its description."""
    from ctfit._fitting.losses import LOSSES
    from ctfit._sampling.chain_diagnostics import _RESIDUAL

    assert set(LOSSES) - {"robust-relative"} <= set(_RESIDUAL)  # robust-relative is sampled with the relative likelihood
    truth, data, _ = metal
    with pytest.warns(ChainTooShortWarning):
        res = sample(truth, data.replace(sigma=None), steps=30, loss="log-ratio", colour=False)
    assert res.to_dict()["likelihood"]["loss"] == "log-ratio"


def test_a_sigma_column_that_does_not_explain_the_residuals_fails_the_posterior(metal):
    """A sigma column three times too small: χ²/dof ≈ 9, and the intervals, which take it as the
    noise, were too narrow (4 of 8 missed the truth) in a run that read usable. It fails now."""
    truth, data, _ = metal
    small = data.replace(sigma=data.sigma / 3)
    with pytest.warns(ChainTooShortWarning):
        res = sample(truth, small, steps=60, loss="sigma", colour=False)
    problems = res.problems
    assert not res.usable and any("the sigma column does not explain the residuals: χ²/dof = " in p for p in problems), problems
    with pytest.warns(ChainTooShortWarning):
        fine = sample(truth, data, steps=60, loss="sigma", colour=False)
    assert not any("sigma column" in p for p in fine.problems)
