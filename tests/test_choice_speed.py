"""What makes the data-chosen default fast: screening fits stopped at SCREEN_TOLERANCE, the choice
fitted to all the data from its screening fit, programs
made ahead in a background thread (prefetch_fit), the geometry of one set of direction pairs
computed once, and the run-once programs compiled for a short compile (COMPILE_EFFORT)."""

from __future__ import annotations

import dataclasses
import os

import jax.numpy as jnp
import numpy as np
import pytest

import ctfit
from ctfit._fitting import problem as problem_module, structure_selection
from ctfit._fitting.least_squares import fit_to_tolerance, prefetch_fit
from ctfit._fitting.seeded_solve import STATIONARY_TOLERANCE
from ctfit._fitting.structure_selection import SCREEN_TOLERANCE
from ctfit._runtime import stored_programs

from conftest import ROOT

ST = ctfit.Structure(family="plastic", lobes=1, diffuse="spectrum")


def _plastic(n_pairs: int, seed: int) -> ctfit.Measurement:
    truth = ctfit.Material(ST, ctfit.Params(s=np.asarray(0.3), m=np.array([0.2]), w=np.ones(1), n=np.full(3, 1.5), rd=np.array([0.1, 0.2, 0.05])),
                           channels=("R", "G", "B"))
    return ctfit.simulate(truth, n_pairs=n_pairs, noise=0.01, seed=seed)


def test_a_looser_tolerance_stops_sooner_and_counts_as_converged_there():
    data = _plastic(300, 1)
    full = ctfit.fit(data, ST)
    loose = fit_to_tolerance(data, ST, tolerance=1e-3)
    assert full.converged and loose.converged
    assert loose.stats["gauss_newton_decrease"] <= 1e-3
    assert loose.stats["steps"] < full.stats["steps"]
    assert loose.stats["cost"] == pytest.approx(full.stats["cost"], rel=1e-2)
    assert not any("not a minimum" in w for w in loose.warnings)
    same = fit_to_tolerance(data, ST)  # no tolerance: fit's own
    assert same.stats["cost"] == full.stats["cost"] and same.stats["steps"] == full.stats["steps"]


def test_screening_fits_stop_at_the_screening_tolerance_and_the_choice_is_fitted_fully():
    data = _plastic(2000, 3)  # 6,000 samples: screened
    best, tried = ctfit.choose_structure(data, lobes=(1,))
    assert best.stats["structure_screening"]["samples"] < len(data)
    assert all(r.stats["gauss_newton_decrease"] <= SCREEN_TOLERANCE for _, r in tried if r.converged)
    direct = ctfit.fit(data, best.material.structure)
    # solved from its screening fit alone, to fit's own tolerance: the minimum fit finds, in fewer steps
    assert best.converged and best.stats["starts"] == 1 and best.stats["steps"] < direct.stats["steps"]
    assert best.stats["gauss_newton_decrease"] <= STATIONARY_TOLERANCE["float64"]
    assert best.stats["cost"] == pytest.approx(direct.stats["cost"], rel=1e-9)


def test_programs_made_ahead_leave_the_fit_nothing_to_compile(compilations):
    st = ctfit.Structure(family="plastic", lobes=2, diffuse="transmitted")  # a structure no other test here fits
    data = _plastic(400, 5)
    prefetch_fit(data, st)
    compilations.clear()
    res = ctfit.fit(data, st)
    assert np.isfinite(res.stats["cost"]) and compilations == []


