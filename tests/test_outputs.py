"""No command loses or damages a user's file: output checks, atomic writes, the cache without a
HOME, HDF5 chains kept, and Ctrl-C (exit 130, one line, resumable)."""

from __future__ import annotations

import json
import os
import signal
import stat
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import jax
import pytest
from typer.testing import CliRunner

from ctfit._io import files as _fileio
from ctfit._io.output_paths import (
    OutputError,
    check_backend,
    check_output,
    check_output_folder,
    result_targets,
    unconverged_target,
)
from ctfit._runtime import compile_cache as _cache, stored_programs as _aot
from ctfit.cli import app

from conftest import ROOT

MATERIAL = ROOT / "configs" / "copper-vase.toml"
runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


def read_only(path: Path, text: str = "keep me\n") -> Path:
    path.write_text(text)
    path.chmod(0o444)
    return path


# --- check_output, check_output_folder ----------------------------------------------------------


def test_output_equal_to_an_input_is_refused(tmp_path):
    data = tmp_path / "data.csv"
    data.write_text("x\n")
    (tmp_path / "sub").mkdir()
    os.link(data, tmp_path / "hard.csv")
    (tmp_path / "soft.csv").symlink_to(data)
    for same in (data, tmp_path / "sub" / ".." / "data.csv", tmp_path / "hard.csv", tmp_path / "soft.csv"):
        with pytest.raises(OutputError, match=r"^-o .*: is the input .*data.csv"):
            check_output(same, [MATERIAL, data])
    assert check_output(tmp_path / "out.csv", [MATERIAL, data]) == tmp_path / "out.csv"


def test_many_outputs_are_checked_against_many_inputs_in_linear_time(tmp_path, monkeypatch):
    """A folder of n files: each of n outputs checked against all n inputs looks each path up
    once (2n lookups, not n²: 5,000 files took over 5 minutes); the first input that is the same file
    is the one named."""
    from ctfit._io import output_paths

    files = [tmp_path / f"f{i}.csv" for i in range(300)]
    for f in files:
        f.write_text("x\n")
    (tmp_path / "alias.csv").symlink_to(files[7])
    calls = []
    real = output_paths._identity
    monkeypatch.setattr(output_paths, "_identity", lambda p: calls.append(p) or real(p))
    inputs = output_paths.InputFiles([*files, tmp_path / "alias.csv"])
    for i in range(300):
        check_output(tmp_path / "out" / f"f{i}.fit.json", inputs, chosen=True)
    assert len(calls) == 301 + 300
    with pytest.raises(OutputError, match=r"is the input .*f7\.csv"):
        check_output(tmp_path / "alias.csv", inputs)


def test_read_only_target_is_refused_even_for_root(tmp_path):
    target = read_only(tmp_path / "result.json")
    with pytest.raises(OutputError, match=r"-o .*result.json: the file is read-only \(mode -r--r--r--\)"):
        check_output(target)
    link = tmp_path / "link.json"
    link.symlink_to(target)
    with pytest.raises(OutputError, match=r"link.json: the file is read-only"):
        check_output(link)
    assert target.read_text() == "keep me\n"


def test_missing_folders_are_made_and_impossible_ones_name_the_users_path(tmp_path):
    out = tmp_path / "a" / "b" / "out.csv"
    check_output(out)
    assert out.parent.is_dir() and not out.exists()
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(OutputError, match=r"^--plot .*file/x/y.png: .*file is a file, not a folder") as err:
        check_output(blocker / "x" / "y.png", option="--plot")
    assert ".tmp" not in str(err.value)
    with pytest.raises(OutputError, match="is a folder; give a file name"):
        check_output(tmp_path)


def test_devices_and_links_are_accepted(tmp_path):
    assert check_output("/dev/null", ["/dev/null"]) == Path("/dev/null")
    link = tmp_path / "link.csv"
    link.symlink_to(tmp_path / "new" / "real.csv")  # dangling: the write creates the target
    check_output(link)
    assert (tmp_path / "new").is_dir()


def test_output_folder(tmp_path):
    assert check_output_folder(tmp_path / "x" / "y", "--backend").is_dir()
    (tmp_path / "f").write_text("")
    with pytest.raises(OutputError, match=r"^--plot .*f: is a file, not a folder"):
        check_output_folder(tmp_path / "f", "--plot")


# --- check_backend ------------------------------------------------------------------------------


