"""``fit_many`` on a real ``LocalCluster`` (2 worker processes, 1 thread each): results equal the
serial ones in input order, files and measurements alike; a bad file is returned in its place;
files of the same geometry share a task; ``ctfit fit --workers`` writes, summarises and resumes."""

import json
import os

import numpy as np
import pytest
from typer.testing import CliRunner

import ctfit
from ctfit._fitting.many import _tasks, geometry_key, input_sha256
from ctfit._runtime.cluster import dask_client
from ctfit._runtime.compile_cache import _default
from ctfit.cli import app

WL = np.array([450.0, 650.0])
ST = ctfit.Structure(lobes=1)


def one_lobe(m, seed, n_pairs=100):
    mat = ctfit.Material(ST, ctfit.Params(m=np.array([m]), w=np.array([1.0]), f0=np.array([0.6, 0.9])), wavelength_nm=WL)
    return ctfit.simulate(mat, n_pairs, noise=0.01, seed=seed)


def write_folder(folder, n=5, bad=True):
    """``n`` CSV files (two geometries: 100 and 80 direction pairs) and, with ``bad``, one that cannot be read."""
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        ctfit.write_csv(one_lobe(0.2 + 0.02 * i, seed=i, n_pairs=100 if i % 2 else 80), folder / f"f{i}.csv")
    if bad:
        (folder / "bad.csv").write_text("not,a,measurement\n1,2,3\n")
    return sorted(folder.glob("f*.csv"))


@pytest.fixture(scope="module")
def client():
    with dask_client(workers=2) as c:
        yield c


def same_fit(a, b):
    for name in ("s", "m", "w", "f0", "rd"):
        pa, pb = getattr(a.material.params, name), getattr(b.material.params, name)
        assert (pa is None) == (pb is None), name
        if pa is not None:
            np.testing.assert_allclose(np.asarray(pa), np.asarray(pb), rtol=1e-8, err_msg=name)
    assert a.stats["converged"] == b.stats["converged"]
    np.testing.assert_allclose(a.stats["cost"], b.stats["cost"], rtol=1e-8)


def test_files_on_a_local_cluster_equal_the_serial_fits_in_input_order(client, tmp_path):
    files = write_folder(tmp_path, bad=False)
    seen = []
    got = ctfit.fit_many(files[::-1], ST, client, on_result=lambda i, r: seen.append(i))
    assert sorted(seen) == list(range(len(files)))
    for path, res in zip(files[::-1], got):
        same_fit(res, ctfit.fit(ctfit.read_measurement(path), ST))
    folders = client.run(_cache_folder)  # every worker keeps its compiled programs on disk
    expected = os.environ.get("JAX_COMPILATION_CACHE_DIR") or str(_default())
    assert len(folders) == 2 and set(folders.values()) == {expected}


def _cache_folder():
    import jax

    return jax.config.jax_compilation_cache_dir


def test_measurements_and_a_bad_file_in_its_place(client, tmp_path, monkeypatch):
    files = write_folder(tmp_path, n=2)
    monkeypatch.chdir(tmp_path)  # not the workers' folder: paths given relative to this one
    items = [one_lobe(0.3, seed=7), "bad.csv", files[1].name]
    got = ctfit.fit_many(items, ST, client, return_errors=True)
    assert isinstance(got[1], ValueError) and str(got[1]).startswith("bad.csv:")  # named as given
    assert got[2].material.name == f"fit of {files[1].name}"
    same_fit(got[0], ctfit.fit(items[0], ST))
    same_fit(got[2], ctfit.fit(ctfit.read_measurement(files[1]), ST))
    with pytest.raises(ValueError, match="bad.csv"):
        ctfit.fit_many(items, ST, client)


def test_public_names():
    assert {"fit_many", "fit_texel_maps"} <= set(ctfit.__all__)
    assert ctfit.fit_many.__module__ == "ctfit._fitting.many" and ctfit.fit_texel_maps.__module__ == "ctfit._fitting.texel_maps"


def test_same_geometry_shares_a_task_and_tasks_stay_coarse():
    a, b = one_lobe(0.2, 0, n_pairs=50), one_lobe(0.3, 1, n_pairs=60)
    assert geometry_key(a) == geometry_key(a.replace(brdf=a.brdf * 2)) != geometry_key(b)
    keys = [geometry_key(m) for m in (a, b, a, b, a)] + [ValueError("unreadable")]
    settled = []
    tasks = _tasks(keys, None, 1, lambda i, e: settled.append(i))
    assert settled == [5]
    assert sorted(map(sorted, tasks)) == [[0, 2, 4], [1, 3]]
    assert _tasks(keys[:5], 2, 1, None) == [[0, 2], [4], [1, 3]]


def test_options_are_checked_and_a_made_cluster_is_closed():
    data = one_lobe(0.2, 0)
    with pytest.raises(ValueError, match="files_per_task"):
        ctfit.fit_many([data], ST, files_per_task=0)
    with pytest.raises(ValueError, match="one Params"):
        ctfit.fit_many([data], ST, start=[None])
    assert ctfit.fit_many([], ST) == []
    with dask_client(workers=1) as made:
        assert made.status == "running" and len(made.scheduler_info()["workers"]) == 1
        (got,) = ctfit.fit_many([data], ST, made)
    assert made.status == "closed"
    same_fit(got, ctfit.fit(data, ST))


runner = CliRunner()