def test_programs_made_ahead_for_a_file_like_this_one_are_not_made_again_while_in_memory(monkeypatch):
    """A database's later files skip laying out the data for the prefetch; once the store dropped
    a program from memory, the next prefetch makes it again."""
    from ctfit._fitting import least_squares

    st = ctfit.Structure(family="plastic", lobes=1, diffuse="transmitted")
    prepared: list = []
    real_prepare = least_squares.prepare_fit
    monkeypatch.setattr(least_squares, "prepare_fit", lambda *a, **k: prepared.append(1) or real_prepare(*a, **k))
    monkeypatch.setattr(least_squares, "_prefetched", {})
    prefetch_fit(_plastic(100, 6), st)
    prefetch_fit(_plastic(100, 7), st)  # another file of the same bands and size
    assert len(prepared) == 1
    prefetch_fit(_plastic(120, 7), st)  # another size
    prefetch_fit(_plastic(100, 7), st, report=False)  # without the report: the same programs (the report is made on the host)
    assert len(prepared) == 2
    prefetch_fit(_plastic(100, 7), st, given_start=True)  # other programs (no seeds' sums)
    assert len(prepared) == 3
    (key, refs), *_ = least_squares._prefetched.items()
    least_squares._prefetched[key] = [*refs[:-1], lambda: None]  # one of them dropped from memory
    prefetch_fit(_plastic(100, 8), st)
    assert len(prepared) == 4
    monkeypatch.setattr(least_squares, "PREFETCHED_KEPT", 2)
    prefetch_fit(_plastic(140, 8), st)  # a fourth kind: the oldest remembered is forgotten
    assert len(least_squares._prefetched) == 2 and len(prepared) == 5
    prefetch_fit(_plastic(120, 9), st)
    assert len(prepared) == 6


def test_the_geometry_of_one_set_of_pairs_is_computed_once(monkeypatch):
    pairs = np.random.default_rng(0).uniform(0, 60, (300, 4))
    first = problem_module.geometry_deg(pairs, on_host=True)

    def computed(*a, **k):
        raise AssertionError("the geometry was computed again")

    monkeypatch.setattr(problem_module, "_geometry_fields", computed)
    again = problem_module.geometry_deg(pairs.copy(), on_host=True)  # equal values, another array
    np.testing.assert_array_equal(again.cos_vh, first.cos_vh)
    with pytest.raises(ValueError):
        again.cos_vh[0] = 0.0  # shared by the fits of these pairs: read-only


def test_each_compile_effort_is_its_own_program(store):
    """As in a fresh process without JAX's cache (conftest's ``store``)."""
    x = jnp.arange(4.0)
    fast = stored_programs.cached_call("effort", jnp.sin, x, effort="once")
    small = stored_programs.cached_call("effort", jnp.sin, x, effort="step")
    tuned = stored_programs.cached_call("effort", jnp.sin, x, effort="run")
    np.testing.assert_allclose(fast, tuned, rtol=1e-12)
    np.testing.assert_allclose(small, tuned, rtol=1e-12)
    assert len(list(store.glob("effort-*.xla"))) == 3  # each XLA accepted its options
    assert set(stored_programs.COMPILE_EFFORT) == {"run", "step", "once"}
    with pytest.raises(KeyError):
        stored_programs.cached_call("effort", jnp.sin, x, effort="fastest")


def test_candidates_are_fitted_without_the_report_and_only_the_choice_with_it(monkeypatch):
    """The data-chosen default fits its candidates without the report (the residual summary's and
    the report's programs took a third of a first run's compiling; both are now made on the host,
    for every fit on chunks), and what comparing them needs is made on the host too (``fit_light``
    was a program per structure); the structure chosen is fitted again with the report, from its
    candidate's fit, and that is the result."""
    from ctfit._fitting import chunked_fit

    made = []
    program = chunked_fit._program

    def recording(name, fn, *args):
        made.append(name)
        return program(name, fn, *args)

    monkeypatch.setattr(chunked_fit, "_program", recording)
    data = _plastic(300, 2)  # 900 samples: not screened
    best, tried = ctfit.choose_structure(data, lobes=(1, 2))
    chosen = ctfit.structure_label(best.material.structure)
    assert "fit_ne" in made and not {"fit_report", "fit_light", "fit_summary"} & set(made)
    assert len(tried) >= 3
    assert all(res.stderr is None and res.stats["report"] is False and res.stats["quality"]["median_relative_error"] > 0 for _, res in tried)
    candidate = next(res for st, res in tried if ctfit.structure_label(st) == chosen)
    assert best.stderr is not None and "rmse" in best.stats and best.stats["starts"] == 1
    assert best.stats["cost"] == pytest.approx(candidate.stats["cost"], rel=1e-9)
    assert best.stats["quality"]["median_relative_error"] == pytest.approx(candidate.stats["quality"]["median_relative_error"], rel=1e-6)


