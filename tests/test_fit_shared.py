"""Measurements of one geometry fitted together (``_fitting/shared_geometry.py``): one program
call for many files' values, each result what ``ctfit.fit`` gives for the file alone."""

import json

import numpy as np
import pytest
from helpers import patch_module
from test_fit_batch import ST, assert_same_fit, assert_same_numbers, folder_result, same_geometry, scattered
from typer.testing import CliRunner

import ctfit
from ctfit._cli import fit_command
from ctfit._fitting import shared_geometry
from ctfit.cli import app


@pytest.fixture(autouse=True)
def any_group_makes_its_program(monkeypatch):
    """Groups of any size take the shared path, their program made if need be (by default a group
    smaller than ``SHARED_COMPILE_FILES`` whose program is not made is fitted on chunks: tested below)."""
    patch_module(monkeypatch, shared_geometry, "SHARED_COMPILE_FILES", 0)


@pytest.fixture
def shared_calls(monkeypatch):
    """The sizes of the groups ``fit_shared`` fitted (not those it handed back to fit one by one)."""
    calls = []
    real = shared_geometry.fit_shared

    def spy(ms, *a, **kw):
        out = real(ms, *a, **kw)
        if out is not None:
            calls.append(len(ms))
        return out

    monkeypatch.setattr(shared_geometry, "fit_shared", spy)
    return calls


@pytest.mark.slow  # compiles the shared program of two layouts
def test_files_of_one_geometry_share_a_call_and_equal_fitting_each_alone(shared_calls):
    grid = same_geometry([0.12, 0.18, 0.25, 0.33, 0.4], n_pairs=90, seed=5)  # grid layout, one geometry
    pairs = scattered(300, 2)  # pairs layout: padded to its size bucket with the others of its geometry
    others = [pairs.replace(brdf=pairs.brdf * f, source=f"<x{f}>") for f in (0.5, 1.5, 3.0)]
    data = [grid[0], pairs, grid[1], *others, *grid[2:]]
    batch = ctfit.fit_batch(data, ST)  # width 1 on a CPU: the shared path
    assert sorted(shared_calls) == [4, 5]
    for d, b in zip(data, batch):
        assert b.material.name == f"fit of {d.source}"
        alone = ctfit.fit(d, ST)
        assert_same_fit(b, alone)
        assert b.status == alone.status
        assert_same_numbers(b.stats["quality"], alone.stats["quality"])


def test_a_member_that_cannot_be_fitted_is_its_error_and_the_others_go_on(shared_calls):
    good = same_geometry([0.15, 0.2, 0.3, 0.35], n_pairs=90, seed=7)
    bad = good[1].replace(brdf=np.zeros(len(good[1])), source="zeros.csv")
    got = ctfit.fit_batch([bad, *good], ST, return_errors=True)  # the first member (the layout's) fails
    assert shared_calls == [5]
    assert isinstance(got[0], ValueError) and "zeros.csv: every brdf is 0" in str(got[0])
    for d, r in zip(good, got[1:]):
        assert_same_fit(r, ctfit.fit(d, ST))
    with pytest.raises(ValueError, match="every brdf is 0"):
        ctfit.fit_batch([*good, bad], ST)


def test_few_files_of_a_geometry_other_starts_or_large_files_are_fitted_one_by_one(shared_calls, monkeypatch):
    three = same_geometry([0.15, 0.2, 0.3], n_pairs=90, seed=8)
    start = ctfit.Params(m=np.array([0.3]), w=np.ones(1), f0=np.array([0.5, 0.5]))
    four = same_geometry([0.15, 0.2, 0.3, 0.35], n_pairs=90, seed=9)
    got = ctfit.fit_batch([*three, *four], ST, start=[None] * 3 + [None, start, None, start])
    assert shared_calls == []  # 3 of one geometry; 2 + 2 of another with two starts
    assert_same_fit(got[4], ctfit.fit(four[1], ST, start=start))
    monkeypatch.setattr(shared_geometry, "SHARED_SAMPLES", 179)  # files of 180 samples: large ones, each on chunks
    got = ctfit.fit_batch(four, ST)
    assert shared_calls == []
    assert_same_fit(got[2], ctfit.fit(four[2], ST))


def test_a_folder_of_mixed_geometries_matches_fitting_each_file(tmp_path, shared_calls, monkeypatch):
    folder = tmp_path / "data"
    folder.mkdir()
    files = [*same_geometry([0.15, 0.2, 0.25, 0.3, 0.35], n_pairs=90, seed=3), *same_geometry([0.2, 0.3], n_pairs=120, seed=4), scattered(300, 6)]
    for i, d in enumerate(files):
        ctfit.write_csv(d, folder / f"m{i}.csv")
    runner = CliRunner()
    args = ["fit", str(folder), "--no-diffuse", "--lobes", "1", "-q"]
    r = runner.invoke(app, [*args, "-o", str(tmp_path / "fits")])
    assert r.exit_code == 0, r.output
    assert shared_calls == [5] and "summary: 8 files: 8 converged" in r.stderr
    for i in range(len(files)):
        alone = tmp_path / f"m{i}.json"
        assert runner.invoke(app, ["fit", str(folder / f"m{i}.csv"), "--no-diffuse", "--lobes", "1", "-o", str(alone)]).exit_code == 0
        assert_same_numbers(folder_result(tmp_path / "fits" / f"m{i}.fit.json"), json.loads(alone.read_text()))
    # Windows of 3 files (read and fitted in the background while the one before is reported):
    # no group of 4 in any window, the same results.
    shared_calls.clear()
    patch_module(monkeypatch, fit_command, "WINDOW_FILES", 3)
    r = runner.invoke(app, [*args, "-o", str(tmp_path / "windows")])
    assert r.exit_code == 0 and shared_calls == []
    for i in range(len(files)):
        name = f"m{i}.fit.json"
        assert_same_numbers(json.loads((tmp_path / "windows" / name).read_text()), json.loads((tmp_path / "fits" / name).read_text()))


