"""``ctfit fit`` over several files: per-file errors, summary, exit status, distinct and kept results,
--param-out, option checks before any work, progress bars, warnings and 'wrote' lines."""

import importlib
import json
import re
import threading
import warnings
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

import ctfit
from ctfit._cli.inputs import read_data as _read_data
from ctfit.cli import app

WL = np.array([450.0, 650.0])
BAR = re.compile(r"files:\s+\d+%")
runner = CliRunner()


def run(*args, **kw):
    return runner.invoke(app, [str(a) for a in args], **kw)


def one_lobe(m=0.25, n_pairs=120, seed=0, wavelengths=WL):
    f0 = np.linspace(0.6, 0.9, len(wavelengths))
    mat = ctfit.Material(ctfit.Structure(lobes=1), ctfit.Params(m=np.array([m]), w=np.array([1.0]), f0=f0), wavelength_nm=wavelengths)
    return ctfit.simulate(mat, n_pairs, noise=0.01, seed=seed)


def write(folder, name, **kw):
    folder.mkdir(parents=True, exist_ok=True)
    ctfit.write_csv(one_lobe(**kw), folder / name)
    return folder / name


def write_alta(path, param_out_line, cosine=False, horizon_row=False):
    """A one-band measurement as ALTA text (ISOTROPIC_TL_TV_PROJ_DPHI), values × cos θ_o with ``cosine``."""
    m = one_lobe(n_pairs=80, wavelengths=np.array([550.0]))
    th_i, th_o = np.deg2rad(m.theta_i), np.deg2rad(m.theta_o)
    dphi = np.deg2rad(m.phi_o - m.phi_i)
    values = m.brdf * (np.cos(th_o) if cosine else 1.0)
    rows = [f"{a:.17g} {t * np.cos(d):.17g} {t * np.sin(d):.17g} {v:.17g}" for a, t, d, v in zip(th_i, th_o, dphi, values)]
    if horizon_row:
        rows.append(f"0.1 {np.pi / 2:.17g} 0.0 0.5")
    head = ["#DIM 3 1", "#PARAM_IN ISOTROPIC_TL_TV_PROJ_DPHI"] + ([f"#PARAM_OUT {param_out_line}"] if param_out_line else [])
    path.write_text("\n".join(head + rows) + "\n")
    return path, values


def summary(stderr):
    return [line for line in stderr.splitlines() if line.startswith("  ")]