def test_an_existing_chain_needs_resume_or_overwrite(tmp_path):
    import h5py

    chain = tmp_path / "run.h5"
    with h5py.File(chain, "w") as f:
        f.create_group("ctfit")["x"] = [1.0]  # (a chain of ctfit's: its group)
    with pytest.raises(OutputError, match=r"--backend .*run.h5: the file exists; .* --resume, .* --overwrite"):
        check_backend(chain, resume=False, overwrite=False)
    with pytest.raises(OutputError, match="resume=True.* overwrite=True"):
        check_backend(chain, resume=False, overwrite=False, flags=("resume=True", "overwrite=True"))
    assert check_backend(chain, resume=True, overwrite=False) == chain
    assert check_backend(chain, resume=False, overwrite=True) == chain
    with pytest.raises(OutputError, match="exclude each other"):
        check_backend(chain, resume=True, overwrite=True)
    with h5py.File(chain, "a") as f:
        f["calibration"] = [2.0]  # the user's data beside the chain: a new chain (the whole file anew) would lose it
    with pytest.raises(OutputError, match=r"run.h5: the HDF5 file holds 'calibration' beside ctfit's chain"):
        check_backend(chain, resume=False, overwrite=True)
    text = tmp_path / "notes.txt"
    text.write_text("not a chain")
    with pytest.raises(OutputError, match="is not an HDF5 file"):
        check_backend(text, resume=True, overwrite=False)
    empty = tmp_path / "empty.h5"
    empty.write_bytes(b"")
    assert check_backend(empty, resume=False, overwrite=False) == empty
    assert check_backend(tmp_path / "new.h5", resume=False, overwrite=False) == tmp_path / "new.h5"


def test_a_truncated_chain_is_refused_naming_the_file(tmp_path):
    """A chain file cut short (a copy that stopped, a full disk): --resume and --overwrite say
    which file HDF5 cannot read and why in a few words, and keep it (HDF5's own message named
    neither: "Unable to synchronously open file (truncated file: eof = 20000, …)")."""
    import h5py

    chain = tmp_path / "run.h5"
    with h5py.File(chain, "w") as f:
        f.create_group("ctfit")["x"] = [0.0] * 50_000
    whole = chain.read_bytes()
    chain.write_bytes(whole[:20_000])
    for resume, so in ((True, "so it holds no chain to continue"), (False, "so what it holds cannot be checked before a new chain replaces it")):
        with pytest.raises(OutputError, match=rf"^--backend .*run.h5: HDF5 cannot read the file \(truncated: 20,000 of {len(whole):,} bytes\), {so}; restore"):
            check_backend(chain, resume=resume, overwrite=not resume)
    assert chain.read_bytes() == whole[:20_000]


def test_the_library_refuses_to_wipe_a_chain(tmp_path):
    import ctfit

    chain = tmp_path / "run.h5"
    chain.write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(100))
    before = chain.read_bytes()
    with pytest.raises(OutputError, match="resume=True.* overwrite=True"):
        ctfit.sample(None, None, backend=chain)  # refused before the material or data are looked at
    assert chain.read_bytes() == before
    for burn, thin, words in ((500, 1, r"burn must be in \[0, steps\), got 500 with steps=200"), (150, 60, "thin must be at most steps − burn = 50")):
        with pytest.raises(ValueError, match=words):  # refused before --overwrite empties the chain, not after a whole run
            ctfit.sample(None, None, steps=200, burn=burn, thin=thin, backend=chain, overwrite=True)
        assert chain.read_bytes() == before


# --- result_targets, unconverged_target ---------------------------------------------------------


def test_result_targets_are_distinct_and_deterministic(tmp_path):
    out = tmp_path / "out"
    files = [Path("a/x.csv"), Path("b/x.csv"), Path("b/y.csv"), Path("p/q/z.csv"), Path("r/q/z.csv"), Path("c/X.csv")]
    got = result_targets(files, out, ".fit.json")
    assert [t.name for t in got.values()] == ["a-x.fit.json", "b-x.fit.json", "y.fit.json", "p-q-z.fit.json", "r-q-z.fit.json", "c-X.fit.json"]
    assert all(t.parent == out for t in got.values())
    assert result_targets(files, out, ".fit.json") == got
    png = result_targets(files, out, ".fit.png")  # the same names for another suffix
    assert [t.name[: -len(".fit.png")] for t in png.values()] == [t.name[: -len(".fit.json")] for t in got.values()]
    # The same stem in the same folder (x.csv, x.alta): the suffix after it, whatever else is fitted
    # (numbered up to the root's folders, the names changed with the set: a rerun without one file was refused).
    same = result_targets([Path("d/x.csv"), Path("d/x.alta"), Path("x.dat")], out, ".fit.json")
    assert [t.name for t in same.values()] == ["x-csv.fit.json", "x-alta.fit.json", "x.fit.json"]
    fewer = result_targets([Path("d/x.csv"), Path("d/x.alta")], out, ".fit.json")
    assert [t.name for t in fewer.values()] == ["x-csv.fit.json", "x-alta.fit.json"]
    case = result_targets([Path("d/x.csv"), Path("d/X.CSV")], out, ".fit.json")  # only case tells them apart: numbered
    assert [t.name for t in case.values()] == ["x-csv.fit.json", "X-CSV-2.fit.json"]
    assert result_targets([Path("only.csv")], out, ".fit.json") == {Path("only.csv"): out / "only.fit.json"}
    assert result_targets(["d/x.csv", "d/x.csv"], out, ".fit.json") == {Path("d/x.csv"): out / "x.fit.json"}


