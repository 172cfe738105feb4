"""read_measurement: dispatch by extension, then by content; a clear error for anything else."""

import shutil

import numpy as np
import pytest

from ctfit import DataError, DataWarning, merl_table, read_measurement, write_merl

from conftest import MEASURED

CSV = "theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n10,0,10,180,550,0.5\n"
ALTA = "#DIM 1 1\n#PARAM_IN COS_TH\n#PARAM_OUT INV_STERADIAN\n0.5 0.25\n"


@pytest.mark.parametrize("name", ["m.csv", "m.CSV", "m.dat", "m.txt", "m"])
def test_csv_by_extension_or_content(tmp_path, name):
    (tmp_path / name).write_text(CSV)
    np.testing.assert_array_equal(read_measurement(tmp_path / name).brdf, [0.5])


@pytest.mark.parametrize("name", ["m.alta", "m.dat", "m.txt"])
def test_alta_by_extension_or_content(tmp_path, name):
    (tmp_path / name).write_text("#SAMPLE x\n" + ALTA)
    assert read_measurement(tmp_path / name).theta_i[0] == pytest.approx(60.0)


@pytest.mark.parametrize("name", ["m.binary", "m.bin"])
def test_merl_by_extension_or_content(tmp_path, name):
    write_merl(tmp_path / name, merl_table(lambda th, td, pd: 0.25 + 0 * th))
    m = read_measurement(tmp_path / name)
    assert m.channels == ("R", "G", "B") and np.allclose(m.brdf, 0.25)


def test_options_reach_the_reader(tmp_path):
    shutil.copy(MEASURED / "retro-gray-tape.dat", tmp_path / "tape.dat")
    with pytest.warns(DataWarning):
        m = read_measurement(tmp_path / "tape.dat", param_out="INV_STERADIAN_COSINE_FACTOR")
    assert m.meta["alta_sample"] == "Gray Tape"


@pytest.mark.parametrize(
    "name, content, pattern",
    [
        ("m.json", "{}", r"m\.json: unknown measurement format '\.json': supported are \.csv .*\.binary .*\.alta or \.dat"),
        ("m", "x y z\n", r"m: unknown measurement format: supported are"),
        ("m.dat", "1 2 3\n", r"m\.dat: no #DIM line"),
    ],
)
def test_unknown_formats_are_named(tmp_path, name, content, pattern):
    (tmp_path / name).write_text(content)
    with pytest.raises(DataError, match=pattern):
        read_measurement(tmp_path / name)
