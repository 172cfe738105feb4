"""A large CSV parsed by a helper process while ``ctfit fit`` starts JAX (``ctfit/_io/read_ahead.py``):
the same measurement as the reader's, the reader's own errors, nothing left running."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from typer.testing import CliRunner

import ctfit
from ctfit._io import read_ahead as ahead_module
from ctfit._io.csv_table import read_table
from ctfit._io.read_ahead import ReadAhead, start_read_ahead
from ctfit.cli import app

from conftest import ROOT

HEADER = "theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n"


def _measurement(n: int, seed: int = 0) -> ctfit.Measurement:
    """``n`` samples of a one-lobe metal, the bands of a pair listed apart (pairs repeat out of order)."""
    metal = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([0.3]), w=np.ones(1), f0=np.array([0.5, 0.9])),
                           wavelength_nm=np.array([450.0, 650.0]))
    return ctfit.simulate(metal, n_pairs=n // 2, seed=seed, noise=0.01)


BIG = 1 << 20
"""The helper's size threshold in these tests (the default, 8 MiB, would take a file of 100,000 rows)."""


@pytest.fixture(autouse=True)
def _threshold(monkeypatch):
    monkeypatch.setattr(ahead_module, "READ_AHEAD_BYTES", BIG)


@pytest.fixture(scope="module")
def big_csv(tmp_path_factory):
    """A CSV above the tests' size threshold."""
    path = tmp_path_factory.mktemp("ahead") / "big.csv"
    ctfit.write_csv(_measurement(30_000), path)
    assert os.path.getsize(path) >= BIG
    return path


def _spy(monkeypatch, method: str, note) -> list:
    """A list that gets ``note(helper, result)`` at every call of ``ReadAhead.<method>``."""
    notes, real = [], getattr(ReadAhead, method)

    def spy(self, *args):
        result = real(self, *args)
        notes.append(note(self, result))
        return result

    monkeypatch.setattr(ReadAhead, method, spy)
    return notes


def _same_measurement(a: ctfit.Measurement, b: ctfit.Measurement) -> None:
    for name in ("theta_i", "phi_i", "theta_o", "phi_o", "band", "brdf", "sigma", "wavelength_nm"):
        assert (getattr(a, name) is None) == (getattr(b, name) is None), name
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert (a.meta, a.source, a.channels) == (b.meta, b.source, b.channels)
    for x, y in zip(a.directions(), b.directions()):
        np.testing.assert_array_equal(x, y)


def test_the_helper_gives_the_readers_measurement_and_its_direction_pairs(big_csv):
    from ctfit._cli.inputs import read_data

    helper = start_read_ahead(big_csv)
    assert isinstance(helper, ReadAhead)
    table = helper.table()
    assert table is not None and table.pairs is not None and table.columns is not None
    assert helper.table() is None  # once only
    again = start_read_ahead(big_csv)
    got = read_data(big_csv, None, again)
    assert "_directions" in got.__dict__  # the helper's pairs, not computed here
    _same_measurement(got, ctfit.read_csv(big_csv))
    plain = table.pairs, ctfit.read_csv(big_csv).directions()
    np.testing.assert_array_equal(plain[0][0], plain[1][0])


