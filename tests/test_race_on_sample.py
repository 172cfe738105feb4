"""A large file's seeds are raced on a random sample of its rows, and only the sample's distinct
winners go on over all the data (ctfit/_fitting/chunked_fit.py: ``race_rows``, ``_race``)."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import ctfit
from ctfit._fitting import chunked_fit
from ctfit._fitting.least_squares import prepare_fit

GOLD = ctfit.Material(ctfit.Structure(lobes=2), ctfit.Params(s=np.asarray(0.8), m=np.array([0.15, 0.4]), w=np.array([0.6, 0.4]),
                                                              f0=np.array([0.6, 0.9])), wavelength_nm=np.array([450.0, 650.0]))


def _pairs(n: int, seed: int) -> ctfit.Measurement:
    """``n`` samples of GOLD, each its own direction pair and one band (the pairs layout), 2 % noise."""
    rng = np.random.default_rng(seed)
    ti, to, po = rng.uniform(0, 75, n), rng.uniform(0, 75, n), 180 + rng.uniform(-60, 60, n)
    band = rng.integers(0, 2, n)
    clean = ctfit.evaluate_at(GOLD, theta_i=ti, theta_o=to, phi_o=po)[np.arange(n), band]
    return ctfit.Measurement(theta_i=ti, phi_i=np.zeros(n), theta_o=to, phi_o=po, band=band, wavelength_nm=GOLD.wavelength_nm,
                             brdf=clean * (1 + 0.02 * rng.standard_normal(n)), source=f"<{n} samples>")


def _prepared(data: ctfit.Measurement, **kw):
    return prepare_fit(data, GOLD.structure, start=None, fixed=(), loss="relative", dtype=jax.numpy.float64, starts=3, chunk=chunked_fit.ROWS, **kw)


def test_the_rows_of_the_race_are_a_sample_of_the_data_and_only_of_a_large_file():
    fewest = chunked_fit.ROWS * chunked_fit.FEWEST_RACE_CHUNKS
    assert chunked_fit.race_rows(_prepared(_pairs(2 * fewest - 1, 1)).problem) is None  # below twice the fewest: raced on all of it
    assert chunked_fit.race_rows(_prepared(_pairs(2 * fewest, 1)).problem).size == fewest  # a small sample of a medium file
    medium = chunked_fit.race_rows(_prepared(_pairs(41 * chunked_fit.ROWS, 1)).problem)
    assert medium.size == chunked_fit.ROWS * (41 // chunked_fit.RACE_SHARE)  # an eighth of the file, in whole chunks
    rows = chunked_fit.ROWS * chunked_fit.RACE_CHUNKS
    assert chunked_fit.race_rows(_prepared(_pairs(chunked_fit.RACE_SHARE * rows - 1, 1)).problem).size < rows  # not yet the most
    problem = _prepared(_pairs(chunked_fit.RACE_SHARE * rows + 5, 1)).problem
    sample = chunked_fit.race_rows(problem)
    assert sample is not None and sample.size == rows and np.all(np.diff(sample) > 0)
    assert np.all(np.asarray(problem.mask)[sample]) and sample[-1] > rows  # data rows only, from all over the file
    np.testing.assert_array_equal(sample, chunked_fit.race_rows(problem))  # the same rows every time (reproducible fits)
    parts = chunked_fit.chunk_problems(problem, rows_of=sample)
    assert len(parts) == chunked_fit.RACE_CHUNKS
    np.testing.assert_array_equal(np.concatenate([np.asarray(p.y) for p in parts]), np.asarray(problem.y)[sample])
    # each sampled sample keeps its own direction pair's geometry (a chunk's ``pair`` None: its own row's)
    assert all(p.pair is None for p in parts)
    theta = np.concatenate([np.asarray(p.geom.cos_l) for p in parts])
    assert problem.pair is None  # every sample its own pair: the geometry is the samples' own, in their order
    np.testing.assert_allclose(theta, np.asarray(problem.geom.cos_l)[sample])


def test_the_race_rows_of_a_grid_are_direction_pairs_with_every_band():
    data = ctfit.simulate(GOLD, n_pairs=40_000, noise=0.01, seed=2)
    problem = _prepared(data).problem
    assert problem.spec.grid
    sample = chunked_fit.race_rows(problem)
    assert sample is not None and np.all(np.asarray(problem.mask)[sample].any(axis=1))
    parts = chunked_fit.chunk_problems(problem, rows_of=sample)
    np.testing.assert_array_equal(np.concatenate([np.asarray(p.y) for p in parts]), np.asarray(problem.y)[sample])
    np.testing.assert_array_equal(np.concatenate([np.asarray(p.geom.cos_l) for p in parts]), np.asarray(problem.geom.cos_l)[sample])


@pytest.mark.parametrize("make", [lambda: _pairs(40_000, 3), lambda: ctfit.simulate(GOLD, n_pairs=20_000, noise=0.02, seed=4), lambda: _pairs(20_000, 5)],
                         ids=["pairs", "grid", "pairs-medium"])
def test_a_race_on_a_sample_ends_where_the_race_on_all_the_data_does(make, monkeypatch):
    data = make()
    sampled = ctfit.fit(data, GOLD.structure, loss="relative")
    assert sampled.stats["race_samples"] >= chunked_fit.ROWS * chunked_fit.FEWEST_RACE_CHUNKS // 2 and sampled.converged
    monkeypatch.setattr(chunked_fit, "FEWEST_RACE_CHUNKS", 10**9)  # every file raced on all its data
    whole = ctfit.fit(data, GOLD.structure, loss="relative")
    assert "race_samples" not in whole.stats and whole.converged
    np.testing.assert_allclose(sampled.stats["cost"], whole.stats["cost"], rtol=1e-8)
    for k in ("m", "w", "f0", "s", "rd"):
        if getattr(whole.material.params, k) is not None:
            np.testing.assert_allclose(getattr(sampled.material.params, k), getattr(whole.material.params, k), rtol=2e-5, atol=1e-7)
    # the steps on all the data: the winner's few from the sample's optimum, against the race's more
    assert sampled.stats["steps"] <= 5 and sampled.stats["steps"] < whole.stats["steps"]


def test_one_start_is_chosen_on_the_sample_and_solved_on_all_the_data(monkeypatch):
    """With one start (no race) the seed's grid scores are summed over the sample's chunks only (a
    fit of 200,000 samples ran every chunk through them: 1.15× the time), and the fit ends where
    the start chosen on all the data ends."""
    data = _pairs(40_000, 6)
    seeded = []
    choose = chunked_fit._seeds
    monkeypatch.setattr(chunked_fit, "_seeds", lambda parts, *a, **k: seeded.append(len(parts)) or choose(parts, *a, **k))
    sampled = ctfit.fit(data, GOLD.structure, loss="relative", starts=1)
    whole_chunks = len(chunked_fit.chunk_problems(_prepared(data).problem))
    assert seeded == [len(chunked_fit.race_rows(_prepared(data).problem)) // chunked_fit.ROWS] and seeded[0] < whole_chunks
    assert "race_samples" not in sampled.stats and sampled.converged  # one seed is not raced: solved on all the data
    monkeypatch.setattr(chunked_fit, "FEWEST_RACE_CHUNKS", 10**9)  # the start chosen on all the data
    whole = ctfit.fit(data, GOLD.structure, loss="relative", starts=1)
    assert seeded[1:] == [whole_chunks]
    np.testing.assert_allclose(sampled.stats["cost"], whole.stats["cost"], rtol=1e-8)
    np.testing.assert_allclose(sampled.material.params.m, whole.material.params.m, rtol=2e-5)


def test_only_the_distinct_winners_of_the_sample_go_on():
    a, b, c = np.zeros(4), np.full(4, 0.5), np.full(4, 1.0)
    near_a = a + 1e-5
    assert chunked_fit._distinct_winners([a, near_a, b], [1.0, 1.0, 1.0]) == [0, 2]  # one point goes on once; another point too
    assert chunked_fit._distinct_winners([a, b, c], [1.0, 1.0 + 0.5 * chunked_fit.RACE_CLOSE, 1.5]) == [0, 1]  # a near tie: both
    assert chunked_fit._distinct_winners([a, b, c], [2.0, 1.0, np.inf]) == [1]  # lowest first; not finite never
    assert chunked_fit._distinct_winners([a, b], [np.inf, np.inf]) == []


def test_seeds_whose_lobes_are_listed_in_another_order_are_one_winner():
    # flat coordinates as ravel_pytree orders them: f0 (2 bands), m (log, 2 lobes), s, w (stick fraction), padded
    u0 = {"f0": np.zeros(2), "m": np.zeros(2), "s": np.zeros(()), "w": np.zeros(1)}
    a = np.array([0.5, 0.6, np.log(0.2), np.log(0.4), 0.9, 0.4, 0.0, 0.0])  # lobes (0.2, w 0.6), (0.4, w 0.4)
    swapped = np.array([0.5, 0.6, np.log(0.4), np.log(0.2), 0.9, 0.6, 0.0, 0.0])  # the same lobes, listed the other way
    other = np.array([0.5, 0.6, np.log(0.4), np.log(0.2), 0.9, 0.4, 0.0, 0.0])  # the same slopes, other weights
    np.testing.assert_allclose(chunked_fit._lobes_in_order(swapped, u0), chunked_fit._lobes_in_order(a, u0))
    assert chunked_fit._distinct_winners([a, swapped, other], [1.0, 1.0, 1.0], u0) == [0, 2]
    assert chunked_fit._distinct_winners([a, swapped], [1.0, 1.0]) == [0, 1]  # without the layout: the coordinates as they are
    one_lobe = {"f0": np.zeros(2), "m": np.zeros(1), "s": np.zeros(())}
    np.testing.assert_array_equal(chunked_fit._lobes_in_order(a[:4], one_lobe), a[:4])


def test_a_race_whose_winners_differ_in_the_order_of_their_lobes_goes_on_once(monkeypatch):
    data = _pairs(40_000, 3)
    u0 = _prepared(data).u0
    at = np.cumsum([0] + [int(np.size(u0[k])) for k in sorted(u0)])
    m, w = (slice(at[i], at[i + 1]) for i in (sorted(u0).index("m"), sorted(u0).index("w")))
    seeds = chunked_fit._seeds

    def mirrored(*args):  # two seeds: the first, and it with its two lobes listed the other way
        out = seeds(*args)
        flat = np.array(out["flat"][:2])
        flat[1] = flat[0]
        flat[1, m], flat[1, w] = flat[0, m][::-1], 1 - flat[0, w]
        return dict(out, flat=flat)

    monkeypatch.setattr(chunked_fit, "_seeds", mirrored)
    runs = _full_runs(monkeypatch)
    seen = []
    distinct = chunked_fit._distinct_winners
    monkeypatch.setattr(chunked_fit, "_distinct_winners", lambda values, costs, u0=None: seen.append(values) or distinct(values, costs, u0))
    out = _core(data)
    (values,) = seen
    assert not np.allclose(values[1], values[0], rtol=1e-2, atol=1e-2)  # the race ends with its lobes the other way ...
    np.testing.assert_allclose(values[1][m], values[0][m][::-1], rtol=1e-6)  # ... at the same point
    assert len(runs) == 1 and np.isfinite(out["costs"]).sum() == 1 and out["costs"].size == 2  # one of the two goes on


def _full_runs(monkeypatch) -> list[int]:
    """Spy: the steps of every run over all the data (more chunks than the race's sample)."""
    runs, run = [], chunked_fit._Kernels.run

    def spy(self, *args):
        out = run(self, *args)
        if len(self.parts) > chunked_fit.RACE_CHUNKS:  # (the files here race on fewer chunks)
            runs.append(out[2])
        return out

    monkeypatch.setattr(chunked_fit._Kernels, "run", spy)
    return runs


def _core(data: ctfit.Measurement) -> dict:
    prep = _prepared(data)
    parts = chunked_fit.chunk_problems(prep.problem)
    race = chunked_fit.chunk_problems(prep.problem, rows_of=chunked_fit.race_rows(prep.problem))
    return chunked_fit.chunked_core(prep.problem, prep.u0, prep.grid, prep.k, 256, False, parts=parts, race_parts=race)


def test_seeds_at_one_point_go_on_once_and_a_near_tie_is_decided_on_all_the_data(monkeypatch):
    data = _pairs(40_000, 5)
    runs = _full_runs(monkeypatch)
    once = _core(data)
    assert len(runs) == 1 and np.sum(np.isfinite(once["costs"])) == 1  # the three seeds met on the sample: one goes on
    assert once["race_samples"] == chunked_fit.ROWS * chunked_fit.FEWEST_RACE_CHUNKS  # 40,000 samples (19 chunks): the smallest sample
    runs.clear()
    monkeypatch.setattr(chunked_fit, "SAME_POINT", 0.0)  # every seed its own point, all within RACE_CLOSE: all go on
    every = _core(data)
    assert len(runs) == 3 and np.all(np.isfinite(every["costs"])) and every["best"] == int(np.argmin(every["costs"]))
    np.testing.assert_allclose(np.min(every["costs"]), np.min(once["costs"]), rtol=1e-8)