def test_batch_goes_on_after_a_bad_file_and_summarises(tmp_path):
    data = tmp_path / "data"
    write(data, "a.csv", seed=1)
    (data / "b.csv").write_text("theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n10,0,95,180,450,0.5\n")
    write(data, "c.csv", seed=2)
    out = tmp_path / "fits"
    r = run("fit", data, "--no-diffuse", "--lobes", "1", "-o", out)
    assert r.exit_code == 2, r.output
    errors = [line for line in r.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and errors[0].startswith(f"error: {data / 'b.csv'}:2") and "theta_o" in errors[0]
    assert "summary: 3 files: 2 converged, 0 did not converge, 1 failed" in r.stderr
    lines = summary(r.stderr)
    assert [line.split()[0] for line in lines] == ["converged", "failed", "converged"]
    assert "theta_o" in lines[1]
    assert sorted(p.name for p in out.iterdir()) == ["a.fit.json", "c.fit.json", "summary.json"]
    rows = json.loads((out / "summary.json").read_text())["results"]
    assert [(row["outcome"], row["result"]) for row in rows] == [
        ("converged", str(out / "a.fit.json")), ("failed", None), ("converged", str(out / "c.fit.json"))]
    assert r.stdout.count("fit of ") == 2


def test_a_batch_stopped_by_an_unexpected_error_ends_its_threads_at_once(tmp_path, monkeypatch):
    """The windows' reader and fitter threads end when the batch stops, in the command's thread,
    not whenever the garbage collector meets the abandoned generator (which once closed it inside
    Python's lock of thread starts: the next command in the process hung for good)."""
    import ctfit._cli.fit_command as fit_command

    data = tmp_path / "data"
    for k in range(3):
        write(data, f"{k}.csv", seed=k)

    def broken(*args, **kw):
        raise RuntimeError("a report that fails")

    monkeypatch.setattr(fit_command, "report_file", broken)
    before = set(threading.enumerate())
    r = run("fit", data, "--no-diffuse", "--lobes", "1", "-o", tmp_path / "fits")
    assert r.exit_code != 0 and isinstance(r.exception, RuntimeError)  # the result keeps the traceback, and so the frames
    left = [t.name for t in set(threading.enumerate()) - before if t.name.startswith(("ctfit-read", "ctfit-fit", "ctfit-write", "ThreadPoolExecutor-"))]
    assert not left, left


def test_a_window_is_fitted_as_soon_as_it_is_read_while_the_one_before_is_reported(monkeypatch):
    """A window's fit starts when its reading ends (on a free fitting thread), not when the caller,
    reporting the window before, asks for the next; at most three windows are held at once."""
    import time

    import ctfit._cli.fit_command as fit_command

    files = [f"{k}.csv" for k in range(10)]
    events, held, lock = [], [0], threading.Lock()

    def note(*what):
        with lock:
            events.append(what)

    def read(chunk, o, base):  # two files a window
        with lock:
            held[0] += 1
            assert held[0] <= 3, "more than three windows held"
        note("read", chunk[0])
        return [(p, None, None) for p in chunk[:2]], {}, ()

    def fit(ready, failed, fixed, o, base):
        note("fit", ready[0][0])
        time.sleep(0.02)
        return {p: (None, None) for p, _, _ in ready}

    monkeypatch.setattr(fit_command, "_read_window", read)
    monkeypatch.setattr(fit_command, "_fit_window", fit)
    got = []
    for window in fit_command._windows(files, None, None):
        note("report", next(iter(window)))
        time.sleep(0.3)  # a slow caller: the next windows are read and fitted meanwhile
        got += list(window)
        note("reported", next(iter(window)))
        with lock:
            held[0] -= 1
    assert got == files
    at = {e: i for i, e in enumerate(events)}
    assert at[("fit", "4.csv")] < at[("reported", "0.csv")]  # the third window's fit began while the first was reported
    assert at[("read", "6.csv")] > at[("reported", "0.csv")]  # and the fourth is read only once the first is done


def test_a_result_that_cannot_be_written_fails_that_file_alone(tmp_path, monkeypatch):
    """Among files fitted together, a result write that fails (a full disk) makes its file
    "failed", with one error line naming the file and the target, and every other file is written
    and said to be, all before the summary."""
    import ctfit._io as io

    data = tmp_path / "data"
    for name, seed in (("a.csv", 1), ("b.csv", 2), ("c.csv", 3)):
        write(data, name, seed=seed)
    out = tmp_path / "fits"
    write_atomically = io.atomic_write

    def failing(path, *args, **kwargs):
        if Path(path).name == "b.fit.json":
            raise OSError(28, "No space left on device", str(path))
        return write_atomically(path, *args, **kwargs)

    monkeypatch.setattr(io, "atomic_write", failing)  # (where every result file is written: a folder's through write_own_result)
    monkeypatch.setattr(importlib.import_module("ctfit._io.output_paths"), "atomic_write", failing)
    r = run("fit", data, "--no-diffuse", "--lobes", "1", "-o", out)
    assert r.exit_code == 2, r.output
    assert [line.split()[0] for line in summary(r.stderr)] == ["converged", "failed", "converged"]
    errors = [line for line in r.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and str(data / "b.csv") in errors[0] and str(out / "b.fit.json") in errors[0], errors
    assert "no space left" in errors[0]
    lines = r.stderr.splitlines()
    wrote = [line for line in lines if line.startswith("wrote ")]
    assert wrote == [f"wrote {out / 'a.fit.json'}", f"wrote {out / 'c.fit.json'}", f"wrote {out / 'summary.json'}"]
    head = next(i for i, line in enumerate(lines) if line.startswith("summary:"))
    assert lines.index(f"wrote {out / 'c.fit.json'}") < head and lines.index(errors[0]) < head
    assert sorted(p.name for p in out.iterdir()) == ["a.fit.json", "c.fit.json", "summary.json"]
    rows = json.loads((out / "summary.json").read_text())["results"]
    assert [row["outcome"] for row in rows] == ["converged", "failed", "converged"]
    assert r.stdout.count("fit of ") == 3  # b's table was printed before its write failed


@pytest.mark.parametrize("lobes", ["1", "auto"])  # fitted together (a window), and one by one
def test_the_summary_hashes_each_file_as_it_was_read(tmp_path, monkeypatch, lobes):
    """summary.json's input_sha256 is the hash of the content that was fitted: a file rewritten
    once the run has read it (an instrument writing its next scan) keeps the hash of its first
    content, which is read once."""
    import hashlib

    from ctfit._cli import fit_command

    data = tmp_path / "data"
    paths = [write(data, name, seed=seed) for name, seed in (("a.csv", 1), ("b.csv", 2), ("c.csv", 3), ("d.csv", 4))]
    before = {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in paths}
    report = fit_command.report_file

    def rewriting(path, *args, **kwargs):  # each file rewritten before its result is reported
        got = report(path, *args, **kwargs)
        Path(path).write_text(Path(path).read_text() + "# rewritten\n")
        return got

    monkeypatch.setattr(fit_command, "report_file", rewriting)
    out = tmp_path / "fits"
    r = run("fit", data, "--no-diffuse", "--lobes", lobes, "-o", out)
    assert r.exit_code == 0, r.output
    rows = json.loads((out / "summary.json").read_text())["results"]
    assert {Path(row["data"]).name: row["input_sha256"] for row in rows} == before
    assert all(hashlib.sha256(p.read_bytes()).hexdigest() != before[p.name] for p in paths)


def test_exit_1_when_a_fit_does_not_converge_and_none_failed(tmp_path):
    data = tmp_path / "data"
    write(data, "a.csv", seed=1)
    write(data, "b.csv", seed=2)
    r = run("fit", data, "--no-diffuse", "--lobes", "1", "--max-steps", 1)
    assert r.exit_code == 1, r.output
    assert "0 converged, 2 did not converge, 0 failed" in r.stderr
    assert [line.split()[:2] for line in summary(r.stderr)] == [["not", "converged"]] * 2


def test_same_file_names_in_two_folders_get_distinct_results(tmp_path):
    a = write(tmp_path / "a", "x.csv", m=0.2, seed=1)
    b = write(tmp_path / "b", "x.csv", m=0.4, seed=2)
    out, plots = tmp_path / "fits", tmp_path / "plots"
    r = run("fit", a, b, "--no-diffuse", "--lobes", "1", "-o", out, "--plot", plots)
    assert r.exit_code == 0, r.output
    docs = {p.name: json.loads(p.read_text()) for p in out.iterdir()}
    assert sorted(docs) == ["a-x.fit.json", "b-x.fit.json", "summary.json"]
    assert docs["a-x.fit.json"]["lobes"][0]["m"] == pytest.approx(0.2, rel=0.02)
    assert docs["b-x.fit.json"]["lobes"][0]["m"] == pytest.approx(0.4, rel=0.02)
    assert sorted(p.name for p in plots.iterdir()) == ["a-x.fit.png", "b-x.fit.png"]


def test_a_fit_that_does_not_converge_keeps_a_converged_result(tmp_path):
    csv = write(tmp_path, "d.csv")
    target = tmp_path / "d.fit.json"
    assert run("fit", csv, "--no-diffuse", "--lobes", "1", "-o", target).exit_code == 0
    good = target.read_bytes()
    r = run("fit", csv, "--no-diffuse", "--lobes", "1", "-o", target, "--max-steps", 1)
    assert r.exit_code == 1, r.output
    assert target.read_bytes() == good
    beside = tmp_path / "d.fit.not-converged.json"
    assert json.loads(beside.read_text())["fit"]["converged"] is False
    assert f"{target} holds a converged fit and is kept" in r.stderr
    assert f"wrote {beside}" in r.stderr.splitlines()


def test_param_out_applies_only_to_files_without_the_line(tmp_path):
    own, values = write_alta(tmp_path / "own.alta", "INV_STERADIAN")
    # The file's own line wins over --param-out (before: "contradicts param_out=...", exit 2).
    m = _read_data(own, "INV_STERADIAN_COSINE_FACTOR")
    assert m.meta["alta_param_out"] == "INV_STERADIAN"
    np.testing.assert_allclose(m.brdf, values)
    bare, cos_values = write_alta(tmp_path / "bare.alta", None, cosine=True)
    m = _read_data(bare, "INV_STERADIAN_COSINE_FACTOR")
    assert m.meta["alta_param_out"] == "INV_STERADIAN_COSINE_FACTOR"
    np.testing.assert_allclose(m.brdf, one_lobe(n_pairs=80, wavelengths=np.array([550.0])).brdf, rtol=1e-12)
    r = run("fit", own, bare, "--no-diffuse", "--lobes", "1", "--param-out", "INV_STERADIAN_COSINE_FACTOR")
    assert r.exit_code == 0, r.output
    assert "2 converged" in r.stderr


def test_a_missing_param_out_names_the_option(tmp_path):
    bare, _ = write_alta(tmp_path / "bare.alta", None)
    r = run("fit", bare)
    assert r.exit_code == 2
    assert "--param-out" in r.stderr and "param_out=" not in r.stderr


def test_a_param_out_of_other_outputs_than_the_files_dim_is_the_options_fault(tmp_path):
    """--param-out RGB_COLOR on a file of one output (no #PARAM_OUT line) said "DIM says 1
    outputs, RGB_COLOR has 3", blaming the file; the option is named, with the units that fit."""
    from conftest import MEASURED, ROOT

    tape = MEASURED / "retro-gray-tape.dat"
    for command in (("fit", tape), ("eval", ROOT / "configs" / "copper.toml", tape, "-o", tmp_path / "e.csv")):
        r = run(*command, "--param-out", "RGB_COLOR")
        assert r.exit_code == 2, r.output
        assert (f"{tape}:4: #DIM says 1 outputs, and --param-out='RGB_COLOR' (the file has no #PARAM_OUT line) has 3: "
                "give one of INV_STERADIAN, INV_STERADIAN_COSINE_FACTOR") in r.stderr, r.stderr
    assert not (tmp_path / "e.csv").exists()


@pytest.mark.parametrize(
    "args, option",
    [
        (("fit", "{csv}", "--starts", 0), "--starts"),
        (("fit", "{csv}", "--starts", -2), "--starts"),
        (("fit", "{csv}", "--max-steps", 0), "--max-steps"),
        (("fit", "{csv}", "--sample", "--steps", 0), "--steps"),
        (("fit", "{csv}", "--sample", "--walkers", 1), "--walkers"),
        (("fit", "{csv}", "--sample", "--walkers", 33), "--walkers"),
        (("fit", "{csv}", "--sample", "--thin", 0), "--thin"),
        (("fit", "{csv}", "--sample", "--burn", -1), "--burn"),
        (("fit", "{csv}", "--sample", "--steps", 10, "--burn", 10), "--burn"),
        (("fit", "{csv}", "--lobes", 0), "--lobes"),
        (("fit", "{csv}", "--loss", "huber"), "--loss"),
        (("fit", "{csv}", "--solver", "newton"), "--solver"),
        (("sample", "{csv}", "{csv}", "--steps", 0), "--steps"),
        (("sample", "{csv}", "{csv}", "--walkers", 0), "--walkers"),
        (("simulate", "{toml}", "--samples", 0), "--samples"),
        (("simulate", "{toml}", "--noise", -0.1), "--noise"),
        (("simulate", "{toml}", "--max-theta", 95), "--max-theta"),
        (("simulate", "{toml}", "--max-theta", 90), "--max-theta"),
        (("render", "{toml}", "--size", 0), "--size"),
        (("render", "{toml}", "--supersample", 0), "--supersample"),
        (("render", "{toml}", "--columns", 0), "--columns"),
    ],
)
def test_bad_counts_are_refused_before_any_work(tmp_path, args, option):
    from conftest import ROOT

    csv = tmp_path / "d.csv"
    csv.write_text("theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n10,0,10,180,450,0.5\n")
    args = [str(a).format(csv=csv, toml=ROOT / "configs" / "gold.toml") for a in args]
    out = tmp_path / "out.json"
    r = run(*args, "-o", out)
    assert r.exit_code == 2, r.output
    assert option in r.output and "Traceback" not in r.output
    assert not out.exists()


def test_lobes_auto_shows_convergence_and_keeps_the_library_choice(tmp_path):
    csv = write(tmp_path, "d.csv", n_pairs=150)
    out = tmp_path / "auto.json"
    r = run("fit", csv, "--lobes", "auto", "--family", "metal", "-o", out)
    assert r.exit_code == 0, r.output
    header, *rows = [line for line in r.stdout.splitlines() if line.startswith("  ")][:7]
    assert header.split() == ["structure", "params", "median", "|f−y|/y", "p90", "BIC", "converged"]
    rows = [row for row in rows if row.strip().startswith("metal")]
    assert all(row.split()[-1] in ("True", "False") or row.endswith("<- chosen") for row in rows)
    kept = [row for row in rows if row.endswith("<- chosen")]
    assert len(kept) == 1
    best, _ = ctfit.choose_structure(ctfit.read_measurement(csv), families=("metal",))
    doc = json.loads(out.read_text())
    assert len(doc["lobes"]) == best.material.structure.lobes
    assert kept[0].split(",")[0].strip() == "metal" and ctfit.structure_label(best.material.structure) in kept[0]


def test_progress_bars_off_without_a_terminal_and_on_when_forced(tmp_path, monkeypatch):
    data = tmp_path / "data"
    write(data, "a.csv", seed=1)
    write(data, "b.csv", seed=2)
    monkeypatch.delenv("CTFIT_PROGRESS", raising=False)
    r = run("fit", data, "--no-diffuse", "--lobes", "1")
    assert r.exit_code == 0, r.output
    assert "\r" not in r.stderr and not BAR.search(r.stderr)
    monkeypatch.setenv("CTFIT_PROGRESS", "1")
    out = tmp_path / "fits"
    r = run("fit", data, "--no-diffuse", "--lobes", "1", "-o", out)
    assert r.exit_code == 0, r.output
    assert BAR.search(r.stderr) and "0/2" in r.stderr
    # A 'wrote' line clears the bar first: what a terminal shows on that line is the message alone.
    wrote = [line.split("\r")[-1] for line in r.stderr.split("\n") if "wrote" in line]
    assert wrote == [f"wrote {out / 'a.fit.json'}", f"wrote {out / 'b.fit.json'}", f"wrote {out / 'summary.json'}"]
    r = run("fit", data, "--no-diffuse", "--lobes", "1", "--quiet")
    assert r.exit_code == 0 and not BAR.search(r.stderr)


def test_sampling_progress_obeys_quiet(tmp_path, monkeypatch):
    csv = write(tmp_path, "d.csv", n_pairs=60)
    monkeypatch.setenv("CTFIT_PROGRESS", "1")
    args = ("fit", csv, "--no-diffuse", "--lobes", "1", "--sample", "--steps", 40, "--walkers", 8)
    r = run(*args)
    assert r.exit_code == 1, r.output  # 40 steps: the walkers have not mixed (the posterior is not usable)
    assert "40/40" in r.stderr and "run longer: --steps" in r.stderr
    r = run(*args, "-q")
    assert r.exit_code == 1, r.output
    assert "40/40" not in r.stderr and "\r" not in r.stderr


def test_table_on_stdout_wrote_on_stderr_after_it(tmp_path):
    csv = write(tmp_path, "d.csv")
    target = tmp_path / "d.fit.json"
    r = run("fit", csv, "--no-diffuse", "--lobes", "1", "-o", target)
    assert r.exit_code == 0, r.output
    assert "fit of" in r.stdout and "wrote " not in r.stdout
    assert r.stderr.splitlines() == [f"wrote {target}"]
    lines = r.output.splitlines()  # stdout and stderr in the order written
    assert lines[-1] == f"wrote {target}" and any(line.startswith("  converged:") for line in lines[:-1])


def test_warnings_print_as_one_clean_line(tmp_path):
    path, _ = write_alta(tmp_path / "tape.alta", "INV_STERADIAN_COSINE_FACTOR", cosine=True, horizon_row=True)
    with warnings.catch_warnings():
        warnings.simplefilter("default")  # as outside pytest, whose filters turn warnings into errors
        r = run("fit", path, "--no-diffuse", "--lobes", "1")
    assert r.exit_code == 0, r.output
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert lines == [f"warning: {path}: 1 samples with theta_o ≥ 90° dropped (a cosine-weighted value cannot be divided by cos θ_o = 0)"]


def test_outputs_are_checked_before_any_work(tmp_path):
    csv = write(tmp_path, "d.csv")
    before = csv.read_bytes()
    r = run("fit", csv, "-o", csv)
    assert r.exit_code == 2 and "is the input" in r.stderr and "fit of" not in r.stdout
    assert csv.read_bytes() == before
    (tmp_path / "file").write_text("x")
    r = run("fit", csv, write(tmp_path / "more", "e.csv"), "-o", tmp_path / "file")
    assert r.exit_code == 2 and "is a file" in r.stderr and "fit of" not in r.stdout


def test_a_stored_chain_needs_resume_or_overwrite(tmp_path):
    csv = write(tmp_path, "d.csv", n_pairs=60)
    chain = tmp_path / "run.h5"
    args = ("fit", csv, "--no-diffuse", "--lobes", "1", "--sample", "--steps", 30, "--walkers", 8, "--backend", chain)
    assert run(*args).exit_code == 1  # 30 steps: written, but the walkers have not mixed
    r = run(*args)
    assert r.exit_code == 2 and "--resume" in r.stderr and "--overwrite" in r.stderr and "fit of" not in r.stdout
    r = run(*args, "--overwrite")
    assert r.exit_code == 1 and "run longer: --steps" in r.stderr, r.output
    r = run("fit", csv, "--overwrite")
    assert r.exit_code == 2 and "--overwrite needs --backend" in r.stderr


def test_a_file_whose_name_is_not_utf8_is_fitted_and_rerun(tmp_path):
    """A name of bytes that are not UTF-8 (Latin-1 from an older system): Python holds them as lone
    surrogates, which JSON text cannot hold. The result is written under the file's own name,
    names its input with U+FFFD where the bytes were, and a rerun knows it as its own."""
    import os

    folder = tmp_path / "db"
    name = os.fsdecode(b"caf\xe9.csv")
    write(folder, name)
    write(folder, "b.csv", seed=1)
    out = tmp_path / "out"
    for _ in range(2):  # the second run replaces its own results
        r = run("fit", folder, "-o", out, "-q", "--lobes", "1", "--no-diffuse")
        assert r.exit_code == 0, r.output
    doc = json.loads((out / os.fsdecode(b"caf\xe9.fit.json")).read_text(encoding="utf-8"))
    assert doc["data"].endswith("caf\ufffd.csv") and doc["name"].endswith("caf\ufffd.csv")
    assert doc["fit"]["converged"] is True


def test_the_summary_names_the_file_a_fit_that_did_not_converge_went_to(tmp_path):
    data = tmp_path / "data"
    write(data, "a.csv", seed=1)
    write(data, "b.csv", seed=2)
    out = tmp_path / "out"
    assert run("fit", data, "--lobes", 1, "-q", "-o", out).exit_code == 0
    r = run("fit", data, "--lobes", 1, "-q", "-o", out, "--max-steps", 1)
    assert r.exit_code == 1, r.output
    rows = {Path(row["data"]).name: row for row in json.loads((out / "summary.json").read_text())["results"]}
    assert rows["a.csv"]["outcome"] == "not converged" and rows["a.csv"]["result"] == str(out / "a.fit.not-converged.json")
    assert (out / "a.fit.not-converged.json").is_file() and json.loads((out / "a.fit.json").read_text())["fit"]["converged"]


def test_a_fifo_in_a_folder_is_one_error_and_the_summary_is_written(tmp_path):
    import os

    data = tmp_path / "data"
    write(data, "a.csv", seed=1)
    os.mkfifo(data / "p.csv")
    out = tmp_path / "out"
    r = run("fit", data, "--lobes", 1, "-q", "-o", out)
    assert r.exit_code == 2 and r.output.count("p.csv: not a regular file") == 2, r.output  # its error line and its summary row
    rows = {Path(row["data"]).name: row for row in json.loads((out / "summary.json").read_text())["results"]}
    assert rows["p.csv"]["outcome"] == "failed" and rows["p.csv"]["input_sha256"] is None and rows["a.csv"]["outcome"] == "converged"


def test_json_of_several_files_is_one_document_a_line(tmp_path):
    """``--json`` with several inputs printed indented documents back to back, which no JSON parser
    reads; it is JSON Lines, each line the document written for that file."""
    data = tmp_path / "data"
    for name, seed in (("a.csv", 1), ("b.csv", 2)):
        write(data, name, seed=seed)
    out = tmp_path / "out"
    r = run("fit", data / "a.csv", data / "b.csv", "--lobes", 1, "--json", "-o", out)
    assert r.exit_code == 0, r.output
    docs = [json.loads(line) for line in r.stdout.splitlines() if line.strip()]
    assert [Path(d["data"]).name for d in docs] == ["a.csv", "b.csv"]
    assert docs == [json.loads((out / f"{n}.fit.json").read_text()) for n in ("a", "b")]


def test_result_files_are_written_while_the_next_files_are_reported(tmp_path, monkeypatch):
    """Files fitted together: a result file is written in a writer thread (its sync waits for the
    disk) while the next file is reported, and its 'wrote' line follows, in the files' order."""
    import ctfit._cli.fit_command as fit_command
    import ctfit._io as io

    data = tmp_path / "data"
    for k in range(3):
        write(data, f"{k}.csv", seed=k)
    reported = {k: threading.Event() for k in range(3)}
    report, own = fit_command.report_file, io.write_own_result
    overlapped = []

    def noting(path, *args, **kwargs):
        reported[int(Path(path).stem)].set()
        return report(path, *args, **kwargs)

    def slow(target, chunks, data):  # the first file's write lasts until the next file is reported
        if Path(data).stem == "0":
            overlapped.append(reported[1].wait(timeout=60))
        return own(target, chunks, data)

    monkeypatch.setattr(fit_command, "report_file", noting)
    monkeypatch.setattr(io, "write_own_result", slow)
    out = tmp_path / "fits"
    r = run("fit", data, "--no-diffuse", "--lobes", "1", "-o", out)
    assert r.exit_code == 0, r.output
    assert overlapped == [True]
    wrote = [line for line in r.stderr.splitlines() if line.startswith("wrote ")]
    assert wrote[:3] == [f"wrote {out / f'{k}.fit.json'}" for k in range(3)]
    assert sorted(p.name for p in out.iterdir()) == ["0.fit.json", "1.fit.json", "2.fit.json", "summary.json"]


def test_a_result_that_cannot_be_written_fails_its_file_only(tmp_path, monkeypatch):
    """A write in the writer thread that fails is that file's error line and 'failed' outcome, in
    its place among the others; the other results are written and the run's status is 2."""
    import ctfit._io as io

    data = tmp_path / "data"
    for k in range(3):
        write(data, f"{k}.csv", seed=k)
    own = io.write_own_result

    def full(target, chunks, data):
        if Path(data).stem == "1":
            raise OSError(28, "No space left on device", str(target))
        return own(target, chunks, data)

    monkeypatch.setattr(io, "write_own_result", full)
    out = tmp_path / "fits"
    r = run("fit", data, "--no-diffuse", "--lobes", "1", "-o", out)
    assert r.exit_code == 2, r.output
    errors = [line for line in r.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "no space left on the device" in errors[0] and str(out / "1.fit.json") in errors[0], errors
    assert [line.split()[0] for line in summary(r.stderr)] == ["converged", "failed", "converged"]
    assert sorted(p.name for p in out.iterdir()) == ["0.fit.json", "2.fit.json", "summary.json"]
    rows = json.loads((out / "summary.json").read_text())["results"]
    assert [row["outcome"] for row in rows] == ["converged", "failed", "converged"]
    assert rows[1]["result"] is None