def test_a_converged_result_is_kept_when_a_new_fit_does_not_converge(tmp_path):
    target = tmp_path / "x.fit.json"
    assert unconverged_target(target) == (target, None)
    target.write_text(json.dumps({"name": "x", "fit": {"converged": True}}))
    where, note = unconverged_target(target)
    assert where == tmp_path / "x.fit.not-converged.json"
    assert "x.fit.json holds a converged fit and is kept" in note and str(where) in note
    target.write_text(json.dumps({"name": "x", "fit": {"converged": False}}))
    where, note = unconverged_target(target)
    assert where == target and "replaced by a fit that did not converge" in note
    target.write_text("not json")
    assert unconverged_target(target)[0] == target


def test_the_not_converged_name_of_a_long_name_fits_the_file_system(tmp_path):
    """A target name of 250 bytes (under the usual limit of 255) cannot take ".not-converged.json"
    as it is: the new result would not be written at all. It gets a shortened name that holds a
    digest of the whole, so two long names stay apart."""
    results = []
    for tail in ("a", "b"):
        target = tmp_path / ("é" * 118 + tail + ".fit.json")  # 246 bytes
        target.write_text(json.dumps({"fit": {"converged": True}}))
        where, note = unconverged_target(target)
        assert len(os.fsencode(where.name)) <= 255 and where.name.endswith(".not-converged.json") and where.parent == tmp_path
        where.write_text("{}")  # can be written
        assert target.read_text() == json.dumps({"fit": {"converged": True}}) and str(where) in note
        results.append(where)
    assert results[0] != results[1]


# --- atomic_write ---------------------------------------------------------------------------------


def test_a_link_stays_a_link(tmp_path):
    real = tmp_path / "real.json"
    real.write_text("old")
    link = tmp_path / "link.json"
    link.symlink_to(real)
    _fileio.atomic_write(link, ["new"])
    assert link.is_symlink() and os.readlink(link) == str(real)
    assert real.read_text() == "new"


def test_a_fifo_is_written_into_not_replaced(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()))
    reader.start()
    _fileio.atomic_write(fifo, [b"through ", b"the pipe"])
    reader.join(10)
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert got == [b"through the pipe"]


def test_read_only_files_are_not_replaced_and_modes_are_kept(tmp_path):
    ro = read_only(tmp_path / "ro.csv")
    with pytest.raises(PermissionError, match="read-only") as err:
        _fileio.atomic_write(ro, ["new"])
    assert err.value.filename == str(ro)
    assert ro.read_text() == "keep me\n"
    private = tmp_path / "private.json"
    private.write_text("old")
    private.chmod(0o600)
    _fileio.atomic_write(private, ["new"])
    assert stat.S_IMODE(private.stat().st_mode) == 0o600 and private.read_text() == "new"


def test_write_errors_name_the_users_file_and_leave_nothing(tmp_path):
    missing = tmp_path / "no" / "such" / "out.csv"
    with pytest.raises(FileNotFoundError) as err:
        _fileio.atomic_write(missing, ["x"])
    assert err.value.filename == str(missing) and ".tmp" not in str(err.value)

    target = tmp_path / "out.csv"
    target.write_text("old")

    def interrupted():
        yield "half"
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        _fileio.atomic_write(target, interrupted())
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]


def test_images_and_figures_are_written_atomically(tmp_path):
    import matplotlib.pyplot as plt
    import numpy as np

    from ctfit import save_png
    from ctfit._sampling.plots import _save_figure

    for name, write in [
        ("tile.png", lambda p: save_png(np.zeros((4, 4, 3), np.uint8), p)),
        ("corner.png", lambda p: _save_figure(plt.figure(figsize=(1, 1)), p)),
    ]:
        real, link = tmp_path / ("real-" + name), tmp_path / name
        real.write_bytes(b"old")
        link.symlink_to(real)
        write(link)
        assert link.is_symlink() and real.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        ro = read_only(tmp_path / ("ro-" + name))
        with pytest.raises(PermissionError, match="read-only"):
            write(ro)
        assert ro.read_text() == "keep me\n"
    plt.close("all")
    assert not list(tmp_path.glob(".*.tmp"))


# --- the cache without a usable HOME -------------------------------------------------------------


@pytest.fixture
def cache_config(monkeypatch):
    """Restore JAX's cache settings and the warn-once memory after the test."""
    saved = jax.config.jax_compilation_cache_dir
    monkeypatch.setattr(_cache, "_warned", set())
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    yield
    jax.config.update("jax_compilation_cache_dir", saved)


