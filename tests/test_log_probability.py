"""The log-probability factory (ctfit._sampling.posterior_density): the density ``ctfit.sample``
hands to emcee, its coordinates' names and the fit's optimum in them."""

import numpy as np
import pytest

import ctfit
from ctfit._sampling.emcee_run import sample
from ctfit._sampling.posterior_density import log_probability

WL = np.array([450.0, 550.0, 650.0])


@pytest.fixture(scope="module")
def metal():
    """A one-lobe metal, 3 % relative noise without a sigma column (the noise scale is sampled), and its fit."""
    st = ctfit.Structure(lobes=1)
    truth = ctfit.Material(st, ctfit.Params(m=np.array([0.25]), w=np.array([1.0]), f0=np.array([0.6, 0.75, 0.9])), wavelength_nm=WL)
    data = ctfit.simulate(truth, 80, noise=0.03, seed=2).replace(sigma=None)
    return data, ctfit.fit(data, st, loss="relative", starts=1)


@pytest.mark.filterwarnings("ignore::ctfit._sampling.chain_diagnostics.ChainTooShortWarning")
def test_the_values_are_those_the_sampler_recorded(metal):
    data, fitted = metal
    lp = log_probability(fitted, data)
    res = sample(fitted, data, steps=40, burn=0, seed=1, colour=False)
    assert lp.labels == res.labels == ["F0[0]", "F0[1]", "F0[2]", "m[0]", "sigma_noise"] and lp.ndim == 5
    np.testing.assert_allclose(lp(res.chain_u[-1]), res.log_prob[-1], rtol=1e-12)  # emcee's walkers, emcee's values
    # The optimum: where the walkers started, the fit's constrained optimum in sampling coordinates.
    assert np.isfinite(lp(lp.optimum[None])[0])
    np.testing.assert_allclose(np.exp(lp.optimum[3]), res.optimum["m"][0], rtol=1e-12)
    np.testing.assert_allclose(1 / (1 + np.exp(-lp.optimum[:3])), res.optimum["F0"], rtol=1e-12)
    np.testing.assert_allclose(np.exp(lp.optimum[4]), res.optimum["sigma_noise"], rtol=1e-12)
    assert lp.loss == "relative" and lp.material is fitted.material


def test_priors_and_walkers_are_the_samplers(metal):
    """A normal prior on m adds its log-density in m = exp(u) at every point; the walkers are checked."""
    data, fitted = metal
    flat, informed = log_probability(fitted, data), log_probability(fitted, data, priors={"m": ("normal", 0.3, 0.05)})
    xs = flat.optimum + np.array([[0.0] * 5, [0.0, 0.0, 0.0, 0.1, 0.0]])
    m = np.exp(xs[:, 3])
    np.testing.assert_allclose(informed(xs) - flat(xs), -0.5 * ((m - 0.3) / 0.05) ** 2 - np.log(0.05), rtol=1e-10)
    with pytest.raises(ValueError, match="walkers must be even"):
        log_probability(fitted, data, walkers=7)


def test_data_on_the_same_directions_share_one_compiled_log_probability(monkeypatch):
    """The geometry is compiled in, the data values are arguments: other values on the same
    directions reuse the program (kept by the runtime, :mod:`ctfit._runtime.stored_programs`),
    other directions compile another."""
    from ctfit._runtime import stored_programs

    monkeypatch.setattr(stored_programs, "_memory", {})
    st = ctfit.Structure(lobes=1)
    params = ctfit.Params(m=np.array([0.3]), w=np.array([1.0]), f0=np.array([0.5, 0.7, 0.8]))
    as_fit = ctfit.Material(st, params, wavelength_nm=WL, meta={"fit": {"loss": "sigma"}})  # sampled as it is, no fit
    data = ctfit.simulate(as_fit, 40, noise=0.02, seed=0)
    first = log_probability(as_fit, data)
    other_values = log_probability(as_fit, data.replace(brdf=data.brdf * 1.05))

    def kept():
        return [k for k in stored_programs._memory if k.startswith("sample_log_prob-")]

    assert len(kept()) == 1
    x = first.optimum[None]
    assert np.isfinite(first(x)[0]) and first(x)[0] != other_values(x)[0]
    log_probability(as_fit, ctfit.simulate(as_fit, 50, noise=0.02, seed=0))  # other directions
    assert len(kept()) == 2
