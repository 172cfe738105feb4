"""``ctfit fit --scheduler`` on an external Dask cluster started as separate processes (``dask
scheduler``, ``dask worker``): results equal the serial ones; a worker killed mid-run loses no
finished result (its task runs again on the other worker); a run killed mid-way keeps every
result written, and the re-run fits only the rest."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import ctfit
from ctfit._fitting.many import input_sha256
from ctfit.cli import app

from conftest import ROOT

BIN = Path(sys.executable).parent
N_FILES = 12  # 3 files per task on 2 workers: 4 tasks


def write_folder(folder: Path) -> list[Path]:
    folder.mkdir(parents=True)
    st = ctfit.Structure(lobes=1)
    for i in range(N_FILES):
        mat = ctfit.Material(st, ctfit.Params(m=np.array([0.15 + 0.02 * i]), w=np.array([1.0]), f0=np.array([0.5, 0.8, 0.9])),
                             wavelength_nm=np.array([450.0, 550.0, 650.0]))
        ctfit.write_csv(ctfit.simulate(mat, 300, noise=0.01, seed=i), folder / f"f{i:02d}.csv")
    return sorted(folder.glob("*.csv"))


def start(args: list[str], log: Path) -> subprocess.Popen:
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "CTFIT_PROGRESS": "0"}
    with open(log, "ab") as f:
        return subprocess.Popen(args, stdout=f, stderr=subprocess.STDOUT, env=env, cwd=log.parent)


class Cluster:
    """A scheduler and worker processes of their own (no nanny: killing a worker's process kills the worker)."""

    def __init__(self, folder: Path):
        self.folder, self.file = folder, folder / "scheduler.json"
        self.scheduler = start([str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                                "--scheduler-file", str(self.file)], folder / "scheduler.log")
        self.workers: list[subprocess.Popen] = []
        deadline = time.monotonic() + 60
        while not self.file.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert self.file.exists(), (folder / "scheduler.log").read_text()
        self.address = json.loads(self.file.read_text())["address"]

    def add_worker(self) -> subprocess.Popen:
        w = start([str(BIN / "dask"), "worker", "--scheduler-file", str(self.file), "--nthreads", "1", "--no-nanny", "--no-dashboard",
                   "--name", f"w{len(self.workers)}"], self.folder / f"worker{len(self.workers)}.log")
        self.workers.append(w)
        return w

    def wait_for_workers(self, n: int) -> None:
        from distributed import Client

        with Client(self.address, timeout="30s") as c:
            c.wait_for_workers(n, timeout=60)

    def close(self) -> None:
        """Ask every process to stop, and kill what is still running after ``CLOSE_WAIT`` seconds:
        a worker whose scheduler stopped first (or whose task was cut) waits out its own timeouts
        before it exits (the teardown took 20 s)."""
        for p in [*self.workers, self.scheduler]:
            if p.poll() is None:
                p.terminate()
        deadline = time.monotonic() + CLOSE_WAIT
        for p in [*self.workers, self.scheduler]:
            try:
                p.wait(timeout=max(deadline - time.monotonic(), 0.01))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


CLOSE_WAIT = 3.0


@pytest.fixture
def cluster(tmp_path):
    (tmp_path / "cluster").mkdir()
    made = Cluster(tmp_path / "cluster")
    try:
        yield made
    finally:
        made.close()


def run_cli(args: list[str], log: Path) -> subprocess.Popen:
    return start([str(BIN / "ctfit"), "fit", *args], log)


def results(out: Path) -> dict[str, dict]:
    return {p.name: json.loads(p.read_text()) for p in sorted(out.glob("*.fit.json"))}


def wait_for_results(out: Path, proc: subprocess.Popen, at_least: int = 1) -> None:
    deadline = time.monotonic() + 240
    while len(list(out.glob("*.fit.json"))) < at_least:
        assert proc.poll() is None, "the run ended before writing a result"
        assert time.monotonic() < deadline, "no result in time"
        time.sleep(0.05)


def started_mid_run(cluster: Cluster, args: list[str], log: Path, out: Path) -> tuple[subprocess.Popen, subprocess.Popen]:
    """Two workers, then ``ctfit fit ARGS`` (in ``log``'s folder) until its first result is in
    ``out``: (the first worker, the run)."""
    victim = cluster.add_worker()
    cluster.add_worker()
    cluster.wait_for_workers(2)
    run = run_cli(args, log)
    wait_for_results(out, run)
    return victim, run


def assert_equal_to_serial(out: Path, serial: Path, files: list[Path]) -> None:
    got, want = results(out), results(serial)
    assert sorted(got) == sorted(want) == sorted(f"{p.stem}.fit.json" for p in files)
    for name, doc in got.items():
        assert doc["lobes"] == want[name]["lobes"] and doc["F0"] == want[name]["F0"] and doc["s"] == want[name]["s"], name
        assert doc["fit"]["converged"] is True and doc["name"] == f"fit of {doc['data']}"  # the file as the user named it


@pytest.fixture
def data(tmp_path):
    files = write_folder(tmp_path / "data")
    serial = CliRunner().invoke(app, ["fit", *map(str, files), "-o", str(tmp_path / "serial"), "-q"])
    assert serial.exit_code == 0, serial.output
    return files, tmp_path / "serial"


def test_a_killed_worker_loses_no_result_and_the_run_completes(cluster, data, tmp_path):
    files, serial = data
    out = tmp_path / "out"  # given relative to the run's folder, which is not the workers' folder
    victim, run = started_mid_run(cluster, ["data", "-o", "out", "--scheduler", cluster.address, "-q"], tmp_path / "run.log", out)
    victim.send_signal(signal.SIGKILL)
    victim.wait()
    assert run.wait(timeout=300) == 0, (tmp_path / "run.log").read_text()
    assert_equal_to_serial(out, serial, files)


def test_an_interrupted_run_keeps_its_results_and_the_rerun_fits_the_rest(cluster, data, tmp_path):
    files, serial = data
    out = tmp_path / "out"
    victim, run = started_mid_run(cluster, [str(tmp_path / "data"), "-o", str(out), "--scheduler", str(cluster.file), "-q"], tmp_path / "run.log", out)
    victim.send_signal(signal.SIGKILL)
    run.send_signal(signal.SIGKILL)  # the whole run stops, as a crash or a lost login would stop it
    victim.wait()
    run.wait()
    kept = results(out)  # whole files only (atomic writes), each naming the input it was fitted from
    assert 0 < len(kept) < N_FILES, "the run was not stopped mid-way"
    for name, doc in kept.items():
        assert doc["input_sha256"] == input_sha256(tmp_path / "data" / name.replace(".fit.json", ".csv"))
    rerun = run_cli([str(tmp_path / "data"), "-o", str(out), "--scheduler", str(cluster.file), "-q"], tmp_path / "rerun.log")
    assert rerun.wait(timeout=300) == 0, (tmp_path / "rerun.log").read_text()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["converged"] == N_FILES
    assert sorted(Path(r["data"]).stem + ".fit.json" for r in summary["results"] if r["kept"]) == sorted(kept)
    assert_equal_to_serial(out, serial, files)
    for name, doc in kept.items():  # kept, not written again
        assert results(out)[name] == doc


@pytest.mark.parametrize("text, words", [("garbage\n", "JSON syntax error"), ("{}", "not a Dask scheduler file"),
                                         ("[1, 2]", "not a Dask scheduler file"), (None, "no such file")])
def test_a_scheduler_file_that_is_not_one_is_one_error_line(tmp_path, text, words):
    """--scheduler FILE.json: a missing file is refused at once (distributed waits for it to appear),
    garbage or an object without 'address' in one line (distributed asserts)."""
    target = tmp_path / "scheduler.json"
    if text is not None:
        target.write_text(text)
    csv = tmp_path / "x.csv"
    ctfit.write_csv(ctfit.simulate(ctfit.load_material(ROOT / "configs" / "gold.toml"), 20, wavelength_nm=[500.0, 600.0]), csv)
    r = CliRunner().invoke(app, ["fit", str(csv), "-o", str(tmp_path / "out"), "--scheduler", str(target)])
    assert r.exit_code == 2, r.output
    errors = [ln for ln in r.output.splitlines() if ln.startswith("error:")]
    assert len(errors) == 1 and words in errors[0] and str(target) in errors[0] and "Traceback" not in r.output


def test_a_scheduler_nobody_runs_is_given_up_after_the_timeout(tmp_path, monkeypatch):
    """A loopback port nothing listens on: an OSError after CONNECT_TIMEOUT, not a hang."""
    import socket

    from ctfit._runtime import cluster

    with socket.socket() as s:  # a free loopback port, closed again: nothing listens there
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    (tmp_path / "s.json").write_text(json.dumps({"address": f"tcp://127.0.0.1:{port}"}))
    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT", "1s")
    with pytest.raises(OSError, match=f"127.0.0.1:{port}"):
        with cluster.dask_client(scheduler=str(tmp_path / "s.json")):
            pass


def test_a_stored_result_is_kept_only_if_it_loads_as_a_material(tmp_path):
    """A result of the same input and options edited since (s = 2) is fitted again, not counted
    as "converged (kept)" (``ctfit color`` then refused it)."""
    from ctfit._cli.fit_cluster import _kept_result

    doc = {"s": 1.0, "lobes": [{"m": 0.2}], "wavelength_nm": [450.0], "F0": [0.5], "data": "a.csv", "input_sha256": "ab" * 32,
           "fit_options": {"lobes": "1"}, "fit": {"converged": True}}
    target = tmp_path / "a.fit.json"
    target.write_text(json.dumps(doc))
    assert _kept_result(target, "ab" * 32, {"lobes": "1"}) == "converged"
    target.write_text(json.dumps(dict(doc, s=2.0)))
    assert _kept_result(target, "ab" * 32, {"lobes": "1"}) is None


def test_a_changed_optical_constants_table_is_a_changed_material(tmp_path):
    """The rerun's record of --material holds the optical constants CSV it loads too: a table
    edited since (every n halved) changed the fixed F0, and the rerun kept the old fits."""
    from types import SimpleNamespace

    from ctfit._cli.fit_cluster import _fit_options_record

    (tmp_path / "oc.csv").write_text("wavelength_nm,n,k\n400,1.2,2.1\n700,0.3,4.0\n")
    (tmp_path / "cu.toml").write_text('s = 1\nlobes = [{ m = 0.2 }]\noptical_constants = "oc.csv"\nfixed = ["f0"]\n')
    o = SimpleNamespace(family="auto", lobes="1", geometry=None, fresnel=None, no_diffuse=True, diffuse=None, loss="auto", solver="lm", float32=False,
                        starts=3, max_steps=256, param_out=None, material=tmp_path / "cu.toml")
    before = _fit_options_record(o)
    assert before["material"] == f"{input_sha256(tmp_path / 'cu.toml')}+{input_sha256(tmp_path / 'oc.csv')}"
    (tmp_path / "oc.csv").write_text("wavelength_nm,n,k\n400,0.6,2.1\n700,0.15,4.0\n")
    assert _fit_options_record(o)["material"] != before["material"]
    (tmp_path / "plain.toml").write_text("s = 1\nlobes = [{ m = 0.2 }]\nF0 = 0.9\n")
    assert _fit_options_record(SimpleNamespace(**{**vars(o), "material": tmp_path / "plain.toml"}))["material"] == input_sha256(tmp_path / "plain.toml")


@pytest.fixture
def in_process_cluster(monkeypatch):
    """``--workers`` on a cluster of one worker thread in this process (no worker processes to start;
    this process's patches reach the worker)."""
    import contextlib

    from distributed import Client

    import ctfit._runtime as runtime
    from ctfit._runtime import cluster

    @contextlib.contextmanager
    def in_process(client=None, **_):
        if client is not None:
            yield client
            return
        with Client(processes=False, n_workers=1, threads_per_worker=1, dashboard_address=":0") as made:
            yield made

    monkeypatch.setattr(runtime, "dask_client", in_process)
    monkeypatch.setattr(cluster, "_prepared", {False, True})  # this process is the worker: leave its JAX set-up as it is


def test_a_file_rewritten_after_it_was_hashed_carries_the_hash_of_the_bytes_fitted(in_process_cluster, tmp_path, monkeypatch):
    """The run hashes a file whose result is stored (here one of other options) before any worker
    reads it: a file rewritten in between is fitted as it is then, and its result (and summary row)
    carries the hash of those bytes, not the old one — else the old bytes put back would keep that
    fit of other data as this file's."""
    import ctfit._fitting as fitting

    st = ctfit.Structure(lobes=1)
    old, new = tmp_path / "old.csv", tmp_path / "new.csv"
    for m, path in ((0.2, old), (0.4, new)):
        mat = ctfit.Material(st, ctfit.Params(m=np.array([m]), w=np.array([1.0]), f0=np.array([0.5, 0.8])), wavelength_nm=np.array([450.0, 650.0]))
        ctfit.write_csv(ctfit.simulate(mat, 200, noise=0.01, seed=1), path)
    (tmp_path / "db").mkdir()
    target, out = tmp_path / "db" / "x.csv", tmp_path / "out"
    target.write_bytes(old.read_bytes())
    real, rewritten = fitting.input_sha256, []

    def hash_then_rewrite(path):
        sha = real(path)
        if Path(path) == target and not rewritten:  # once, just after the run hashed the old bytes
            target.write_bytes(new.read_bytes())
            rewritten.append(sha)
        return sha

    args = ["fit", str(tmp_path / "db"), "-o", str(out), "--workers", "1", "--family", "metal", "--lobes", "1", "--diffuse", "F0/pi", "-q"]
    assert CliRunner().invoke(app, [*args, "--max-steps", "100"]).exit_code == 0  # a stored result, of other options: the run hashes the file
    monkeypatch.setattr(fitting, "input_sha256", hash_then_rewrite)
    first = CliRunner().invoke(app, args)
    assert first.exit_code == 0, first.output
    assert rewritten == [input_sha256(old)]
    doc = json.loads((out / "x.fit.json").read_text())
    assert doc["lobes"][0]["m"] == pytest.approx(0.4, rel=0.05)  # the new bytes were fitted ...
    assert doc["input_sha256"] == input_sha256(new)  # ... and the result says so
    assert [r["input_sha256"] for r in json.loads((out / "summary.json").read_text())["results"]] == [input_sha256(new)]
    monkeypatch.setattr(fitting, "input_sha256", real)
    target.write_bytes(old.read_bytes())  # the old bytes back: fitted again, not "kept"
    again = CliRunner().invoke(app, args[:-1])
    assert again.exit_code == 0, again.output
    assert "kept" not in again.output
    doc = json.loads((out / "x.fit.json").read_text())
    assert doc["lobes"][0]["m"] == pytest.approx(0.2, rel=0.05) and doc["input_sha256"] == input_sha256(old)


def test_a_worker_reads_again_a_file_that_changed_while_it_read_it(tmp_path, monkeypatch):
    """The hash a worker returns is of the bytes it parsed: a file that changed during the read is
    read again; one that changes at every read fails, named as the user gave it."""
    from ctfit._fitting import many

    mat = ctfit.load_material(ROOT / "configs" / "gold.toml")
    versions = [tmp_path / f"v{i}.csv" for i in range(many.READ_TRIES + 1)]
    for i, path in enumerate(versions):
        ctfit.write_csv(ctfit.simulate(mat, 20 + i, wavelength_nm=[500.0, 600.0], seed=i), path)
    target = tmp_path / "x.csv"
    target.write_bytes(versions[0].read_bytes())
    real, reads = many.read_input, []

    def read_then_rewrite(path, param_out=None, changes=1):
        got = real(path, param_out)
        reads.append(len(got))
        if len(reads) <= changes:
            target.write_bytes(versions[len(reads)].read_bytes())
        return got

    monkeypatch.setattr(many, "read_input", read_then_rewrite)
    meas, sha = many._read_hashed(("x.csv", str(target)), None)
    sizes = [len(ctfit.read_csv(v)) for v in versions]  # each version of its own size
    assert reads == sizes[:2] and len(meas) == sizes[1] and sha == input_sha256(versions[1]) and meas.source == "x.csv"
    target.write_bytes(versions[0].read_bytes())
    reads.clear()
    monkeypatch.setattr(many, "read_input", lambda path, param_out=None: read_then_rewrite(path, param_out, changes=many.READ_TRIES))
    with pytest.raises(ValueError, match=r"^x\.csv: changed while it was read"):
        many._read_hashed(("x.csv", str(target)), None)
    assert len(reads) == many.READ_TRIES


def test_ctrl_c_at_the_terminal_ends_a_local_cluster_run_with_one_line(tmp_path):
    """Ctrl-C reaches the whole process group: each worker of ``--workers`` printed a traceback
    (KeyboardInterrupt inside Dask's nanny) before the command's line. Workers start with SIGINT
    ignored; the command shuts them down: status 130, one 'interrupted' line, no process left."""
    st = ctfit.Structure(lobes=1)
    (tmp_path / "data").mkdir()
    for i in range(40):  # enough work that the workers are busy when the signal comes
        mat = ctfit.Material(st, ctfit.Params(m=np.array([0.15 + 0.005 * i]), w=np.array([1.0]), f0=np.array([0.5, 0.8, 0.9])),
                             wavelength_nm=np.array([450.0, 550.0, 650.0]))
        ctfit.write_csv(ctfit.simulate(mat, 1500, noise=0.01, seed=i), tmp_path / "data" / f"f{i:02d}.csv")
    out, log = tmp_path / "out", tmp_path / "run.log"
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "CTFIT_PROGRESS": "0"}
    with open(log, "ab") as f:
        run = subprocess.Popen([str(BIN / "ctfit"), "fit", str(tmp_path / "data"), "-o", f"{out}/", "--workers", "2", "-q"], stdout=f,
                               stderr=subprocess.STDOUT, env=env, cwd=tmp_path, start_new_session=True)
    wait_for_results(out, run)  # the workers are fitting
    os.killpg(run.pid, signal.SIGINT)  # as a terminal does: the command and every process it started
    assert run.wait(timeout=120) == 130
    text = log.read_text()
    assert "Traceback" not in text and "KeyboardInterrupt" not in text, text
    assert sum(line.startswith("interrupted") for line in text.splitlines()) == 1, text
    deadline = time.monotonic() + 30
    while (left := subprocess.run(["ps", "-o", "pid=,stat=,args=", "-g", str(run.pid)], capture_output=True, text=True).stdout.strip()):
        assert time.monotonic() < deadline, left
        time.sleep(0.2)