@pytest.mark.parametrize("home", ["file", "", None])
def test_no_usable_home_means_no_cache_and_one_warning(tmp_path, monkeypatch, cache_config, home):
    monkeypatch.chdir(tmp_path)
    if home == "file":  # root may create any folder: a path under a regular file cannot be one
        (tmp_path / "file").write_text("")
        monkeypatch.setenv("HOME", str(tmp_path / "file"))
    elif home == "":
        monkeypatch.setenv("HOME", "")
    else:
        monkeypatch.delenv("HOME")
        monkeypatch.setattr(Path, "home", classmethod(lambda cls: (_ for _ in ()).throw(RuntimeError("no home"))))
    with pytest.warns(_cache.CacheWarning, match="compilation cache off") as got:
        assert _cache.enable_compilation_cache() is None
    assert len(got) == 1
    assert jax.config.jax_compilation_cache_dir is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert _cache.enable_compilation_cache() is None  # once per process
    assert not Path(".cache").exists()  # an empty HOME is not the current folder


def test_a_writable_cache_folder_is_used(tmp_path, cache_config):
    where = _cache.enable_compilation_cache(tmp_path / "c")
    assert where == tmp_path / "c" and jax.config.jax_compilation_cache_dir == str(where)
    assert stat.S_IMODE(where.stat().st_mode) == 0o700


def test_the_program_store_is_private(tmp_path, monkeypatch, cache_config):
    import jax.numpy as jnp

    monkeypatch.setattr(_aot, "_stores", {})
    monkeypatch.setattr(_aot, "_memory", {})
    jax.config.update("jax_compilation_cache_dir", str(tmp_path / "mine"))
    store = _aot._store()
    assert store == tmp_path / "mine" / "ctfit-aot" and stat.S_IMODE(store.stat().st_mode) == 0o700

    shared = tmp_path / "shared" / "ctfit-aot"
    shared.mkdir(parents=True)
    shared.chmod(0o777)
    jax.config.update("jax_compilation_cache_dir", str(tmp_path / "shared"))
    with pytest.warns(_cache.CacheWarning, match=r"ctfit-aot can be written by other users .*chmod go-w"):
        assert _aot._store() is None
    got = _aot.cached_call("toy", lambda x: {"y": 2 * x}, jnp.arange(3.0))
    assert list(got["y"]) == [0.0, 2.0, 4.0]
    assert not list(shared.iterdir())  # nothing written to (or loaded from) the shared folder


# --- the commands: checks come before any work ---------------------------------------------------


@pytest.fixture
def no_work(monkeypatch):
    """Fail the test if a command gets as far as setting up JAX."""
    from ctfit._cli import commands, fit_cluster, fit_command

    def setup(*a, **k):
        raise AssertionError("the command started its work before checking its outputs")

    for module in (commands, fit_command, fit_cluster):
        monkeypatch.setattr(module, "setup_jax", setup)


def test_commands_refuse_an_output_that_is_an_input(tmp_path, no_work):
    data = tmp_path / "data.csv"
    data.write_text("theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n10,0,10,180,500,1\n")
    mat = tmp_path / "m.toml"
    mat.write_bytes(MATERIAL.read_bytes())
    before = data.read_bytes(), mat.read_bytes()
    for args, victim in [
        (("eval", mat, data, "-o", data), data),
        (("eval", mat, data, "-o", mat), mat),
        (("simulate", mat, "-o", mat), mat),
        (("render", mat, "-o", mat), mat),
        (("sample", mat, data, "-o", data), data),
        (("sample", mat, data, "-o", tmp_path / "x.json", "--backend", data), data),
        (("fit", data, "--material", mat, "-o", mat), mat),  # the material that starts the fit: it was overwritten
        (("fit", data, "--material", mat, "--plot", mat), mat),
        (("fit", data, "--material", mat, "-o", tmp_path / "x.json", "--sample", "--backend", mat), mat),
    ]:
        r = run(*args)
        assert r.exit_code == 2, (args, r.output)
        assert r.output.startswith("error: ") and f"is the input {victim}" in r.output, r.output
    assert (data.read_bytes(), mat.read_bytes()) == before
    r = run("fit", data, "-o", tmp_path / "result.toml")  # JSON in a .toml file would not load back
    assert r.exit_code == 2 and "name it .json" in r.output and not (tmp_path / "result.toml").exists(), r.output