_WARM_FIT = """
import sys
from ctfit.cli import main
sys.argv = ["ctfit", "fit", sys.argv[1], "--family", "metal", "--lobes", "1", "--diffuse", "none", "-o", sys.argv[2], "-q"]
try:
    main()
except SystemExit as e:
    assert not e.code, e.code
print(sorted(m for m in ("equinox", "optimistix", "lineax") if m in sys.modules))
"""


@pytest.mark.slow
def shipped_in_use() -> bool:
    """Whether this machine uses the solver's shipped programs (ctfit/_runtime/shipped_programs.py)."""
    from ctfit._fitting.chunked_fit import shipped_solver_arguments
    from ctfit._runtime import shipped

    return all(shipped(name, args) is not None for name, _, args in shipped_solver_arguments(8, np.float64))


def test_a_fit_whose_programs_are_stored_imports_neither_equinox_optimistix_nor_lineax(tmp_path):
    """Their imports cost 0.15 s (optimistix, lineax) and 0.25–0.4 s (Equinox) of a warm whole
    process; they are needed only where the solver is traced (ctfit/_fitting/seeded_solve.py;
    the fit's pytrees are JAX-registered dataclasses, ctfit/_model/pytrees.py), which a first fit
    skips too where ctfit ships the solver's programs (tests/test_shipped_programs.py)."""
    import subprocess
    import sys

    env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=str(tmp_path / "cache"))
    run = lambda: subprocess.run([sys.executable, "-c", _WARM_FIT, str(ROOT / "measurements" / "testbed" / "blend-conductors.csv"),
                                  str(tmp_path / "fit.json")], capture_output=True, text=True, env=env, timeout=600)
    first, second = run(), run()
    assert first.returncode == 0 and second.returncode == 0, first.stderr[-2000:] + second.stderr[-2000:]
    assert first.stdout.splitlines()[-1] == ("[]" if shipped_in_use() else "['equinox', 'lineax', 'optimistix']")  # it compiled
    assert second.stdout.splitlines()[-1] == "[]"
    # A folder of one geometry (fitted together, ctfit/_fitting/shared_geometry.py): none either.
    folder = tmp_path / "folder"
    folder.mkdir()
    base = ctfit.simulate(ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([0.2]), w=np.ones(1),
                          f0=np.array([0.9])), wavelength_nm=np.array([550.0])), n_pairs=60, seed=0)
    for i in range(4):
        ctfit.write_csv(base.replace(brdf=np.asarray(base.brdf) * (1 + 0.1 * i)), folder / f"f{i}.csv")
    run = lambda: subprocess.run([sys.executable, "-c", _WARM_FIT, str(folder), str(tmp_path / "out")], capture_output=True, text=True,
                                 env=env, timeout=600)
    first, second = run(), run()
    assert first.returncode == 0 and second.returncode == 0, first.stderr[-2000:] + second.stderr[-2000:]
    assert second.stdout.splitlines()[-1] == "[]"


def _metal(n_pairs: int, seed: int) -> ctfit.Measurement:
    """Copper-coloured metal data: a plastic (index at most 2.5) cannot reach its specular part."""
    truth = ctfit.Material(ctfit.Structure(lobes=1, diffuse="F0/pi"), ctfit.Params(s=np.asarray(0.9), m=np.array([0.25]), w=np.ones(1),
                                                                                    f0=np.array([0.95, 0.64, 0.54])), channels=("R", "G", "B"))
    return ctfit.simulate(truth, n_pairs=n_pairs, noise=0.01, seed=seed)


