"""ALTA text files: the three measured files in measurements/brdf/, synthetic files, and every error."""

import math
import re

import numpy as np
import pytest

from ctfit import DataError, DataWarning, read_alta, read_csv, write_csv

from conftest import MEASURED

HEAD_3D = "#DIM 3 1\n#PARAM_IN ISOTROPIC_TL_TV_PROJ_DPHI\n"


def write(tmp_path, text, name="data.alta"):
    path = tmp_path / name
    (path.write_bytes if isinstance(text, bytes) else path.write_text)(text)
    return path


def read_measured(name, **kwargs):
    with pytest.warns(DataWarning, match=r"86 samples with theta_o ≥ 90° dropped"):
        return read_alta(MEASURED / name, **kwargs)


# --- the measured files -------------------------------------------------------------------------


def test_retro_3m_yellow():
    m = read_measured("retro-3M-jaune.dat")
    assert len(m) == 7397 - 86
    np.testing.assert_array_equal(m.wavelength_nm, [550.0])
    assert (m.band == 0).all() and m.sigma is None
    assert m.meta["alta_sample"] == "3M Yellow"
    assert m.meta["alta_param_out"] == "INV_STERADIAN_COSINE_FACTOR"
    assert "placeholder" in m.meta["wavelength_nm"] and "86 samples" in m.meta["dropped"]
    np.testing.assert_array_equal(np.unique(m.theta_i), [15.0, 30.0, 60.0])
    assert (m.phi_i == 0).all() and m.theta_o.max() < 90 and m.brdf.min() > 0
    # Line 11: θ_l = 15°, [θ_v cos Δφ, θ_v sin Δφ] = [-1.5184…, 1.9e-16] (87°, Δφ = 180°), value 0.00362877.
    theta_v = math.hypot(-1.51843644923506659871748070145259, 0.00000000000000018595483372643967)
    assert m.theta_i[0] == pytest.approx(15.0) and m.theta_o[0] == pytest.approx(math.degrees(theta_v))
    assert m.phi_o[0] == pytest.approx(180.0)
    assert m.brdf[0] == pytest.approx(0.00362876999999999991231014462301 / math.cos(theta_v), rel=1e-12)


def test_retro_gray_tape_needs_its_missing_param_out():
    with pytest.raises(DataError, match=r"retro-gray-tape\.dat: no #PARAM_OUT line: the unit of the values is unknown"):
        read_alta(MEASURED / "retro-gray-tape.dat")
    m = read_measured("retro-gray-tape.dat", param_out="INV_STERADIAN_COSINE_FACTOR")
    assert len(m) == 7405 - 86 and m.meta["alta_sample"] == "Gray Tape"


def test_param_out_must_agree_with_the_file():
    with pytest.raises(DataError, match=r"retro-3M-jaune\.dat:7: #PARAM_OUT INV_STERADIAN_COSINE_FACTOR contradicts param_out='INV_STERADIAN'"):
        read_alta(MEASURED / "retro-3M-jaune.dat", param_out="INV_STERADIAN")