@pytest.mark.parametrize("where", ["beside", "env"])
def test_a_materials_optical_constants_csv_is_an_input_too(tmp_path, no_work, monkeypatch, where):
    """A material file whose ``optical_constants`` names a CSV reads that file: no command writes
    over it (simulate, export, eval, render through a link, fit --material with -o or --plot all
    replaced it, and the material then no longer loaded). Beside the material file, and in a
    folder of $CTFIT_OPTICAL_CONSTANTS."""
    tables = tmp_path / ("tables" if where == "env" else "work")
    tables.mkdir(exist_ok=True)
    table = tables / "oc.csv"
    table.write_bytes((ROOT / "ctfit" / "data" / "optical_constants" / "Cu.csv").read_bytes())
    if where == "env":
        monkeypatch.setenv("CTFIT_OPTICAL_CONSTANTS", str(tables))
    work = tmp_path / "work"
    work.mkdir(exist_ok=True)
    mat = work / "m.toml"
    mat.write_text('name = "local copper"\ns = 1.0\nlobes = [{ m = 0.2 }]\noptical_constants = "oc.csv"\n')
    data = work / "data.csv"
    data.write_text("theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n10,0,10,180,500,1\n20,0,20,180,500,1\n")
    (work / "pic.png").symlink_to(table)
    before = table.read_bytes()
    for args in [
        ("simulate", mat, "-o", table),
        ("export", mat, "--to", "mitsuba", "-o", table),
        ("export", mat, "--to", "merl", "-o", table),
        ("eval", mat, data, "-o", table),
        ("render", mat, "-o", work / "pic.png"),
        ("fit", data, "--material", mat, "-o", table),
        ("fit", data, "--material", mat, "--plot", work / "pic.png"),
    ]:
        r = run(*args)
        assert r.exit_code == 2, (args, r.output)
        assert r.output.startswith("error: ") and f"is the input {table}" in r.output, (args, r.output)
    assert table.read_bytes() == before
    from ctfit._io import material_file_inputs

    assert material_file_inputs(mat) == [mat, table.resolve()]


def test_commands_refuse_read_only_and_unmakeable_outputs(tmp_path, no_work):
    ro = read_only(tmp_path / "ro.csv")
    r = run("simulate", MATERIAL, "-o", ro)
    assert r.exit_code == 2 and "ro.csv: the file is read-only" in r.output
    assert ro.read_text() == "keep me\n"
    (tmp_path / "file").write_text("")
    r = run("simulate", MATERIAL, "-o", tmp_path / "file" / "out.csv")
    assert r.exit_code == 2 and f"-o {tmp_path / 'file' / 'out.csv'}:" in r.output and ".tmp" not in r.output
    r = run("sample", MATERIAL, tmp_path / "data.csv", "-o", tmp_path / "o.json", "--plot", tmp_path / "file")
    assert r.exit_code == 2 and "--plot" in r.output and "not a folder" in r.output


def test_sample_keeps_an_existing_chain(tmp_path, no_work):
    chain = tmp_path / "run.h5"
    chain.write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(100))
    fit_json = tmp_path / "fit.json"
    fit_json.write_text("{}")
    # DATA does not exist: the refusal comes before anything is read.
    r = run("sample", fit_json, tmp_path / "missing.csv", "--backend", chain)
    assert r.exit_code == 2 and "--resume" in r.output and "--overwrite" in r.output, r.output
    assert chain.read_bytes().startswith(b"\x89HDF") and len(chain.read_bytes()) == 108
    r = run("sample", fit_json, tmp_path / "missing.csv", "--overwrite")
    assert r.exit_code == 2 and "--overwrite needs --backend" in r.output


def test_outputs_through_links_and_devices(tmp_path):
    real = tmp_path / "real.csv"
    real.write_text("old")
    link = tmp_path / "link.csv"
    link.symlink_to(real)
    args = ("--samples", 20, "--wavelengths", "500:600:100")
    r = run("simulate", MATERIAL, "-o", link, *args)
    assert r.exit_code == 0, r.output
    assert link.is_symlink() and real.read_text().startswith("# ")
    r = run("simulate", MATERIAL, "-o", "/dev/null", *args)
    assert r.exit_code == 0, r.output
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)


# --- in a new process: HOME, Ctrl-C -------------------------------------------------------------


def _env(tmp_path, **extra):
    env = {k: v for k, v in os.environ.items() if k not in ("JAX_COMPILATION_CACHE_DIR", "HOME")}
    env.update(HOME=str(tmp_path / "home"), MPLBACKEND="Agg", JAX_PLATFORMS="cpu", **extra)
    return env


def _ctfit(*args):
    return [sys.executable, "-m", "ctfit.cli", *map(str, args)]


def test_a_home_that_cannot_hold_a_cache_gives_one_warning(tmp_path):
    """Neither JAX's cache nor matplotlib's configuration folder (imported by render) can live
    in HOME: one warning line, then the command's own line."""
    (tmp_path / "home").write_text("a file, not a folder")
    out = tmp_path / "out.png"
    r = subprocess.run(
        _ctfit("render", MATERIAL, "-o", out, "--size", 16, "--supersample", 1, "--step", 20),
        env=_env(tmp_path), capture_output=True, text=True, timeout=300,
    )
    assert r.returncode == 0, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 2, r.stderr
    assert lines[0].startswith("warning: compilation cache off: cannot write to ") and str(tmp_path / "home") in lines[0]
    assert lines[1].startswith("wrote ")
    assert out.read_bytes()[:4] == b"\x89PNG"


