"""Inputs a hostile or careless user gives: devices, FIFOs, nesting, huge numbers in the JSON files
a command looks at (ctfit/_io/untrusted.py). Each is one error naming the file, never a hang."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from typer.testing import CliRunner

from ctfit._io import untrusted
from ctfit.cli import app

from conftest import ROOT

_READ = """
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))  # a reader that reads /dev/zero stops here
import ctfit
reader = getattr(ctfit, sys.argv[1])
try:
    reader(sys.argv[2])
except (ctfit.DataError, ctfit.MaterialError) as err:
    print(err)
"""


def _device_inputs(tmp_path):
    zero = tmp_path / "zero"
    zero.symlink_to("/dev/zero")
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    return {"/dev/zero": (zero, "a character device"), "FIFO": (fifo, r"a FIFO \(named pipe\)")}


@pytest.mark.parametrize("kind", ["/dev/zero", "FIFO"])
@pytest.mark.parametrize(
    "reader, suffix",
    [("read_measurement", ".csv"), ("read_measurement", ".alta"), ("read_measurement", ".binary"), ("read_measurement", ".dat"),
     ("read_measurement", ".txt"), ("load_material", ".toml"), ("load_material", ".json"), ("read_optical_constants", ".csv")],
)
def test_a_device_or_fifo_is_refused_before_it_is_read(tmp_path, kind, reader, suffix):
    """A link to /dev/zero (endless), a FIFO (no writer: open waits for ever): refused at once, in
    a process with a time limit and 2 GiB of memory."""
    path, what = _device_inputs(tmp_path)[kind]
    named = path.with_suffix(suffix)
    path.rename(named)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-c", _READ, reader, str(named)], capture_output=True, text=True, timeout=60, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.startswith(f"{named}: not a regular file but ")
    assert __import__("re").search(what, done.stdout)


def test_the_command_refuses_a_link_to_dev_zero_in_one_line(tmp_path):
    (tmp_path / "zero.csv").symlink_to("/dev/zero")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "cache")}
    script = "import resource; resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30)); from ctfit.cli import main; main()"
    done = subprocess.run([sys.executable, "-c", script, "fit", "zero.csv"], cwd=tmp_path, capture_output=True, text=True, timeout=120, env=env)
    assert done.returncode == 2
    assert done.stderr == "error: zero.csv: not a regular file but a character device (such as /dev/zero); ctfit reads files only\n"


@pytest.mark.parametrize(
    "name, text, message",
    [
        ("deep.toml", "s = 1\nnote = " + "[" * 600 + "]" * 600 + "\n", "deep.toml: nested too deeply to read"),
        ("deep.json", "[" * 100_000 + "]" * 100_000, "deep.json: nested too deeply to read"),
        ("big.json", '{"s": 1' + "0" * 5000 + "}", "big.json: a number of more than 4300 digits; not a value ctfit can read"),
        ("big.toml", "s = 1" + "0" * 5000 + "\n", "big.toml: a number of more than 4300 digits; not a value ctfit can read"),
        ("nul.csv", "theta_i,phi_i\x00\n", "nul.csv:1: a NUL byte at byte offset 13"),
    ],
)
def test_nesting_huge_numbers_and_binary_give_one_error_line(tmp_path, monkeypatch, name, text, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / name).write_text(text)
    command = ["fit", name] if name.endswith(".csv") else ["color", name]
    got = CliRunner().invoke(app, command)
    assert got.exit_code == 2, got.output
    assert got.output.startswith(f"error: {message}") and got.output.count("\n") == 1


@pytest.mark.parametrize(
    "text",
    ["[" * 100_000 + "]" * 100_000, '{"fit": {"converged": true}, "x": 1' + "0" * 5000 + "}", "{\x00}"],
    ids=["nested", "huge number", "binary"],
)
def test_an_earlier_result_that_cannot_be_read_is_no_result(tmp_path, text):
    """The fit JSON a command looks at before it writes (a converged fit to keep; a --workers
    re-run's result to skip) is nothing to keep when it cannot be read, whatever the reason."""
    from ctfit._cli.fit_cluster import _kept_result
    from ctfit._io import unconverged_target

    target = tmp_path / "x.fit.json"
    target.write_text(text)
    assert untrusted.read_json_or_none(target) is None
    assert _kept_result(target, "0" * 64, {}) is None
    assert unconverged_target(target) == (target, f"{target} replaced by a fit that did not converge")


def test_a_scheduler_file_is_read_as_any_input(tmp_path, monkeypatch):
    """--scheduler FILE.json: nested, not JSON, without an address, a device → one error line."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "g.csv").write_text("theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n10,0,30,180,550,0.1\n")
    files = {"deep.json": "[" * 100_000 + "]" * 100_000, "cut.json": "{", "other.json": '{"addr": 1}'}
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    (tmp_path / "zero.json").symlink_to("/dev/zero")
    expected = {
        "deep.json": "deep.json: nested too deeply to read",
        "cut.json": "cut.json:1:2: JSON syntax error",
        "other.json": "other.json: not a Dask scheduler file (a JSON object with an \"address\"), got {'addr': 1}",
        "zero.json": "zero.json: not a regular file but a character device",
    }
    for name, message in expected.items():
        got = CliRunner().invoke(app, ["fit", "g.csv", "--scheduler", name, "-o", "out"])
        assert got.exit_code == 2 and got.output.startswith(f"error: {message}") and got.output.count("\n") == 1, got.output


def test_quote_and_shorten_cut_long_text():
    assert untrusted.quote("a" * 81) == repr("a" * 80) + "…"
    assert untrusted.quote("a" * 80) == repr("a" * 80)
    assert untrusted.quote(list(range(10_000))).endswith("…") and len(untrusted.quote(list(range(10_000)))) == 81
    assert untrusted.shorten("é" * 100, 3) == "ééé…"
