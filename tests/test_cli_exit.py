"""The console script ``ctfit`` ends with ``os._exit`` after every exit handler (``_cli/leave.py``):
the same exit status and output as a normal exit, every file whole."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from ctfit._cli.leave import exit_status

ROOT = Path(__file__).resolve().parents[1]
CONSOLE = "import sys; from ctfit.cli import console; sys.argv = ['ctfit', *sys.argv[1:]]; sys.exit(console())"


def console(*args, extra: str = ""):
    return subprocess.run([sys.executable, "-c", extra + CONSOLE, *map(str, args)], capture_output=True, text=True, timeout=600)


def test_a_fit_through_the_console_script_is_written_whole_and_exits_0(tmp_path):
    out = tmp_path / "f.json"
    r = console("fit", ROOT / "measurements" / "testbed" / "plastic.csv", "-o", out, "--lobes", 1, "--family", "plastic", "--diffuse", "transmitted")
    assert r.returncode == 0, r.stderr
    assert r.stderr.startswith("wrote ") and r.stdout.startswith("fit of ") and r.stdout.endswith("\n")  # both streams reached their pipes whole
    assert json.loads(out.read_text())["fit"]["converged"] is True


def test_the_console_script_keeps_error_statuses_and_runs_the_other_exit_handlers(tmp_path):
    flag = tmp_path / "ran"
    # a handler registered while the command runs (as JAX, Dask or logging do when imported there)
    handler = ("import atexit, pathlib, ctfit._cli.commands as c\n_main = c.main\n"
               f"def main():\n    atexit.register(lambda: pathlib.Path({str(flag)!r}).write_text('yes'))\n    _main()\n"
               "c.main = main\n")
    r = console("fit", tmp_path / "missing.csv", "-o", tmp_path / "f.json", extra=handler)
    assert r.returncode == 2 and "no such file" in r.stderr
    assert flag.read_text() == "yes"  # it ran before the quick exit
    assert console("--version").returncode == 0


@pytest.mark.parametrize(("code", "status"), [(None, 0), (0, 0), (1, 1), (2, 2), (130, 130), ("a message", 1)])
def test_exit_status_is_pythons(code, status):
    assert exit_status(code) == status
    r = subprocess.run([sys.executable, "-c", f"import sys; sys.exit({code!r})"], capture_output=True)
    assert r.returncode == status


def test_python_m_ctfit_is_the_command(tmp_path):
    """``python -m ctfit`` (no ``ctfit`` on PATH: an environment not activated, a notebook) runs the
    command, its help named so, with the command's exit status (it was "No module named ctfit.__main__")."""
    run = lambda *a: subprocess.run([sys.executable, "-m", "ctfit", *map(str, a)], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    r = run("--help")
    assert r.returncode == 0 and r.stdout.startswith("Usage: python -m ctfit"), r.stdout + r.stderr
    r = run("fit", tmp_path / "missing.csv")
    assert r.returncode == 2 and "no such file" in r.stderr
