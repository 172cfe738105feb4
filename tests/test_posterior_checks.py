"""The verdicts on a posterior (is it usable?), the priors' support, and the corner plot's axes:
small known inputs, no sampling."""

import jax.numpy as jnp
import numpy as np
import pytest

from ctfit._sampling.checks import check_posterior, fit_distance, steps_needed
from ctfit._sampling.plots import _central_ranges
from ctfit._sampling.priors import describe_priors, log_prior, normalise_priors, support


def test_default_priors_are_proper_and_physical():
    prior = normalise_priors(None, ("f0", "m", "rd", "s", "w"), noise=True)
    assert [p[0] for p in prior] == ["f0", "m", "rd", "s", "w", "sigma_noise"]
    assert support("m") == (1e-5, 4.0) and support("n") == (1.0, 1e3) and support("n", "conductor") == (0.0, 1e3)
    desc = describe_priors(prior, (), "f0", True)["parameters"]
    assert desc["m"]["range"] == "[1e-05, 4]" and desc["weight"]["density"].startswith("uniform on the simplex")
    assert all(e["proper"] for e in desc.values())
    # −∞ outside the support, whatever the kind; a narrower uniform cuts further.
    m = jnp.asarray([0.1, 5.0])
    assert log_prior("flat", (), m, 1e-5, 4.0) == -jnp.inf and log_prior("flat", (), m[:1], 1e-5, 4.0) == 0.0
    assert log_prior("uniform", (0.2, 0.3), m[:1], 1e-5, 4.0) == -jnp.inf
    with pytest.raises(ValueError, match="lo must be < hi"):
        normalise_priors({"m": ("uniform", 0.5, 0.1)}, ("m",), noise=False)


def test_corner_ranges_are_central_quantiles_with_the_rest_noted():
    rng = np.random.default_rng(0)
    data = np.column_stack([rng.normal(0.3, 0.01, 10_000), rng.normal(0.5, 0.02, 10_000)])
    data[:20, 0] = 2.4e5  # a far tail
    ranges, outside = _central_ranges(data)
    assert ranges[0][1] < 1 and ranges[1][0] > 0.4
    assert 0.002 <= outside <= 0.03


def test_checks_on_known_draws():
    """A Gaussian well inside its prior is usable; draws piled at s = 0, or spread over F0's whole
    range, or an optimum where no draw is, are each one plain line."""
    rng = np.random.default_rng(1)
    prior = (("f0", "flat", ()), ("s", "flat", ()))
    good = {"F0": rng.normal(0.5, 0.01, (4000, 1)), "s": rng.normal(0.5, 0.01, 4000)}
    lp = -0.5 * ((good["s"] - 0.5) / 0.01) ** 2
    ok = check_posterior(good, prior, "f0", lp, 0.0, {"F0": [0.5], "s": 0.5})
    assert ok["usable"] and ok["problems"] == []
    bad = {"F0": rng.uniform(0, 1, (4000, 1)), "s": np.abs(rng.normal(0, 0.01, 4000))}
    res = check_posterior(bad, prior, "f0", lp, -1e3, {"F0": [0.5], "s": 0.5})
    assert not res["usable"] and len(res["problems"]) == 3
    assert res["problems"][0].startswith("left the fit") and "s runs to 0" in res["problems"][1] and "F0[0]" in res["problems"][2]


@pytest.mark.parametrize(("steps", "burn", "tau"), [(400, 399, float("nan")), (2000, 1000, 60.0), (2000, 1500, 20.0), (300, 30, 5.0)])
def test_steps_needed_keeps_fifty_tau_after_the_runs_own_burn_in(steps, burn, tau):
    """The steps the mixing line asks for keep 50 τ after the burn-in that run used: with
    ``--burn 399`` of 400 steps it asked for 410 (11 kept, so the next run failed again)."""
    need = steps_needed(steps, burn, tau, float("nan"))
    assert need - burn >= 50 * (tau if np.isfinite(tau) else 1.0) and need > steps


def test_fit_distance_counts_the_fits_own_noise():
    """D² of a point from Gaussian draws: ≈ d²/σ² alone, halved when the fit's variance equals the
    posterior's; the limit is the χ² 99 % point (6.63 for one coordinate)."""
    draws = np.random.default_rng(2).normal(0.0, 1.0, (20_000, 1))
    d2, limit = fit_distance(draws, np.array([4.0]), np.zeros((1, 1)))
    assert abs(d2 - 16) < 1 and abs(limit - 6.635) < 0.01
    d2_both, _ = fit_distance(draws, np.array([4.0]), np.eye(1))
    assert abs(d2_both - 8) < 0.5


def test_arviz_diagnostics_of_a_short_chain_print_nothing(capfd):
    """Fewer than four draws per walker: ArviZ's ESS and R̂ are NaN (reported as not computed),
    and its "Shape validation failed" lines no longer reach stderr above the table; its log
    level is as it was after."""
    from ctfit._sampling.arviz_export import arviz, diagnostics, inference_data

    log = arviz()._log
    before = log.level
    rng = np.random.default_rng(1)
    idata = inference_data({"m": rng.random((3 * 32, 1)), "s": rng.random(3 * 32)}, rng.random(3 * 32), 32, [550.0])
    got = diagnostics(idata)
    assert set(got) == {"m[0]", "s"} and all(np.isnan(v["r_hat"]) for v in got.values())
    assert "Shape validation" not in capfd.readouterr().err
    assert log.level == before
