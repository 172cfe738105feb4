"""One run at a time writes an HDF5 chain file (ctfit/_io/chain_lock.py): a second ``ctfit sample``,
``ctfit fit --sample`` or ``sample()`` on a chain that another run is writing is refused at its
start, in one line naming the file, and the first run goes on to the chain it would have written
alone. (A second run used to open the file between two of the first's steps, and HDF5's own lock
then killed the first: "unable to lock file".)"""

from __future__ import annotations

import os
import subprocess
import sys
import threading

import emcee
import numpy as np
import pytest
from typer.testing import CliRunner

import ctfit
from ctfit._io import chain_lock, hold_chain, lock_path
from ctfit._io.output_paths import check_backend
from ctfit._sampling.engine import Engine
from ctfit.cli import app

from conftest import ROOT

runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


def busy(path) -> str:
    """The line a run refused on ``path`` prints."""
    return f"error: --backend {path}: another ctfit run is writing this chain file; wait for it to end, or name another file\n"


_HOLDER = """
import sys
from ctfit._io import hold_chain
with hold_chain(sys.argv[1]):
    print("holding", flush=True)
    sys.stdin.read()
"""


def _holder(path) -> subprocess.Popen:
    """Another process that holds the lock of the chain ``path`` (as a run writing it does) until its stdin closes."""
    proc = subprocess.Popen([sys.executable, "-c", _HOLDER, str(path)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT)
    assert proc.stdout.readline() == "holding\n"
    return proc


@pytest.fixture
def no_work(monkeypatch):
    """Fail the test if a command gets as far as setting up JAX: a refusal comes first."""
    from ctfit._cli import commands, fit_command

    def setup(*a, **k):
        raise AssertionError("the command started its work before checking its --backend")

    for module in (commands, fit_command):
        monkeypatch.setattr(module, "setup_jax", setup)


def test_a_run_on_a_chain_that_another_process_writes_is_refused_at_its_start(tmp_path, no_work):
    chain, other = tmp_path / "run.h5", tmp_path / "other.h5"
    data, mat = tmp_path / "data.csv", ROOT / "configs" / "copper-vase.toml"
    data.write_text("theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n10,0,10,180,500,1\n")
    holder = _holder(chain)  # the first run has the lock; its file is not made yet
    try:
        for args in (("sample", mat, data), ("fit", data, "--material", mat, "--sample")):
            for flags in ((), ("--resume",), ("--overwrite",)):
                r = run(*args, "-o", tmp_path / "x.json", "--backend", chain, *flags)
                assert (r.exit_code, r.output) == (2, busy(chain)), (args, flags)
        with pytest.raises(ValueError, match=r"^backend .*run\.h5: another ctfit run is writing this chain file; wait"):
            ctfit.sample(None, None, backend=chain, resume=True)  # refused before the material or data are looked at
        (tmp_path / "link.h5").symlink_to(chain)
        with pytest.raises(ValueError, match="another ctfit run is writing"):  # the file under another name: the same lock
            check_backend(tmp_path / "link.h5", resume=False, overwrite=False)
        assert check_backend(other, resume=False, overwrite=False) == other  # another file in the folder: not held
        assert not chain.exists() and not (tmp_path / "x.json").exists()
    finally:
        holder.kill()  # a killed run: the kernel drops its lock, and leaves its file
        holder.communicate()
    assert lock_path(chain).exists()
    assert check_backend(chain, resume=False, overwrite=False) == chain  # no stale lock
    assert not lock_path(chain).exists()  # removed by the run that held it last


_INTERRUPTED_HOLDER = """
import sys
from ctfit._cli.interrupt import install
from ctfit._io import hold_chain
install(lambda: "interrupted")
with hold_chain(sys.argv[1]):
    print("holding", flush=True)
    sys.stdin.read()
"""


def test_an_interrupted_command_leaves_no_lock_file(tmp_path):
    """The command's Ctrl-C exits at once (``os._exit``, no ``finally``): the chain's lock file
    ``.run.h5.lock`` stayed beside it after every interrupted run; it is removed as the run ends."""
    import signal

    chain = tmp_path / "run.h5"
    proc = subprocess.Popen([sys.executable, "-c", _INTERRUPTED_HOLDER, str(chain)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=ROOT)
    assert proc.stdout.readline() == "holding\n" and lock_path(chain).exists()
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert (proc.returncode, err) == (130, "interrupted\n")
    assert not lock_path(chain).exists() and list(tmp_path.iterdir()) == []


def test_the_lock_is_one_per_file_per_thread_and_goes_unlocked_where_it_cannot_be_made(tmp_path, monkeypatch):
    chain = tmp_path / "run.h5"
    refused = []

    def second():
        try:
            with hold_chain(chain):
                pass
        except BlockingIOError as e:
            refused.append(e)

    with hold_chain(chain):
        with hold_chain(chain):  # the thread that holds it: the command's check, then sample()'s
            pass
        assert lock_path(chain).exists()  # still held by the outer block
        worker = threading.Thread(target=second)
        worker.start()
        worker.join()
        assert len(refused) == 1  # another thread of the program: another run
    assert not lock_path(chain).exists()
    with hold_chain(os.devnull), hold_chain(os.devnull):  # a device: nothing to lock
        pass
    monkeypatch.setattr(chain_lock, "lock_path", lambda path: tmp_path / "gone" / ".run.h5.lock")  # a lock that cannot be made
    with hold_chain(chain), hold_chain(chain):
        pass


def test_a_lock_file_removed_by_the_run_that_ends_is_not_taken(tmp_path, monkeypatch):
    """A run that opened the lock file just before the run holding it ended (and removed it)
    gets the lock of a file no longer there: it locks the one at the name instead."""
    chain = tmp_path / "run.h5"
    real_flock = chain_lock.fcntl.flock
    ends = iter([True])

    def flock_after_the_end(fd, how):
        if next(ends, False):
            os.unlink(lock_path(chain))  # the run that held it ends
        return real_flock(fd, how)

    monkeypatch.setattr(chain_lock.fcntl, "flock", flock_after_the_end)
    with hold_chain(chain):
        fd = chain_lock._held[str(lock_path(chain))].fd
        assert os.path.samestat(os.fstat(fd), os.stat(lock_path(chain)))


def _chain(path) -> np.ndarray:
    return emcee.backends.HDFBackend(str(path), name="ctfit", read_only=True).get_chain()


@pytest.mark.slow
def test_the_first_run_ends_whole_while_second_runs_are_refused(tmp_path, monkeypatch):
    """The defect as it was met: while a ``ctfit sample`` writes its chain, ``ctfit sample
    --resume`` and ``--overwrite`` on the same file, started as processes between two of its
    steps, each exit at once with one line; the first run ends with the chain of a run alone."""
    csv, fit_json = tmp_path / "copper.csv", tmp_path / "fit.json"
    assert run("simulate", ROOT / "configs" / "copper-vase.toml", "-o", csv, "--samples", 200, "--seed", 2, "--noise", 0.01,
               "--wavelengths", "400:700:100").exit_code == 0
    assert run("fit", csv, "--lobes", 1, "--no-diffuse", "-o", fit_json).exit_code == 0
    args = ("sample", fit_json, csv, "--steps", 24, "--walkers", 24, "--seed", 3, "-q")
    chain, seconds, calls, original = tmp_path / "run.h5", {}, {"n": 0}, Engine.__call__

    def with_second_runs(self, coords):
        calls["n"] += 1
        if calls["n"] == 1 + 2 * 8:  # 8 steps stored, the file closed until the next
            for flag in ("--resume", "--overwrite"):
                second = [sys.executable, "-m", "ctfit.cli", *map(str, args), "--backend", str(chain), flag, "-o", str(tmp_path / "second.json")]
                seconds[flag] = subprocess.run(second, capture_output=True, text=True, cwd=ROOT, timeout=300)
        return original(self, coords)

    monkeypatch.setattr(Engine, "__call__", with_second_runs)
    first = run(*args, "--backend", chain, "-o", tmp_path / "first.json")
    monkeypatch.setattr(Engine, "__call__", original)
    for flag, second in seconds.items():
        assert (second.returncode, second.stderr, second.stdout) == (2, busy(chain), ""), flag
    assert first.exit_code in (0, 1) and "wrote" in first.output and not (tmp_path / "second.json").exists(), first.output
    alone = run(*args, "--backend", tmp_path / "alone.h5", "-o", tmp_path / "alone.json")
    assert alone.exit_code == first.exit_code
    np.testing.assert_array_equal(_chain(chain), _chain(tmp_path / "alone.h5"))
    assert _chain(chain).shape[:2] == (24, 24) and not lock_path(chain).exists()


def test_a_chain_of_several_names_is_not_continued_in_place(tmp_path, no_work):
    """A chain file with a second name (a hard link: a backup snapshot made with ``cp -al`` or
    rsync's --link-dest) is not continued: the chain is written in place, so the snapshot would
    change too, and the lock, taken by name, would not keep out a run through the other name. The
    file is left as it was; starting again (a new file renamed over the name) stays allowed."""
    import h5py

    chain, snapshot = tmp_path / "run.h5", tmp_path / "snapshot" / "run.h5"
    with h5py.File(chain, "w") as f:
        f.create_dataset("ctfit/chain", data=np.arange(6.0))
    assert check_backend(chain, resume=True, overwrite=False) == chain  # one name: continued
    snapshot.parent.mkdir()
    os.link(chain, snapshot)
    before = chain.read_bytes()
    with pytest.raises(ValueError, match=r"run\.h5: the file has 2 names \(hard links\); a continued chain is written in place"):
        check_backend(chain, resume=True, overwrite=False)
    data, mat = tmp_path / "data.csv", ROOT / "configs" / "copper-vase.toml"
    data.write_text("theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n10,0,10,180,500,1\n")
    r = run("sample", mat, data, "-o", tmp_path / "x.json", "--backend", snapshot, "--resume")
    assert r.exit_code == 2 and r.output.startswith(f"error: --backend {snapshot}: the file has 2 names (hard links)"), r.output
    assert chain.read_bytes() == before and os.path.samefile(chain, snapshot)
    assert check_backend(chain, resume=False, overwrite=True) == chain