def test_a_candidate_that_cannot_describe_the_data_stops_at_its_step_budget_and_the_choice_is_unchanged(monkeypatch):
    """A plastic fitted to a metal's data crawls (s → 1 while R_d grows); stopped at
    CANDIDATE_STEPS it loses even at its reach, so it is not solved on, and the choice and its fit
    are those of candidates all solved to max_steps."""
    data = _metal(500, 1)
    best, tried = ctfit.choose_structure(data, lobes=(1,))
    stopped = [r for st, r in tried if r.stats["fit_status"] == "max_steps"]
    assert all(r.stats["steps"] == structure_selection.CANDIDATE_STEPS for r in stopped)
    assert any(r.material.structure.family == "plastic" for r in stopped)  # (and a conductor on effective-index data: k crawls to 0)
    chosen = next(r for st, r in tried if st == best.material.structure)
    for r in stopped:
        reach = structure_selection._reach(r)
        assert reach.stats["cost"] < r.stats["cost"] and reach.stats["bic"] < r.stats["bic"]
        assert not structure_selection._better(reach, chosen, len(data), heldout=False)
    unknown = dataclasses.replace(stopped[0], stats={**stopped[0].stats, "gauss_newton_decrease": float("nan")})
    assert structure_selection._reach(unknown).stats["cost"] == pytest.approx(1e-3 * stopped[0].stats["cost"])  # no promise known: the most
    monkeypatch.setattr(structure_selection, "CANDIDATE_STEPS", 256)  # every candidate solved to max_steps
    full_best, full_tried = ctfit.choose_structure(data, lobes=(1,))
    assert full_best.material.structure == best.material.structure and best.converged
    assert best.stats["cost"] == pytest.approx(full_best.stats["cost"], rel=1e-9)
    assert sum(r.stats["steps"] for _, r in tried) < sum(r.stats["steps"] for _, r in full_tried)


def test_a_candidate_stopped_at_its_budget_is_solved_on_where_that_could_change_the_choice(monkeypatch):
    data = _plastic(300, 2)
    free_best, _ = ctfit.choose_structure(data, lobes=(1, 2))
    monkeypatch.setattr(structure_selection, "CANDIDATE_STEPS", 2)  # every candidate stops at 2 steps
    best, tried = ctfit.choose_structure(data, lobes=(1, 2))
    assert best.material.structure == free_best.material.structure
    assert best.stats["cost"] == pytest.approx(free_best.stats["cost"], rel=1e-9)
    chosen = next(r for st, r in tried if st == best.material.structure)
    assert chosen.stats["steps"] > 2 and chosen.converged  # solved on from where the budget stopped it
    assert any(r.stats["fit_status"] == "max_steps" for _, r in tried)  # others lose even at their reach: left as they stopped


def test_a_candidate_whose_best_seed_spent_the_budget_counts_as_stopped_even_when_judged_converged():
    """float32's stationarity test (10⁻³) passes short of a minimum: a candidate so judged at the
    last step of its budget may still drop (a two-lobe metal stopped 1.2 % above its minimum lost
    to three lobes), so it is solved on where its reach could change a comparison, as an
    unconverged one is; one that converged within the budget, or was solved on already, is not."""
    data = _metal(40, 1)
    res = ctfit.fit(data, ctfit.Structure(lobes=1, diffuse="F0/pi"), max_steps=8)
    candidates = structure_selection._Candidates(data, None, len(data), None, {})
    budget = candidates.budget
    with_stats = lambda **kw: dataclasses.replace(res, stats={**res.stats, **kw})
    assert candidates.stopped(with_stats(fit_status="converged", steps=budget))
    assert candidates.stopped(with_stats(fit_status="max_steps", steps=budget))
    assert not candidates.stopped(with_stats(fit_status="converged", steps=budget - 1))
    solved = with_stats(fit_status="converged", steps=budget)
    candidates.solved_on.add(id(solved))
    assert not candidates.stopped(solved)
    assert not structure_selection._Candidates(data, None, len(data), None, {"max_steps": budget}).stopped(with_stats(fit_status="converged", steps=budget))


def test_only_levenberg_marquardt_candidates_get_the_step_budget():
    """The other solvers' one program is compiled per step limit: their candidates keep max_steps."""
    data = _metal(20, 1)
    budget = lambda **kw: structure_selection._Candidates(data, None, len(data), None, kw).budget
    assert budget() == budget(solver="lm", max_steps=256) == structure_selection.CANDIDATE_STEPS
    assert budget(solver="lm", max_steps=10) == 10
    assert budget(solver="dogleg", max_steps=256) == budget(solver="bfgs", max_steps=256) == 256
