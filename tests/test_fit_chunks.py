"""A large grid is summed chunk by chunk (cost, Jᵀr, JᵀJ, seed scores, the residual summary):
the same numbers as all at once, and the compiled fit's temporaries stay chunk-sized."""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ctfit
from ctfit._fitting import chunks as _chunks, fit_report, least_squares as _fit
from ctfit._fitting.chunks import CHUNK, bucket
from ctfit._fitting.jacobian import half_squared_norm, normal_equations
from ctfit._fitting.problem import make_problem

SMALL_CHUNK = 64


def _grid(pairs: int, seed: int = 0):
    """A spectral grid (every pair × 3 bands) of a one-lobe material with a diffuse part, 1 % noise."""
    rng = np.random.default_rng(seed)
    ti, to = rng.uniform(0, 80, pairs), rng.uniform(0, 80, pairs)
    pi, po = rng.uniform(0, 360, pairs), rng.uniform(0, 360, pairs)
    rep = lambda a: np.repeat(a, 3)
    wl = np.array([450.0, 550.0, 650.0])
    geometry = ctfit.Measurement(theta_i=rep(ti), phi_i=rep(pi), theta_o=rep(to), phi_o=rep(po), band=np.tile(np.arange(3), pairs),
                                 wavelength_nm=wl)
    truth = ctfit.Material(ctfit.Structure(lobes=1), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.9, 0.6, 0.4])),
                           wavelength_nm=wl)
    values = ctfit.evaluate(truth, geometry) * (1 + 0.01 * rng.standard_normal(len(geometry)))
    return geometry.replace(brdf=values)


def _fresh_fit_core():
    """The fit program traced anew (equinox keeps one trace per function, whatever ``CHUNK`` is)."""
    return eqx.filter_jit(lambda *a: _fit.fit_core(*a))


@pytest.fixture
def small_chunks(monkeypatch):
    monkeypatch.setattr(_chunks, "CHUNK", SMALL_CHUNK)


def _problem_and_start(data, loss="relative"):
    rows = 48 * SMALL_CHUNK  # samples of the pairs layout (and pairs: at least as many)
    pad_to = (16 * SMALL_CHUNK, rows) if len(data.directions()[0]) <= 16 * SMALL_CHUNK else (rows, rows)
    return _fit.prepare_fit(data, ctfit.Structure(lobes=1), start=None, fixed=(), loss=loss, dtype=jnp.float64, starts=3, pad_to=pad_to)


def _scattered(samples: int, seed: int = 1):
    """Every sample its own direction pair (the pairs layout), 3 bands, a few pairs shared."""
    data = _grid(samples, seed)  # pairs × 3 bands; keep one band of most pairs
    keep = (np.arange(len(data)) % 3 == np.repeat(np.arange(samples) % 3, 3)) | (np.arange(len(data)) < 12)
    return data.replace(**{k: getattr(data, k)[keep] for k in ("theta_i", "phi_i", "theta_o", "phi_o", "band", "brdf")})


@pytest.mark.parametrize("loss", ["relative", "log"])
@pytest.mark.parametrize("layout", ["grid", "pairs"])
def test_chunked_sums_equal_the_whole(small_chunks, loss, layout):
    data = _grid(16 * SMALL_CHUNK - 5) if layout == "grid" else _scattered(16 * 3 * SMALL_CHUNK - 40)
    prep = _problem_and_start(data, loss)
    problem, u = prep.problem, dict(prep.u0, m=jnp.log(jnp.array([0.3])))
    assert problem.spec.grid == (layout == "grid") and _chunks.chunk_count(problem) == (16 if layout == "grid" else 48)
    chunked = (jax.jit(half_squared_norm)(problem, u), *jax.jit(normal_equations)(problem, u))
    _chunks.CHUNK = 10**9  # the same problem, summed at once
    assert _chunks.chunk_count(problem) == 1
    at_once = (jax.jit(half_squared_norm)(problem, u), *jax.jit(normal_equations)(problem, u))
    for a, b in zip(chunked, at_once):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(chunked[0], chunked[1], rtol=1e-12)  # the cost of both routes