def test_pink_felt_cos_th_rgb():
    m = read_alta(MEASURED / "pink-felt-1d.alta")
    assert m.channels == ("R", "G", "B") and m.wavelength_nm is None and len(m) == 90 * 3
    np.testing.assert_array_equal(m.band[:6], [0, 1, 2, 0, 1, 2])
    theta_h = math.degrees(math.acos(0.999984567305837))
    # θ_d = 0: light and viewer both along the half vector (ALTA's half_to_cartesian(θ_h, 0, 0, 0)).
    np.testing.assert_allclose(m.theta_i[:3], theta_h, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(m.theta_o, m.theta_i)
    assert (m.phi_i == 0).all() and (m.phi_o == 0).all()
    np.testing.assert_array_equal(m.brdf[:3], [0.109704419970512, 0.0794405192136765, 0.0616232864558697])
    assert "wavelength_nm" not in m.meta


def test_measured_file_survives_a_csv_round_trip(tmp_path):
    m = read_measured("retro-3M-jaune.dat")
    write_csv(m, tmp_path / "yellow.csv")
    back = read_csv(tmp_path / "yellow.csv")
    for name in ("theta_i", "phi_i", "theta_o", "phi_o", "brdf", "band", "wavelength_nm"):
        np.testing.assert_array_equal(getattr(back, name), getattr(m, name))
    assert m.band_unknown and back.band_unknown  # the '# band: unknown' line: the stand-in wavelength is not read as a real band
    assert back.meta == {**m.meta, "band": "unknown (no known wavelength; 550 nm stands in)"}


# --- synthetic files ----------------------------------------------------------------------------


def test_inv_steradian_keeps_horizon_and_reads_negative_theta_l(tmp_path):
    text = "#DIM 3 1\n#PARAM_IN ISOTROPIC_TL_TV_PROJ_DPHI\n#PARAM_OUT INV_STERADIAN\n" f"-0.5 0 {math.pi / 2} 0.25\n0.5 0 0 0.5\n"
    m = read_alta(write(tmp_path, text))
    np.testing.assert_allclose(m.theta_i, math.degrees(0.5))
    np.testing.assert_array_equal(m.phi_i, [180.0, 0.0])
    np.testing.assert_array_equal(m.theta_o, [90.0, 0.0])
    np.testing.assert_array_equal(m.phi_o, [90.0, 0.0])
    np.testing.assert_array_equal(m.brdf, [0.25, 0.5])


def test_vs1_half_width_becomes_sigma_and_is_cosine_corrected(tmp_path):
    text = HEAD_3D + "#PARAM_OUT INV_STERADIAN_COSINE_FACTOR\n#VS 1\n\t0.3  -0.6 0.8   0.5 0.05\t\n"
    m = read_alta(write(tmp_path, text))
    assert m.theta_o[0] == pytest.approx(math.degrees(1.0)) and m.phi_o[0] == pytest.approx(math.degrees(math.atan2(0.8, -0.6)))
    np.testing.assert_allclose(m.brdf, 0.5 / math.cos(1.0), rtol=1e-14)
    np.testing.assert_allclose(m.sigma, 0.05 / math.cos(1.0), rtol=1e-14)


def test_vs2_bounds_become_sigma_per_channel(tmp_path):
    text = "#DIM 1 3\n#PARAM_IN COS_TH\n#PARAM_OUT RGB_COLOR\n#VS 2\n1.0 0.5 0.6 0.7 0.4 0.7 0.5 0.9 0.6 0.8\n"
    m = read_alta(write(tmp_path, text))
    np.testing.assert_array_equal(m.theta_i, [0, 0, 0])
    np.testing.assert_array_equal(m.brdf, [0.5, 0.6, 0.7])
    np.testing.assert_allclose(m.sigma, [0.15, 0.2, 0.1])


GOOD_ROW = "0.3 0.1 0.2 0.5\n"
OUT = "#PARAM_OUT INV_STERADIAN\n"
BAD = [
    (OUT + "#PARAM_IN ISOTROPIC_TL_TV_PROJ_DPHI\n" + GOOD_ROW, r"data\.alta: no #DIM line"),
    ("#DIM three 1\n#PARAM_IN COS_TH\n" + OUT + GOOD_ROW, r"data\.alta:1: #DIM 'three 1': expected two integers"),
    ("#DIM 3 1\n" + OUT + GOOD_ROW, r"data\.alta: no #PARAM_IN line"),
    ("#DIM 3 1\n#PARAM_IN RUSIN_TH_TD_PD\n" + OUT + GOOD_ROW, r"data\.alta:2: #PARAM_IN RUSIN_TH_TD_PD: not supported \(supported: ISOTROPIC_TL_TV_PROJ_DPHI, "
                                                              r"COS_TH\)"),
    ("#DIM 2 1\n#PARAM_IN ISOTROPIC_TL_TV_PROJ_DPHI\n" + OUT + GOOD_ROW, r"data\.alta:1: #DIM says 2 inputs, #PARAM_IN ISOTROPIC_TL_TV_PROJ_DPHI has 3"),
    (HEAD_3D + "#PARAM_OUT XYZ_COLOR\n" + GOOD_ROW, r"data\.alta:3: output XYZ_COLOR: not supported"),
    ("#DIM 1 1\n#PARAM_IN COS_TH\n#PARAM_OUT RGB_COLOR\n0.5 0.1\n", r"data\.alta:1: #DIM says 1 outputs, RGB_COLOR has 3"),
    (HEAD_3D + OUT + "#VS 3\n" + GOOD_ROW, r"data\.alta:4: #VS 3: expected 0, 1 or 2"),
    (HEAD_3D + OUT + "#VS 1\n#VS 2\n" + GOOD_ROW, r"data\.alta:5: #VS 2 differs from #VS 1 on line 4"),
    (HEAD_3D + OUT + "#PARAM_IN COS_TH\n" + GOOD_ROW, r"data\.alta:4: #PARAM_IN appears twice \(also line 2\)"),
    ("#FORMAT binary\n" + HEAD_3D + OUT, r"data\.alta:1: #FORMAT binary: only ALTA's text format is supported"),
    (HEAD_3D + OUT + "# nothing else\n", r"data\.alta: no data lines"),
    (HEAD_3D + OUT + GOOD_ROW + "0.3 0.1 0.2\n", r"data\.alta:5: expected 4 numbers \(theta_l theta_v\*cos\(dphi\) theta_v\*sin\(dphi\) value\), found 3"),
    (HEAD_3D + OUT + GOOD_ROW + "0.3 0.1 x 0.5\n", r"data\.alta:5: column 'theta_v\*sin\(dphi\)' \(3\): 'x' is not a number"),
    (HEAD_3D + OUT + GOOD_ROW + "0.3 0.1 0.2 nan\n", r"data\.alta:5: column 'value' \(4\): NaN is not allowed"),
    (HEAD_3D + OUT + GOOD_ROW + "0.3 0.1 0.2 -1e-3\n", r"data\.alta:5: column 'value' \(4\): -0\.001 is negative"),
    (HEAD_3D + OUT + "1.6 0.1 0.2 0.5\n", r"data\.alta:4: column 'theta_l' \(1\): 1\.6 rad: the light is below the horizon"),
    (HEAD_3D + OUT + "0.3 1.2 1.2 0.5\n", r"data\.alta:4: column 'theta_v\*cos\(dphi\), theta_v\*sin\(dphi\)' \(2\): θ_v = hypot\(1\.2, 1\.2\) = 1\.69.* rad "
                                          r"> π/2"),
    ("#DIM 1 1\n#PARAM_IN COS_TH\n" + OUT + "1.5 0.1\n", r"data\.alta:4: column 'cos\(theta_h\)' \(1\): 1\.5 is not the cosine"),
    (HEAD_3D + OUT + "#VS 1\n0.3 0.1 0.2 0.5 0\n", r"data\.alta:5: column 'value_halfwidth' \(5\): 0\.0: the half-width must be positive"),
    (HEAD_3D + OUT + "#VS 2\n0.3 0.1 0.2 0.5 0.6 0.7\n", r"data\.alta:5: column 'value_lower' \(5\): 0\.6: the lower bound exceeds the value"),
    (HEAD_3D + OUT + "#VS 2\n0.3 0.1 0.2 0.5 0.4 0.45\n", r"data\.alta:5: column 'value_upper' \(6\): 0\.45: the upper bound is below the value"),
    (HEAD_3D + "#PARAM_OUT INV_STERADIAN_COSINE_FACTOR\n" + f"0.3 0 {math.pi / 2} 0.5\n", r"data\.alta: no samples left: 1 samples with theta_o ≥ 90° dropped"),
    (b"#DIM 3 1 \xe9\n", r"data\.alta:1: byte 0xe9 at byte offset 9"),
]


@pytest.mark.parametrize("text, pattern", BAD, ids=[re.sub(r"\W+", "_", p[:40]) for _, p in BAD])
def test_bad_input_raises_located_error(tmp_path, text, pattern):
    with pytest.raises(DataError, match=pattern):
        read_alta(write(tmp_path, text))


# The rows are decoded at once, as one JSON array (ctfit/_io/json_numbers.py); where JSON does not
# take a field, the rows are read field by field with float(), as before: both give float()'s values.
TOKENS = ["0", "-0", "-0.0", "-0e3", "+0.5", ".5", "5.", "1E-3", "007", "1_0", "0.26179938779914940782944654529274", "4.9e-324",
          "123456789012345678901234567890", "1e-400"]


@pytest.mark.parametrize("token", TOKENS)
def test_each_value_reads_as_float_reads_it(tmp_path, token, monkeypatch):
    from ctfit._io import alta

    path = write(tmp_path, HEAD_3D + OUT + f"0.3 0.1 0.2 {token}\n0.3 -0 0.2 0.5\n")
    m = read_alta(path)
    want = np.array([float(token), 0.5])
    np.testing.assert_array_equal(m.brdf, want)
    np.testing.assert_array_equal(np.signbit(m.brdf), np.signbit(want))
    monkeypatch.setattr(alta, "_numbers_at_once", lambda *a: None)
    by_row = read_alta(path)
    for name in ("theta_i", "phi_i", "theta_o", "phi_o", "brdf"):
        np.testing.assert_array_equal(getattr(m, name), getattr(by_row, name), err_msg=name)
        np.testing.assert_array_equal(np.signbit(getattr(m, name)), np.signbit(getattr(by_row, name)), err_msg=name)


def test_plain_rows_are_decoded_at_once_and_others_row_by_row(tmp_path, monkeypatch):
    from ctfit._io import alta

    by_row = []
    real = alta._numbers_by_row
    monkeypatch.setattr(alta, "_numbers_by_row", lambda *a: by_row.append(1) or real(*a))
    with pytest.warns(DataWarning):
        measured = read_alta(MEASURED / "retro-3M-jaune.dat")
    plain = read_alta(write(tmp_path, HEAD_3D + OUT + "0.3 -0 0.2 0.5\n0.2\t0.1  0 1e-3\n"))
    assert by_row == [] and len(measured) == 7397 - 86
    np.testing.assert_array_equal(plain.brdf, [0.5, 1e-3])
    monkeypatch.setattr(alta, "_numbers_at_once", lambda *a: None)  # every file row by row: the same values
    with pytest.warns(DataWarning):
        again = read_alta(MEASURED / "retro-3M-jaune.dat")
    for name in ("theta_i", "phi_i", "theta_o", "phi_o", "brdf"):
        np.testing.assert_array_equal(getattr(measured, name), getattr(again, name), err_msg=name)
    read_alta(write(tmp_path, HEAD_3D + OUT + "0.3 0.1 0.2 +0.5\n", "plus.alta"))
    assert by_row == [1, 1]


def test_old_mac_line_endings_read_as_lines(tmp_path):
    text = HEAD_3D + OUT + GOOD_ROW + "0.2 0.1 0.1 0.4\n"
    lf = read_alta(write(tmp_path, text, "lf.alta"))
    cr = read_alta(write(tmp_path, text.replace("\n", "\r"), "cr.alta"))
    np.testing.assert_array_equal(cr.brdf, lf.brdf)
    np.testing.assert_array_equal(cr.theta_o, lf.theta_o)


@pytest.mark.parametrize(
    "text, pattern",
    [
        (HEAD_3D + OUT + "0.3 0.1 " + "x" * 1_000_000 + " 0.5\n", r"data\.alta:4: column 'theta_v\*sin\(dphi\)' \(3\): 'x{80}'… is not a number$"),
        ("#DIM " + "3" * 1_000_000 + " 1\n" + OUT + GOOD_ROW, r"data\.alta:1: #DIM '3{80}'…: expected two integers"),
        ("#DIM 3 1\n#PARAM_IN " + "P" * 1_000_000 + "\n" + OUT + GOOD_ROW, r"data\.alta:2: #PARAM_IN P{80}…: not supported"),
        (HEAD_3D + "#PARAM_OUT " + "Q" * 1_000_000 + "\n" + GOOD_ROW, r"data\.alta:3: output Q{80}…: not supported"),
        ("#FORMAT " + "b" * 1_000_000 + "\n" + HEAD_3D + OUT, r"data\.alta:1: #FORMAT b{80}…: only"),
        (HEAD_3D + OUT + "#VS " + "9" * 1_000_000 + "\n" + GOOD_ROW, r"data\.alta:4: #VS 9{80}…: expected 0, 1 or 2"),
        (HEAD_3D + "\x00" + OUT + GOOD_ROW, r"data\.alta:3: a NUL byte at byte offset 45: a binary file"),
    ],
    ids=["number", "DIM", "PARAM_IN", "PARAM_OUT", "FORMAT", "VS", "binary"],
)
def test_an_error_quotes_at_most_80_characters_of_the_file(tmp_path, text, pattern):
    with pytest.raises(DataError, match=pattern) as err:
        read_alta(write(tmp_path, text))
    assert len(str(err.value)) < len(str(tmp_path)) + 200