def _interrupt_when(proc, ready, settle: float = 1.0, timeout: float = 240.0):
    """SIGINT to ``proc`` ``settle`` seconds after ``ready()`` holds; its (returncode, stderr)."""
    t0 = time.monotonic()
    while not ready():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() - t0 < timeout
        time.sleep(0.02)
    time.sleep(settle)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    return proc.returncode, err


def test_the_interrupted_line(monkeypatch):
    from ctfit._cli.commands import _interrupted_message
    from ctfit._io import interrupt as _interrupt

    monkeypatch.setitem(_interrupt._state, "resumable", None)
    monkeypatch.setattr(sys, "argv", ["ctfit", "sample", "f.json", "d.csv", "--backend", "my run.h5", "--overwrite"])
    assert _interrupted_message() == "interrupted"  # no chain written yet: nothing to resume
    _interrupt.note_resumable("my run.h5")
    assert _interrupted_message() == "interrupted; resume with: ctfit sample f.json d.csv --backend 'my run.h5' --resume"
    monkeypatch.setattr(sys, "argv", ["ctfit", "fit", "a.csv", "b.csv", "--sample", "--backend=chains", "--resume"])
    assert _interrupted_message() == "interrupted; resume with: ctfit fit a.csv b.csv --sample --backend=chains --resume"
    monkeypatch.setattr(sys, "argv", ["ctfit", "fit", "a.csv"])
    assert _interrupted_message() == "interrupted"


_SCRIPT = """
import hashlib, os, signal, sys
from ctfit._io.interrupt import deferred
from ctfit._cli.interrupt import install
install(lambda: "interrupted: " + sys.argv[1])
print("ready", flush=True)
if sys.argv[1] == "in C":  # the main thread stays in C code without the GIL: the watcher exits
    hashlib.pbkdf2_hmac("sha256", b"x", b"y", 10**9)
else:  # a deferred write ends before the exit
    with deferred():
        os.kill(os.getpid(), signal.SIGINT)
        open(sys.argv[2], "w").write("whole")
    open(sys.argv[2], "a").write(", and after")
"""


