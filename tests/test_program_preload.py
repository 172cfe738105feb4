"""ctfit/_runtime/program_preload.py: the programs a command used last time, loaded from the store
while the next one with the same options reads its files."""

from __future__ import annotations

import json
import threading
import time
from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np
import pytest
from typer.testing import CliRunner

import ctfit
from ctfit._cli.fit_command import PROGRAM_OPTIONS, program_signature
from ctfit._fitting import chunked_fit, problem
from ctfit._runtime import program_preload as preload, stored_programs as _aot
from ctfit.cli import app


def _fn(a, x, power):
    return {"y": a * 2.0 + x**power}


def _toy(power: int = 2):
    return _aot.cached_call("toy", _fn, jnp.arange(3.0), jnp.array([1.0, 2.0, 3.0]), power)


@pytest.fixture
def loads(store, monkeypatch):
    """The store in a fresh folder (conftest's ``store``), its loads from disk counted (a list of
    keys), what was asked for and loaded ahead emptied."""
    seen: list[str] = []
    real = _aot._load

    def counted(path, key):
        seen.append(key)
        return real(path, key)

    monkeypatch.setattr(_aot, "_load", counted)
    monkeypatch.setattr(_aot, "_askers", [])
    monkeypatch.setattr(_aot, "_preloaded", {})
    monkeypatch.setattr(_aot, "_missed", [])
    return seen


def _no_tracing(monkeypatch):
    def traced(*a, **k):
        raise AssertionError("traced again although the program was loaded ahead")

    monkeypatch.setattr(_aot.jax, "jit", traced)


def _recorded(signature: str = "sig", power: int = 2) -> dict:
    asked = preload.programs_asked()
    out = _toy(power)
    preload.record_programs(signature, asked)
    return dict(asked=asked, out=out)


def _ahead(signature: str) -> list[str]:
    """The programs a preload of ``signature`` loads (all of them: nothing asked meanwhile), dropped."""
    ahead = preload.start_preload(signature)
    ahead._thread.join()
    loaded = list(ahead.loaded)
    ahead.finish()
    return loaded


def test_recorded_programs_are_loaded_ahead_and_used_without_another_load(loads, monkeypatch):
    want = _recorded()["out"]
    monkeypatch.setattr(_aot, "_memory", {})  # as in a new process
    ahead = preload.start_preload("sig")
    ahead._thread.join()
    assert len(loads) == 1 and list(_aot._preloaded) == loads
    _no_tracing(monkeypatch)
    got = _toy()
    np.testing.assert_array_equal(got["y"], want["y"])
    assert len(loads) == 1 and _aot._preloaded == {}  # taken, not loaded again
    ahead.finish()


def test_a_damaged_program_loaded_ahead_is_dropped_with_a_warning_and_compiled_again(loads, monkeypatch):
    (key,) = _recorded()["asked"]
    monkeypatch.setattr(_aot, "_memory", {})

    def damaged(*leaves):
        raise RuntimeError("cannot run")

    _aot._preloaded[key] = damaged
    with pytest.warns(RuntimeWarning, match="ignoring the compiled-program cache entry"):
        got = _toy()
    np.testing.assert_array_equal(got["y"], jnp.arange(3.0) * 2.0 + jnp.array([1.0, 4.0, 9.0]))


def test_programs_no_fit_asks_for_are_dropped_when_the_command_ends(loads, monkeypatch):
    _recorded()
    monkeypatch.setattr(_aot, "_memory", {})
    assert _ahead("sig") == loads and len(loads) == 1
    assert _aot._preloaded == {} and _aot._missed == []


def test_a_record_names_this_run_s_programs_first_then_the_last_run_s(loads):
    (first,) = _recorded(power=2)["asked"].values()
    (second,) = _recorded(power=3)["asked"].values()  # another program (its static power)
    (path,) = _aot._store().glob("recent-*.json")
    assert [tuple(e) for e in json.loads(path.read_text())["programs"]] == [second, first]
    assert _aot._askers == []  # each recording ended


def test_ending_one_recording_leaves_another_of_equal_contents_going(loads):
    first, second = preload.programs_asked(), preload.programs_asked()  # both empty: equal, not the same
    preload.record_programs("sig", second, write=False)
    assert len(_aot._askers) == 1 and _aot._askers[0] is first
    preload.record_programs("sig", first, write=False)
    assert _aot._askers == []


def test_a_run_stopped_midway_leaves_the_record_as_it_was(loads):
    _recorded(power=2)
    path = preload._record_path("sig")
    before = path.read_text()
    asked = preload.programs_asked()
    _toy(3)
    preload.record_programs("sig", asked, write=False)
    assert path.read_text() == before and _aot._askers == []


def test_a_missing_or_malformed_record_loads_nothing(loads):
    assert _ahead("never recorded") == []
    path = preload._record_path("sig")
    env, digest = _aot._environment_digest(), "0" * 64
    for programs in ('3', '[["toy", 3]]', '[["toy"]]', f'[["../toy", "{digest}"]]', '[["toy", "../../x"]]', '[]'):
        path.write_text(f'{{"environment": "{env}", "programs": {programs}}}')
        assert _ahead("sig") == [], programs  # (a name or digest that could lead out of the store: refused)
    for text in ("not json", '{"other": 1}', f'{{"programs": [["toy", "{digest}"]]}}'):
        path.write_text(text)
        assert _ahead("sig") == [], text
    path.write_text(f'{{"environment": "{env}", "programs": []}}')
    preload.record_programs("sig", preload.programs_asked())  # nothing asked for: the record is left as it was
    assert json.loads(path.read_text())["programs"] == []