def test_the_helper_process_never_imports_jax(big_csv):
    code = (f"import sys; from ctfit._io.csv_table import read_table; t = read_table({str(big_csv)!r}, prepared=True); "
            "print(len(t.pairs[1]), 'jax' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["30000", "False"]


def test_small_files_other_formats_one_core_or_turned_off_get_no_helper(big_csv, tmp_path, monkeypatch):
    small = tmp_path / "small.csv"
    small.write_text(HEADER + "30,0,30,180,550,0.1\n")
    assert start_read_ahead(small) is None
    alta = tmp_path / "big.alta"
    alta.write_bytes(big_csv.read_bytes())
    assert start_read_ahead(alta) is None
    assert start_read_ahead(tmp_path / "missing.csv") is None
    assert start_read_ahead(tmp_path) is None
    monkeypatch.setattr(ahead_module, "usable_cores", lambda: 1)
    assert start_read_ahead(big_csv) is None
    monkeypatch.undo()
    monkeypatch.setenv("CTFIT_READ_AHEAD", "0")
    assert start_read_ahead(big_csv) is None


def test_a_bad_file_is_read_here_with_the_readers_error(tmp_path, monkeypatch):
    from ctfit._cli.inputs import read_data

    monkeypatch.setattr(ahead_module, "READ_AHEAD_BYTES", 10)
    bad = tmp_path / "bad.csv"
    bad.write_text(HEADER + "30,0,30,180,550,0.1\n" * 3 + "30,0,30,180,550,abc\n")
    helper = start_read_ahead(bad)
    assert helper is not None
    with pytest.raises(ctfit.DataError) as seen:
        read_data(bad, None, helper)
    with pytest.raises(ctfit.DataError) as plain:
        ctfit.read_csv(bad)
    assert str(seen.value) == str(plain.value) and "bad.csv:5" in str(seen.value)


def test_a_file_changed_after_the_helper_started_is_read_again(tmp_path, monkeypatch):
    from ctfit._cli.inputs import read_data

    monkeypatch.setattr(ahead_module, "READ_AHEAD_BYTES", 10)
    path = tmp_path / "moving.csv"
    path.write_text(HEADER + "30,0,30,180,550,0.1\n")
    helper = start_read_ahead(path)
    assert helper is not None
    path.write_text(HEADER + "30,0,30,180,550,0.25\n40,0,40,180,550,0.5\n")  # another size: another identity
    assert helper.table() is None
    again = start_read_ahead(path)
    path.write_text(HEADER + "10,0,10,180,550,0.75\n")
    assert read_data(path, None, again).brdf.tolist() == [0.75]


def test_a_cancelled_helper_is_stopped(big_csv):
    helper = start_read_ahead(big_csv)
    assert helper is not None
    process = helper._process
    helper.cancel()
    assert process is not None and process.returncode is not None and process.stdout.closed
    assert helper.table() is None


def test_ctfit_fit_gives_the_same_result_with_and_without_the_helper(tmp_path, monkeypatch):
    path = tmp_path / "metal.csv"
    ctfit.write_csv(_measurement(400, seed=3), path)
    monkeypatch.setattr(ahead_module, "READ_AHEAD_BYTES", 10)
    taken = _spy(monkeypatch, "table", lambda helper, table: table is not None)
    runner = CliRunner()
    docs = []
    for setting in ("1", "0"):
        monkeypatch.setenv("CTFIT_READ_AHEAD", setting)
        r = runner.invoke(app, ["fit", str(path), "--lobes", "1", "--no-diffuse", "--json", "-q"])
        assert r.exit_code == 0, r.output
        doc = json.loads(r.stdout)
        doc["fit"].pop("time_s")
        docs.append(doc)
    assert taken == [True]  # the first run took the helper's table, the second started none
    assert docs[0] == docs[1]


def test_ctfit_fit_refusing_an_option_leaves_no_helper_running(tmp_path, monkeypatch):
    path = tmp_path / "metal.csv"
    ctfit.write_csv(_measurement(40, seed=4), path)
    monkeypatch.setattr(ahead_module, "READ_AHEAD_BYTES", 10)
    started = _spy(monkeypatch, "__init__", lambda helper, _: helper._process)
    r = CliRunner().invoke(app, ["fit", str(path), "--lobes", "99"])
    assert r.exit_code == 2 and "--lobes" in r.output
    assert len(started) == 1 and started[0].returncode is not None  # started, then stopped


def test_the_bundled_measurements_read_the_same_through_the_helper(monkeypatch):
    from ctfit._cli.inputs import read_data

    monkeypatch.setattr(ahead_module, "READ_AHEAD_BYTES", 10)
    files = sorted((ROOT / "measurements").rglob("*.csv"))
    assert files
    for path in files[:3]:
        table = read_table(path, prepared=True)
        assert table.pairs is not None
        _same_measurement(read_data(path, None, start_read_ahead(path)), ctfit.read_csv(path))


def test_ctfit_fit_starts_the_helper_before_it_imports_jax(big_csv):
    """The helper's parse overlaps the command's import of JAX only if it starts first."""
    code = (f"import sys\nfrom ctfit._io import read_ahead as r\nr.READ_AHEAD_BYTES = {BIG}\ninit = r.ReadAhead.__init__\n"
            "def spy(self, path):\n    print('jax imported:', 'jax' in sys.modules, flush=True)\n    init(self, path)\n"
            "r.ReadAhead.__init__ = spy\nfrom ctfit.cli import main\n"
            f"sys.argv = ['ctfit', 'fit', {str(big_csv)!r}, '--lobes', '99']\ntry:\n    main()\nexcept SystemExit:\n    pass\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.splitlines()[0] == "jax imported: False", out.stdout + out.stderr


def test_the_helper_is_started_before_the_command_imports_numpy():
    """What the command imports before it starts the helper: neither NumPy nor ``importlib.metadata``
    (0.1 s and 0.04 s here, which a large file's fit would wait for once more); the helper
    process itself imports no ``importlib.metadata`` either (``ctfit.__version__`` is looked up
    when asked for)."""
    code = ("import sys; import ctfit.cli, ctfit._cli.commands, ctfit._cli.fit_command; from ctfit._io import start_read_ahead; "
            "print('numpy' in sys.modules, 'importlib.metadata' in sys.modules); "
            "import ctfit._io.read_ahead, ctfit; print('importlib.metadata' in sys.modules, ctfit.__version__ == "
            f"{ctfit.__version__!r})")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False", "False", "True"], out.stdout + out.stderr