@pytest.mark.parametrize("where", ["in C", "deferred"])
def test_ctrl_c_exits_at_once_unless_a_write_is_under_way(tmp_path, where):
    marker = tmp_path / "marker"
    proc = subprocess.Popen([sys.executable, "-c", _SCRIPT, where, str(marker)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout.readline() == "ready\n"
    if where == "in C":
        time.sleep(0.3)
        proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert (proc.returncode, err) == (130, f"interrupted: {where}\n")
    assert (marker.read_text() if where == "deferred" else None) == ("whole" if where == "deferred" else None)


@pytest.mark.slow
def test_ctrl_c_during_a_cold_compile_exits_130_with_one_line(tmp_path):
    csv = tmp_path / "d.csv"
    assert run("simulate", MATERIAL, "-o", csv, "--samples", 200, "--wavelengths", "400:700:100").exit_code == 0
    cache = tmp_path / "cache"  # empty: the fit traces and compiles from scratch
    out = tmp_path / "fit.json"
    proc = subprocess.Popen(
        _ctfit("fit", csv, "-o", out), env=_env(tmp_path, JAX_COMPILATION_CACHE_DIR=str(cache)),
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    # The direction pairs' small geometry program is stored first; the fit's own program is then
    # traced and compiled (seconds, cold): interrupt half a second into that.
    code, err = _interrupt_when(proc, lambda: any(cache.glob("ctfit-aot/*.xla")), settle=0.5)
    assert (code, err) == (130, "interrupted\n")
    assert not out.exists()
    assert not [p for p in tmp_path.rglob("*.tmp")]


@pytest.mark.slow
def test_ctrl_c_while_sampling_says_how_to_resume_and_resuming_works(tmp_path):
    csv = tmp_path / "d.csv"
    fit_json = tmp_path / "d.fit.json"
    assert run("simulate", MATERIAL, "-o", csv, "--samples", 200, "--wavelengths", "400:700:100", "--noise", 0.02).exit_code == 0
    assert run("fit", csv, "-o", fit_json, "--material", MATERIAL).exit_code == 0  # its structure: no structure choice to compile
    chain, post = tmp_path / "run.h5", tmp_path / "post.json"
    args = ["sample", fit_json, csv, "--steps", 1000, "--backend", chain, "-o", post, "-q"]  # -q: no progress lines on stderr
    env = _env(tmp_path, JAX_COMPILATION_CACHE_DIR=str(tmp_path / "cache"))
    proc = subprocess.Popen(_ctfit(*args), env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)

    code, err = _interrupt_when(proc, lambda: _stored_iteration(chain, at_least=20), settle=0.5)
    hint = "interrupted; resume with: ctfit " + " ".join(map(str, args)) + " --resume"
    assert (code, err) == (130, hint + "\n")
    assert not post.exists()

    again = subprocess.run(_ctfit(*args, "--resume", "--json"), env=env, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    usable = json.loads(again.stdout)["uncertainty"]["usable"]
    assert again.returncode == (0 if usable else 1), again.stderr  # 1: the posterior is not usable (e.g. not mixed)
    diag = json.loads(again.stdout)["uncertainty"]["diagnostics"]
    assert 0 < diag["resumed_from"] < 1000 and diag["resumed_from"] + diag["steps_run_now"] == diag["steps"] == 1000
    assert json.loads(post.read_text())["uncertainty"]["diagnostics"]["steps"] == 1000

    # Started again (--overwrite) and stopped after some steps: the new chain, in a temporary file
    # beside it until then, now stands in the file, and the line says so (the 1,000 steps before are gone).
    hidden = lambda: sorted(tmp_path.glob(".ctfit-*.tmp"))
    proc = subprocess.Popen(_ctfit(*args, "--overwrite"), env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    code, err = _interrupt_when(proc, lambda: any(_stored_iteration(f, at_least=10) for f in hidden()), settle=0.2)
    steps = _stored_iteration(chain)
    assert code == 130 and err == f"{hint}; {chain} now holds the new chain ({steps} steps)\n" and 10 <= steps < 1000
    assert not hidden()


def _stored_iteration(path, at_least=None):
    """The steps stored in a chain file (read without HDF5's lock; a read mid-write is retried);
    with ``at_least``, whether there are that many (False while the file is not there yet)."""
    import h5py

    try:
        with h5py.File(path, "r", locking=False) as f:
            n = int(f["ctfit"].attrs.get("iteration", 0))
    except (OSError, KeyError, ValueError, RuntimeError):
        if at_least is None:
            raise
        return False
    return n if at_least is None else n >= at_least


def test_a_cache_entry_cut_by_ctrl_c_is_removed_without_a_word(tmp_path, monkeypatch):
    """A Ctrl-C during a write removes its temporary file; the line names the user's outputs that
    were not written, never ctfit's own cache entries (``atomic_write(quiet=True)``), which the
    program store writes from background threads at any moment of a cold fit."""
    cut = []

    def chunks(path):
        yield b"part"
        cut.append(_fileio.remove_temporaries())  # what the interrupt handler would say now
        raise KeyboardInterrupt

    for quiet, name in ((False, "fit.json"), (True, "entry.xla")):
        with pytest.raises(KeyboardInterrupt):
            _fileio.atomic_write(tmp_path / name, chunks(tmp_path / name), quiet=quiet)
    assert cut == [[f"{tmp_path / 'fit.json'} was not created"], []]
    assert not list(tmp_path.iterdir())  # no temporary file left, nothing created


def test_no_temporary_is_made_after_the_last_sweep_of_an_interrupted_exit(tmp_path):
    """The interrupted exit sweeps the temporaries, then ends the process. A background thread
    (the program store's) that starts a write between the two must not leave a new temporary:
    it waits until the process has gone. Run in a child process: the sweep is final there."""
    script = f"""
import os, threading, time
from ctfit._io import files
folder = {str(tmp_path)!r}
files.remove_temporaries(last=True)
writer = threading.Thread(target=files.atomic_write, args=(os.path.join(folder, "entry.xla"), [b"x"]), kwargs={{"quiet": True}}, daemon=True)
writer.start()
writer.join(1.0)
print(writer.is_alive(), sorted(os.listdir(folder)), flush=True)
os._exit(130)
"""
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 130, proc.stderr
    assert proc.stdout.split() == ["True", "[]"]  # the write waits; no temporary, no entry
    assert not list(tmp_path.iterdir())


def test_a_folder_run_replaces_only_its_own_results(tmp_path, monkeypatch):
    """``ctfit fit DIR -o OUT``: a file in OUT at a result's name that this input's earlier fit did
    not write (notes by hand, another folder's fit of an input of the same name), or a
    ``summary.json`` that is not ctfit's, is kept and the run refused before any work; a rerun
    replaces its own results."""
    first, other, out = tmp_path / "in1", tmp_path / "in2", tmp_path / "out"
    for folder, seed in ((first, 1), (other, 2)):
        folder.mkdir()
        assert run("simulate", MATERIAL, "-o", folder / "a.csv", "--samples", 40, "--wavelengths", "450,650", "--seed", seed).exit_code == 0
    args = ("--lobes", 1, "--no-diffuse", "-q", "-o", out)
    out.mkdir()
    for name in ("a.fit.json", "summary.json"):
        (out / name).write_text("my notes\n")
        r = run("fit", first, *args)
        assert r.exit_code == 2 and f"{out / name}: the file exists and is not a" in r.output, r.output
        assert (out / name).read_text() == "my notes\n"
        (out / name).unlink()
    assert run("fit", first, *args).exit_code == 0
    again = run("fit", first, *args)  # a rerun: its own results replaced
    assert again.exit_code == 0, again.output
    monkeypatch.chdir(tmp_path)  # results that name their input relative to the folder the run started in
    assert run("fit", "in1", "--lobes", 1, "--no-diffuse", "-q", "-o", "out").exit_code == 0
    monkeypatch.chdir(first)  # a rerun started elsewhere, naming the folder otherwise: still its own results
    assert run("fit", first, *args).exit_code == 0
    before = (out / "a.fit.json").read_bytes()
    r = run("fit", other, *args)
    assert r.exit_code == 2 and "holds the fit of another input" in r.output and str(first / "a.csv") in r.output, r.output
    assert (out / "a.fit.json").read_bytes() == before


def test_a_result_of_a_file_of_the_same_name_in_another_folder_is_kept(tmp_path, monkeypatch):
    """A run started inside its data folder names its input ``a.csv``; another folder's ``a.csv``
    fitted into the same results folder is another input (its content differs), not a rerun: it
    was written over the first one's fit."""
    first, other, out = tmp_path / "db1", tmp_path / "db2", tmp_path / "out"
    for folder, seed in ((first, 1), (other, 2)):
        folder.mkdir()
        assert run("simulate", MATERIAL, "-o", folder / "a.csv", "--samples", 40, "--wavelengths", "450,650", "--seed", seed).exit_code == 0
    args = ("--lobes", 1, "--no-diffuse", "-q")
    monkeypatch.chdir(first)
    assert run("fit", "a.csv", *args, "-o", f"{out}/").exit_code == 0
    before = (out / "a.fit.json").read_bytes()
    assert json.loads(before)["data"] == "a.csv" and len(json.loads(before)["input_sha256"]) == 64
    monkeypatch.chdir(tmp_path)
    r = run("fit", other / "a.csv", *args, "-o", f"{out}/")
    assert r.exit_code == 2 and "holds the fit of another input, 'a.csv'" in r.output, r.output
    assert (out / "a.fit.json").read_bytes() == before
    assert run("fit", first / "a.csv", *args, "-o", f"{out}/").exit_code == 0  # the same file from elsewhere: its own result, replaced


def test_a_result_written_meanwhile_by_another_run_is_kept(tmp_path, monkeypatch):
    """Two runs into one folder at once: the check before the run saw no file, but by the time of
    the write another run's fit of another input is there; it is kept and this file fails (both
    printed 'wrote' and one fit was lost)."""
    import ctfit._cli.fit_command as fit_command

    data = tmp_path / "a.csv"
    assert run("simulate", MATERIAL, "-o", data, "--samples", 40, "--wavelengths", "450,650").exit_code == 0
    out = tmp_path / "out"
    theirs = json.dumps({"data": "/elsewhere/a.csv", "fit": {"converged": True}, "s": 1.0}) + "\n"
    report = fit_command._report_fit

    def meanwhile(res, path, o, target, own=False):
        Path(target).write_text(theirs)  # the other run's rename lands between the plan and this write
        return report(res, path, o, target, own=own)

    monkeypatch.setattr(fit_command, "_report_fit", meanwhile)
    r = run("fit", data, "--lobes", 1, "--no-diffuse", "-q", "-o", f"{out}/")
    assert r.exit_code == 2 and "holds the fit of another input, '/elsewhere/a.csv'" in r.output, r.output
    assert (out / "a.fit.json").read_text() == theirs
    assert not [p for p in out.iterdir() if p.name.startswith(".ctfit-")]  # no temporary left


def test_a_sampled_result_written_meanwhile_by_another_run_is_kept(tmp_path, monkeypatch):
    """``fit --sample`` into a folder: the sampling takes minutes, and another run's fit of another
    input put at the result's name meanwhile is kept (the write checks again); that input fails."""
    import ctfit._cli.sample_command as sample_command

    data = tmp_path / "a.csv"
    assert run("simulate", MATERIAL, "-o", data, "--samples", 40, "--wavelengths", "450,650").exit_code == 0
    out = tmp_path / "out"
    theirs = json.dumps({"data": "/elsewhere/a.csv", "fit": {"converged": True}, "s": 1.0}) + "\n"
    sampled = sample_command._uncertainty

    def meanwhile(*args, **kwargs):
        section = sampled(*args, **kwargs)
        (out / "a.fit.json").write_text(theirs)  # the other run's rename lands while this one samples
        return section

    monkeypatch.setattr(sample_command, "_uncertainty", meanwhile)
    r = run("fit", data, "--lobes", 1, "--no-diffuse", "-q", "--sample", "--steps", 40, "-o", f"{out}/")
    assert r.exit_code == 2 and "holds the fit of another input, '/elsewhere/a.csv'" in r.output, r.output
    assert (out / "a.fit.json").read_text() == theirs