def test_a_record_of_another_ctfit_is_neither_loaded_nor_kept(loads):
    _recorded(power=2)
    path = preload._record_path("sig")
    doc = json.loads(path.read_text())
    path.write_text(json.dumps(dict(doc, environment="another ctfit's source or JAX")))
    assert _ahead("sig") == []
    (key,) = _recorded(power=3)["asked"].values()
    assert [tuple(e) for e in json.loads(path.read_text())["programs"]] == [key]  # the other's programs are left out


def test_records_beyond_the_limit_are_deleted_oldest_first(loads, monkeypatch):
    import os

    monkeypatch.setattr(preload, "RECORDS_KEPT", 2)
    for i, sig in enumerate(("a", "b", "c")):
        _recorded(sig)
        os.utime(preload._record_path(sig), (1000 + i, 1000 + i))
    _recorded("c")
    assert sorted(p.name for p in _aot._store().glob("recent-*.json")) == sorted(preload._record_path(s).name for s in ("b", "c"))


def test_the_signature_names_the_options_that_shape_programs_not_the_files():
    o = SimpleNamespace(**dict.fromkeys(PROGRAM_OPTIONS) | dict(data=["a.csv"], output="a.fit.json", lobes=2, loss="relative"))
    same = SimpleNamespace(**vars(o) | dict(data=["b.csv"], output="out/", quiet=True))
    assert program_signature(o, None) == program_signature(same, None)
    assert program_signature(o, None) != program_signature(SimpleNamespace(**vars(o) | dict(lobes=3)), None)
    assert program_signature(o, None) != program_signature(SimpleNamespace(**vars(o) | dict(float32=True)), None)
    material = SimpleNamespace(structure="Structure(lobes=1)")
    assert program_signature(o, material) != program_signature(o, None)


def test_a_program_the_record_does_not_name_stops_the_loading_ahead(loads, monkeypatch):
    _recorded(power=2)
    monkeypatch.setattr(_aot, "_memory", {})
    gate = threading.Event()
    real = _aot._load

    def slow(path, key):
        gate.wait(5)  # the fit asks for another program before this load ends
        return real(path, key)

    monkeypatch.setattr(_aot, "_load", slow)
    ahead = preload.start_preload("sig")
    while ahead._keys is None:  # the record read (then its load waits for the gate)
        time.sleep(0.001)
    assert not ahead._stop.is_set()
    _toy(3)  # not in the record: a fit of other data
    assert ahead._stop.is_set()
    gate.set()
    ahead.finish()
    assert _aot._missed == [] and _aot._preloaded == {}


def test_a_program_asked_for_before_the_record_is_read_stops_the_loading_once_it_is(loads, monkeypatch):
    _recorded(power=2)
    monkeypatch.setattr(_aot, "_memory", {})
    gate = threading.Event()
    real = preload._entries

    def slow(path):
        gate.wait(5)  # the fit asks for another program before the record is read
        return real(path)

    monkeypatch.setattr(preload, "_entries", slow)
    ahead = preload.start_preload("sig")
    _toy(3)  # not in the record, asked for while the thread still reads it
    assert ahead._keys is None and not ahead._stop.is_set()
    gate.set()
    ahead._thread.join(10)  # the thread ends by itself, before finish() could stop it
    assert ahead._stop.is_set() and ahead.loaded == []  # nothing of the record loaded for nothing
    ahead.finish()
    assert _aot._missed == [] and _aot._preloaded == {}


def test_a_second_fit_command_with_the_same_options_takes_its_programs_loaded_ahead(tmp_path, monkeypatch):
    """Whole ``ctfit fit`` commands in this process (its store, as a new process finds it): the
    second, on a file of another size, asks for nothing the first's record did not name, and
    every program loaded ahead is the one it runs."""
    mat = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([0.3]), w=np.ones(1), f0=np.array([0.5, 0.8])),
                         wavelength_nm=np.array([480.0, 620.0]))
    for name, pairs in (("a.csv", 300), ("b.csv", 700)):
        ctfit.write_csv(ctfit.simulate(mat, pairs, noise=0.01, seed=pairs), tmp_path / name)
    options = ["--lobes", "1", "--no-diffuse", "--starts", "3", "--loss", "relative", "-q"]
    run = lambda name: CliRunner().invoke(app, ["fit", str(tmp_path / name), *options, "-o", str(tmp_path / f"{name}.json")])

    def new_process():  # what this worker's earlier fits left in memory: the store is asked for every program
        for module, name, empty in ((_aot, "_memory", {}), (chunked_fit, "_programs", {}), (chunked_fit, "_made", set()), (_aot, "_preloaded", {}),
                                    (problem, "_recent_geometry", {})):
            monkeypatch.setattr(module, name, empty)

    new_process()
    assert run("a.csv").exit_code == 0
    new_process()
    made: list = []
    outside: list = []  # (preload, key) of the programs asked for that were not loaded ahead
    real_init, real_missed = preload.Preload.__init__, preload.Preload._missed

    def kept(self, entries):
        made.append(self)
        real_init(self, entries)

    def missed(self, key):  # (judged once the run ends: under load the fit may ask before the thread read the record)
        outside.append((self, key))
        real_missed(self, key)

    monkeypatch.setattr(preload.Preload, "__init__", kept)
    monkeypatch.setattr(preload.Preload, "_missed", missed)
    result = run("b.csv")
    assert result.exit_code == 0, result.output
    (ahead,) = made
    assert ahead.loaded and [key for who, key in outside if key not in who._keys] == []
    assert set(ahead.loaded) <= set(_aot._memory), "a program loaded ahead was not the one run"
    assert _aot._preloaded == {} and _aot._missed == []