def test_cli_workers_writes_summarises_and_skips_what_is_done(tmp_path):
    files = write_folder(tmp_path / "data")
    out = tmp_path / "out"
    named = ["--family", "metal", "--lobes", "1", "--diffuse", "F0/pi"]  # the workers' bookkeeping, not the data-chosen default (tested apart)
    first = runner.invoke(app, ["fit", str(tmp_path / "data"), "-o", str(out), "--workers", "2", *named])
    assert first.exit_code == 2, first.output  # the bad file
    summary = json.loads((out / "summary.json").read_text())
    assert (summary["converged"], summary["failed"]) == (5, 1)
    bad = next(r for r in summary["results"] if r["outcome"] == "failed")
    assert bad["data"].endswith("bad.csv") and "theta_i" in bad["reason"]
    serial = runner.invoke(app, ["fit", *map(str, files), "-o", str(tmp_path / "serial"), *named])
    assert serial.exit_code == 0, serial.output
    for path in files:
        doc = json.loads((out / f"{path.stem}.fit.json").read_text())
        assert doc["input_sha256"] == input_sha256(path)
        alone = json.loads((tmp_path / "serial" / f"{path.stem}.fit.json").read_text())
        assert doc["lobes"] == alone["lobes"] and doc["F0"] == alone["F0"] and doc["s"] == alone["s"]
        assert doc["fit"]["cost"] == pytest.approx(alone["fit"]["cost"], rel=1e-12)
    (out / "f3.fit.json").unlink()
    ctfit.write_csv(one_lobe(0.4, seed=9, n_pairs=100), files[1])  # changed input: fitted again
    again = runner.invoke(app, ["fit", str(tmp_path / "data"), "-o", str(out), "--workers", "2", *named], env={"CTFIT_PROGRESS": "1"})
    assert "tasks:" in again.output  # a bar over the tasks
    rows = {r["data"].rsplit("/", 1)[-1]: r for r in json.loads((out / "summary.json").read_text())["results"]}
    assert [name for name, r in rows.items() if not r["kept"] and r["outcome"] == "converged"] == ["f1.csv", "f3.csv"], again.output
    assert json.loads((out / "f1.fit.json").read_text())["lobes"][0]["m"] == pytest.approx(0.4, rel=0.05)


@pytest.mark.parametrize("args, message", [
    (["--workers", "2"], "needs -o"),
    (["--workers", "2", "-o", "OUT", "--sample"], "leave out --sample"),
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:1", "-o", "OUT"], "give one of them"),
])
def test_cli_cluster_options_are_refused_before_any_work(tmp_path, args, message):
    files = write_folder(tmp_path / "data", n=2, bad=False)
    got = runner.invoke(app, ["fit", *map(str, files), *[a.replace("OUT", str(tmp_path / "out")) for a in args]])
    assert got.exit_code == 2 and message in got.output
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_a_data_chosen_structure_keeps_the_candidates_asked_for(client, tmp_path):
    """``ctfit fit DIR --family plastic --lobes 1 --workers N`` chose among every family and lobe
    count (the workers called ``ctfit.fit``'s default) and wrote the options it had not used into
    the result; ``choice`` (``choose_structure``'s candidates) now reaches the workers, and the
    result is the one fitted in this process."""
    data = one_lobe(0.2, 3)
    choice = dict(families=("plastic",), lobes=(1,))
    (got,) = ctfit.fit_many([data], None, client, choice=choice)
    alone = ctfit.choose_structure(data, **choice)[0]
    assert [row["structure"] for row in got.stats["structure_choice"]] == [row["structure"] for row in alone.stats["structure_choice"]]
    assert got.material.structure == alone.material.structure and got.material.structure.family == "plastic"
    assert all(row["structure"].startswith("plastic, 1 lobe,") for row in got.stats["structure_choice"])
    ctfit.write_csv(data, (tmp_path / "data").mkdir() or tmp_path / "data" / "a.csv")
    r = runner.invoke(app, ["fit", str(tmp_path / "data"), "-o", str(tmp_path / "out"), "--workers", "1", "--family", "plastic", "--lobes", "1"])
    doc = json.loads((tmp_path / "out" / "a.fit.json").read_text())
    assert r.exit_code in (0, 1), r.output
    assert doc["family"] == "plastic" and all(row["structure"].startswith("plastic, 1 lobe,") for row in doc["fit"]["structure_choice"])


def test_a_local_cluster_larger_than_the_machine_is_refused_by_name(tmp_path):
    """``--workers 10**20`` started worker processes until it was killed; now it is refused
    before any work, naming the limit (4 per usable core), and the library says the same."""
    from ctfit._io import usable_cores
    from ctfit._runtime import LOCAL_WORKERS_PER_CORE, check_local_workers

    limit = LOCAL_WORKERS_PER_CORE * usable_cores()
    check_local_workers(limit)
    with pytest.raises(ValueError, match=f"at most {limit} worker processes"):
        check_local_workers(limit + 1)
    with pytest.raises(ValueError, match=f"at most {limit} worker processes"), dask_client(workers=10**20):
        pass
    data = tmp_path / "data"
    data.mkdir()
    (data / "a.csv").write_text("theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n10,0,10,180,550,1.0\n")
    r = CliRunner().invoke(app, ["fit", str(data), "-o", str(tmp_path / "out"), "--workers", str(10**20)])
    assert r.exit_code == 2, r.output
    assert "--workers 100000000000000000000" in r.output and f"at most {limit} worker processes" in r.output, r.output
    assert not (tmp_path / "out").exists()