def test_what_the_directions_give_is_computed_once_for_members_of_one_geometry(monkeypatch):
    from ctfit._fitting import diagnostics

    data = scattered(300, 11)
    member = data.replace(brdf=2 * data.brdf).with_directions(*data.directions())  # as fit_shared hands its members on
    per_sample = diagnostics._half_angle(data.theta_i, data.phi_i, data.theta_o, data.phi_o)
    np.testing.assert_array_equal(diagnostics.half_angle_deg(data), per_sample)
    notes = diagnostics.relative_residual_structure(data.directions()[0], data.brdf, index=data.directions()[1])
    calls = []
    real = diagnostics._half_angle
    monkeypatch.setattr(diagnostics, "_half_angle", lambda *a: calls.append(1) or real(*a))
    assert diagnostics.relative_residual_structure(member.directions()[0], data.brdf, index=member.directions()[1]) == notes
    np.testing.assert_array_equal(diagnostics.half_angle_deg(member), per_sample)
    assert len(calls) == 0  # the member's pairs gave what was kept for data's
    fresh = scattered(300, 12)
    diagnostics.half_angle_deg(fresh)
    assert len(calls) == 1  # other pairs: computed
    diagnostics.relative_residual_structure(fresh.directions()[0], fresh.brdf, index=fresh.directions()[1])
    assert len(calls) == 1  # the groups of α (and of L·V away from the peak) take the pairs' α computed above


def test_a_group_of_several_calls_makes_its_program_first_on_members_all_skipped(monkeypatch):
    """The store checks a program it loads by running it, under a lock: made by the first of
    several calls running side by side, it would keep the others waiting for that call's whole
    solve. So it is made first, with every member inactive (skipped), and every call finds it."""
    events = []
    for name in ("stored_program", "cached_call"):
        real = getattr(shared_geometry, name)
        spy = lambda *a, _name=name, _real=real, **kw: events.append((_name, a[0], np.asarray(a[5]).tolist())) or _real(*a, **kw)
        monkeypatch.setattr(shared_geometry, name, spy)
    patch_module(monkeypatch, shared_geometry, "SHARED_CALL", 2)
    data = same_geometry([0.15, 0.2, 0.25, 0.3, 0.35], n_pairs=90, seed=3)
    got = ctfit.fit_batch(data, ST)
    assert events[0] == ("stored_program", "fit_shared", [False, False])
    # the calls run side by side, so their order is the threads' (a loaded machine started the third before the second)
    assert sorted(events[1:]) == sorted(("cached_call", "fit_shared", on) for on in ([True, True], [True, True], [True, False]))
    assert_same_fit(got[4], ctfit.fit(data[4], ST))
    events.clear()
    patch_module(monkeypatch, shared_geometry, "SHARED_CALL", 8)
    ctfit.fit_batch(data, ST)  # one call: it makes the program itself
    assert events == [("cached_call", "fit_shared", [True] * 5 + [False] * 3)]


def test_a_small_group_of_a_layout_whose_program_is_not_made_is_fitted_on_chunks(monkeypatch):
    """A new size of file compiles nothing: fewer than ``SHARED_COMPILE_FILES`` files of a layout
    whose shared program is made neither in memory nor on disk are fitted one by one on chunks
    (programs every size shares); once the program is made (here by a larger group), a small group
    of that layout uses it. The results are the same either way."""
    from ctfit._runtime import stored_programs

    monkeypatch.setattr(stored_programs, "_store", lambda: None)  # no disk store: what a run of the suite before left there does not count
    monkeypatch.setattr(stored_programs, "_memory", {})  # nor what the tests before made in this process (one program per size bucket)
    patch_module(monkeypatch, shared_geometry, "SHARED_COMPILE_FILES", 6)
    made = []
    real = shared_geometry.cached_call
    monkeypatch.setattr(shared_geometry, "cached_call", lambda name, *a, **kw: made.append(name) or real(name, *a, **kw))
    data = same_geometry([0.15, 0.2, 0.25, 0.3, 0.35], n_pairs=97, seed=21)
    alone = [ctfit.fit(d, ST) for d in data]
    one_by_one = ctfit.fit_batch(data, ST)
    assert made == []  # no shared call: its program would have been compiled
    six = ctfit.fit_batch([*data, data[0].replace(source="<again>")], ST)  # 6 files: worth compiling
    assert made == ["fit_shared"]
    shared = ctfit.fit_batch(data, ST)  # 5 again: the program is made now, so they share it
    assert made == ["fit_shared", "fit_shared"]
    for a, b, c, d in zip(alone, one_by_one, six, shared):
        assert_same_fit(b, a)
        assert_same_fit(c, a)
        assert_same_fit(d, a)