def test_samples_each_with_their_own_pair_sum_as_with_their_pairs_gathered(small_chunks):
    """The fit's chunks hold each sample's own pair's geometry (``pair`` None: nothing gathered or
    summed per pair): the same cost, Jᵀr and JᵀJ as the layout that gathers it, summed chunk by
    chunk or at once."""
    prep = _problem_and_start(_scattered(16 * 3 * SMALL_CHUNK - 40))
    problem, u = prep.problem, dict(prep.u0, m=jnp.log(jnp.array([0.3])))
    own = dataclasses.replace(problem, geom=jax.tree.map(lambda a: np.asarray(a)[np.asarray(problem.pair)], problem.geom), pair=None)
    gathered = (jax.jit(half_squared_norm)(problem, u), *jax.jit(normal_equations)(problem, u))
    assert _chunks.chunk_count(own) == 48
    chunked = (jax.jit(half_squared_norm)(own, u), *jax.jit(normal_equations)(own, u))
    _chunks.CHUNK = 10**9
    at_once = (jax.jit(half_squared_norm)(own, u), *jax.jit(normal_equations)(own, u))
    for a, b, c in zip(gathered, chunked, at_once):
        np.testing.assert_allclose(b, a, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(c, a, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("pad", [False, True])
def test_samples_of_distinct_pairs_are_laid_out_each_with_its_own_pair(pad):
    """Scattered data (every sample its own direction pair) gets ``pair`` None and the geometry
    in the samples' order, padded as they are; data whose pairs are shared keeps its index."""
    data = _grid(300, 3)
    one = data.replace(**{k: getattr(data, k)[::3] for k in ("theta_i", "phi_i", "theta_o", "phi_o", "band", "brdf")})
    problem = make_problem(ctfit.Structure(lobes=1), one, fixed_params=ctfit.Params(), pad=pad)
    assert not problem.spec.grid and problem.pair is None
    assert problem.geom.cos_vh.shape == problem.y.shape == ((bucket(300),) if pad else (300,))
    own = ctfit.geometry_from_angles_deg(one.theta_i, one.phi_i, one.theta_o, one.phi_o)  # every sample's, in order
    np.testing.assert_allclose(np.asarray(problem.geom.cos_vh)[:300], np.asarray(own.cos_vh), rtol=1e-12)
    np.testing.assert_array_equal(np.asarray(problem.y)[:300], one.brdf)
    shared = _scattered(600)  # a few pairs hold two samples
    assert make_problem(ctfit.Structure(lobes=1), shared, fixed_params=ctfit.Params()).pair is not None


@pytest.mark.parametrize("layout", ["grid", "pairs"])
def test_chunked_fit_equals_the_whole_fit(small_chunks, layout):
    prep = _problem_and_start(_grid(16 * SMALL_CHUNK - 5) if layout == "grid" else _scattered(16 * 3 * SMALL_CHUNK - 40))
    rows = 16 if layout == "grid" else 48
    args = (prep.u0, prep.grid, *prep.options("lm", 256))
    chunked = jax.device_get(_fresh_fit_core()(prep.problem, *args))
    _chunks.CHUNK = 10**9
    whole = jax.device_get(_fresh_fit_core()(prep.problem, *args))
    cols = (3,) if layout == "grid" else ()
    assert chunked["rel"].shape == (rows, SMALL_CHUNK, *cols) and whole["rel"].shape == (1, rows * SMALL_CHUNK, *cols)
    np.testing.assert_allclose(chunked["costs"], whole["costs"], rtol=1e-9)
    for key in ("rmse", "rel_rmse", "zero_cost"):
        np.testing.assert_allclose(chunked[key], whole[key], rtol=1e-12)
    np.testing.assert_allclose(chunked["rel"].reshape(-1), whole["rel"].reshape(-1), rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(chunked["params"]["m"], whole["params"]["m"], rtol=1e-9)
    assert int(chunked["bad"]) == int(whole["bad"]) == 0


def test_the_fit_program_s_temporaries_do_not_grow_with_the_data(small_chunks):
    """XLA's own account of the compiled fit: on a grid of 64 chunks its temporary memory is a
    fraction of its inputs (all at once, it is larger than them)."""
    prep = _fit.prepare_fit(_grid(64 * SMALL_CHUNK - 7), ctfit.Structure(lobes=1, diffuse=None), start=None, fixed=(), loss="relative",
                         dtype=jnp.float64, starts=3, pad_to=(64 * SMALL_CHUNK, 3 * 64 * SMALL_CHUNK))

    def memory():
        lowered = _fresh_fit_core().lower(prep.problem, prep.u0, prep.grid, *prep.options("lm", 256))
        return lowered.compile().compiled.memory_analysis()

    chunked = memory()
    _chunks.CHUNK = 10**9
    whole = memory()
    assert chunked.temp_size_in_bytes < 0.5 * chunked.argument_size_in_bytes < whole.temp_size_in_bytes
    assert chunked.temp_size_in_bytes < 0.25 * whole.temp_size_in_bytes


def test_large_buckets_are_whole_chunks_and_pad_little():
    for n in (2**18 + 1, 1_096_216, 3_288_648, 4_500_000, 2**21 - 1, 2**21):
        b = bucket(n)
        assert b % CHUNK == 0 and n <= b <= 1.125 * n and bucket(b) == b
    assert bucket(2**18) == 2**18  # the √2 buckets up to there


def test_cos_theta_i_is_kept_only_for_the_losses_that_weight_by_it():
    data = _grid(40)
    for loss, kept in (("relative", False), ("absolute", False), ("cosine", True), ("log", True)):
        p = make_problem(ctfit.Structure(lobes=1), data, fixed_params=ctfit.Params(), loss=loss)
        assert (p.cos_i is not None) == kept


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_the_rms_of_chunks_does_not_overflow(dtype):
    """The fit's rmse from per-chunk (max|e|, Σ (e/max|e|)²): the rms of all, without squaring
    values near the dtype's largest, NaN where a value is not finite, 0 for no error."""
    big = 1e30 if dtype == jnp.float32 else 1e200

    def rms(chunks, xp=jnp):
        parts = [fit_report._scaled_squares(jnp.asarray(c, dtype)) for c in chunks]
        big_, sq = (xp.asarray(np.stack([np.asarray(p[i]) for p in parts])) for i in (0, 1))
        return float(fit_report.combined_rms(big_, sq, sum(len(c) for c in chunks), xp=xp))

    for xp in (jnp, np):  # in a program, and on the host (the fit on chunks)
        assert rms([[big, -big], [0.0, 0.0]], xp) == pytest.approx(big / np.sqrt(2), rel=1e-6)
        assert rms([[3.0], [4.0]], xp) == pytest.approx(np.sqrt(12.5), rel=1e-6)
        assert rms([[0.0, 0.0], [0.0]], xp) == 0.0
        with np.errstate(invalid="ignore"):
            assert np.isnan(rms([[1.0, np.inf], [2.0]], xp)) and np.isnan(rms([[1.0], [np.nan]], xp))


@pytest.mark.parametrize("chunks", [1, 7, 16, 33])
def test_chunk_sums_add_in_one_order_with_threads_or_without(chunks, monkeypatch):
    """A pass over many chunks runs as two chains side by side (the normal equations, the seeds'
    scores), over fewer as one; the additions are the same with or without the threads, and on
    a one-core machine. What a program returns beyond its sums (``fit_ne``: the chunk's model
    values) comes back per chunk, in the chunks' order."""
    from ctfit._fitting import chunked_fit

    rng = np.random.default_rng(chunks)
    parts = [[jnp.asarray(rng.standard_normal(5) * 10.0 ** rng.integers(-8, 8))] for _ in range(chunks)]
    add = jax.jit(lambda total, count, x: [total + x, count + 1.0, 2 * x])
    zeros = [jnp.zeros(5), jnp.zeros(())]
    threads = chunked_fit.chunk_sums(add, zeros, parts, [])
    alone = chunked_fit.chunk_sums(add, zeros, parts, [], side_by_side=False)
    monkeypatch.setattr(chunked_fit, "_sum_pool", [None])  # one core: no threads
    one_core = chunked_fit.chunk_sums(add, zeros, parts, [])
    for got in (alone, one_core):
        np.testing.assert_array_equal(np.asarray(got[0][0]), np.asarray(threads[0][0]))
    assert float(threads[0][1]) == chunks
    half = -(-chunks // 2)
    halves = [parts[:half], parts[half:]] if chunks >= chunked_fit.SPLIT_CHUNKS else [parts]
    want = sum(sum((np.asarray(p[0]) for p in h), np.zeros(5)) for h in halves)
    np.testing.assert_array_equal(np.asarray(threads[0][0]), want)  # first half, then the second, added
    for got in (threads, alone, one_core):
        assert len(got[1]) == chunks
        for (kept,), (x,) in zip(got[1], parts):
            np.testing.assert_array_equal(np.asarray(kept), 2 * np.asarray(x))


@pytest.mark.parametrize("layout", ["grid", "pairs"])
def test_chunks_sent_through_the_transfer_program_are_those_sent_one_by_one(layout):
    """The chunks after the first go to the device through one compiled call each
    (``chunk_put``), placed in the first chunk's problem by their position among its leaves: the
    same problems, array for array, as ``jax.device_put`` and a problem made for each chunk."""
    from ctfit._fitting import chunked_fit

    data = _grid(3 * chunked_fit.ROWS // 2) if layout == "grid" else _scattered(3 * chunked_fit.ROWS + 7)
    prep = _fit.prepare_fit(data, ctfit.Structure(lobes=1), start=None, fixed=(), loss="log", dtype=jnp.float64, starts=1,
                            chunk=chunked_fit.ROWS)
    sent = chunked_fit.chunk_problems(prep.problem)
    assert len(sent) >= 2
    rows = sent[0].y.shape[0]
    for c, part in enumerate(sent):
        one = chunked_fit.chunk_problems(dataclasses.replace(prep.problem, **_rows_from(prep.problem, c * rows, rows)), limit=1)[0]
        assert jax.tree.structure(part) == jax.tree.structure(one) and part.spec == one.spec
        for x, y in zip(jax.tree.leaves(part), jax.tree.leaves(one)):
            assert isinstance(x, jax.Array) and x.dtype == y.dtype
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert not np.array_equal(np.asarray(sent[0].y), np.asarray(sent[1].y))  # each chunk its own rows


def _rows_from(problem, start: int, rows: int) -> dict:
    """The fields of ``problem`` cut to ``rows`` rows from ``start``: a problem whose first chunk is that chunk."""
    cut = lambda a: None if a is None else np.asarray(a)[start: start + rows]
    fields = {k: cut(getattr(problem, k)) for k in ("y", "sigma", "cos_i", "mask")}
    if problem.spec.grid or problem.pair is None:
        fields["geom"] = jax.tree.map(cut, problem.geom)
    else:
        fields["pair"] = cut(problem.pair)
    if not problem.spec.grid:
        fields["band"] = cut(problem.band)
    return fields


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_the_fit_s_geometry_on_the_host_is_the_model_s(dtype):
    """A fit lays out its pairs' geometry on the host, in NumPy (``problem.geometry_deg``, a
    block at a time: no program to make), with the model's own functions
    (:func:`~ctfit.geometry_from_angles_deg` with ``xp=numpy``): the values and dtypes of the
    traced geometry, below the horizon and at grazing angles too."""
    from ctfit._fitting import problem as problem_module

    rng = np.random.default_rng(3)
    pairs = rng.uniform([0, -30, 0, -30], [95, 400, 95, 400], (5000, 4))
    pairs[:50, 2] = 90.0  # on the horizon
    pairs[50:100, 0] = 89.999
    pairs = pairs.astype(dtype)
    want = jax.jit(lambda p: ctfit.geometry_from_angles_deg(p[:, 0], p[:, 1], p[:, 2], p[:, 3]))(pairs)
    for block in (5000, 1024):  # one block, and several
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(problem_module, "GEOMETRY_BLOCK", block)
            mp.setattr(problem_module, "_recent_geometry", {})
            got = problem_module.geometry_deg(pairs, on_host=True)
        for f in ("cos_l", "cos_v", "sin_l", "sin_v", "cos_h", "tan2_h", "cos_vh", "valid"):
            g, w = getattr(got, f), np.asarray(getattr(want, f))
            assert isinstance(g, np.ndarray) and g.dtype == w.dtype and g.shape == (5000,), f
            if f == "valid":
                np.testing.assert_array_equal(g, w)
                assert not g[:50].any() and g[50:].sum() > 3000
            else:
                np.testing.assert_allclose(g, w, rtol=1e-13 if dtype == np.float64 else 2e-5, atol=1e-15 if dtype == np.float64 else 1e-6, err_msg=f)
                assert np.all(np.isfinite(g)), f


@pytest.mark.parametrize("cols", [(), (3,)])
def test_the_host_summary_is_the_same_whatever_the_cells_summarised_at_once(monkeypatch, cols):
    """The chunked fit's residual summary (``chunked_fit._summary``, filled in place a group of
    chunks at a time) gives the same numbers a few chunks at a time as all at once, in the
    layout's order, a cell whose value is not finite counted."""
    from types import SimpleNamespace

    import ctfit._fitting.chunked_fit as chunked_fit

    rng = np.random.default_rng(5)
    rows, count = 8, 7
    y = rng.uniform(0.1, 2.0, (rows * count, *cols))
    values = [y[c * rows: (c + 1) * rows] * rng.uniform(0.9, 1.1, (rows, *cols)) for c in range(count)]
    values[3][2] = np.inf
    mask = np.ones(y.shape, bool)
    mask[-5:] = False
    problem = SimpleNamespace(y=y, mask=mask, floor=np.asarray(0.05))
    monkeypatch.setattr(chunked_fit, "SUMMARY_CELLS", 10**9)
    whole = chunked_fit._summary(problem, values)
    monkeypatch.setattr(chunked_fit, "SUMMARY_CELLS", 2 * values[0].size)  # two chunks at a time, the last alone
    parts = chunked_fit._summary(problem, values)
    expect = (np.concatenate(values) - y) / np.maximum(np.abs(y), 0.05)
    expect[~mask] = 0
    np.testing.assert_array_equal(parts["rel"], whole["rel"])
    np.testing.assert_allclose(parts["rel"][np.isfinite(expect)], expect[np.isfinite(expect)].astype(np.float32), rtol=1e-6)
    assert parts["rel"].dtype == np.float32 and parts["rel"].shape == y.shape
    assert parts["bad"] == whole["bad"] == (3 if cols else 1)
    np.testing.assert_allclose([parts["rmse"], parts["rel_rmse"]], [whole["rmse"], whole["rel_rmse"]], rtol=1e-12)
