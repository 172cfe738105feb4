"""Measurement CSV: reading, validation errors (file:line: column), writing, round trips."""

import os
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

import ctfit
from ctfit import DataError, Measurement, read_csv, write_csv
from ctfit._io import csv_files as _csvio, csv_table as _table

HEADER = "theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf"


def write(tmp_path, text, name="data.csv"):
    path = tmp_path / name
    (path.write_bytes if isinstance(text, bytes) else path.write_text)(text)
    return path


def assert_same(a: Measurement, b: Measurement):
    for name in ("theta_i", "phi_i", "theta_o", "phi_o", "band", "brdf", "sigma", "wavelength_nm"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            np.testing.assert_array_equal(x, y, err_msg=name)
    assert a.channels == b.channels
    assert {k: str(v) for k, v in a.meta.items()} == b.meta


@pytest.fixture(params=["fast", "blocks", "slow"])
def path_kind(request, monkeypatch):
    """Run a test through the vectorised path (whole, and in blocks of a line or two) and through
    the line-by-line fallback."""
    if request.param == "slow":
        monkeypatch.setattr(_table, "_parse_fast", lambda *args: None)
    if request.param == "blocks":
        monkeypatch.setattr(_table, "PARSE_BLOCK", 7)
    return request.param


# --- reading ------------------------------------------------------------------------------------


def test_read_spectral(tmp_path, path_kind):
    text = (
        "# Free text, ignored\n"
        "# sample: gold foil\n"
        "#instrument:gonio-2\n"
        "\n"
        f"{HEADER}\n"
        "10,0,10,180,650,0.5\n"
        "20,-90,30,720,450,0.25\n"
        "0,359.5,90,-1e-20,550,0\n"
    )
    m = read_csv(write(tmp_path, text))
    assert m.meta == {"sample": "gold foil", "instrument": "gonio-2"}
    np.testing.assert_array_equal(m.theta_i, [10, 20, 0])
    np.testing.assert_array_equal(m.phi_i, [0, 270, 359.5])
    np.testing.assert_array_equal(m.phi_o, [180, 0, 0])  # modulo 360; a tiny negative φ is 0, not 360
    np.testing.assert_array_equal(m.wavelength_nm, [450, 550, 650])
    np.testing.assert_array_equal(m.band, [2, 0, 1])
    np.testing.assert_array_equal(m.brdf, [0.5, 0.25, 0])
    assert m.sigma is None and m.channels is None
    assert m.source == str(tmp_path / "data.csv")


def test_read_rgb_channels_in_rgb_order(tmp_path, path_kind):
    text = "theta_i,phi_i,theta_o,phi_o,channel,brdf,sigma\n10,0,10,180,B,0.5,0.01\n10,0,10,180,R,0.7,0.02\n"
    m = read_csv(write(tmp_path, text))
    assert m.channels == ("R", "B") and m.wavelength_nm is None
    np.testing.assert_array_equal(m.band, [1, 0])
    np.testing.assert_array_equal(m.sigma, [0.01, 0.02])


def test_columns_in_any_order_extra_columns_ignored(tmp_path, path_kind):
    text = "note,brdf,phi_o,theta_o,wavelength_nm,phi_i,theta_i,model\nfirst,0.5,180,10,550,0,20,0.4\n,0.25,90,30,550,45,40,0.2\n"
    m = read_csv(write(tmp_path, text))
    np.testing.assert_array_equal(m.theta_i, [20, 40])
    np.testing.assert_array_equal(m.phi_i, [0, 45])
    np.testing.assert_array_equal(m.theta_o, [10, 30])
    np.testing.assert_array_equal(m.brdf, [0.5, 0.25])


def test_no_brdf_column_reads_geometry_only(tmp_path, path_kind):
    m = read_csv(write(tmp_path, "theta_i,phi_i,theta_o,phi_o,wavelength_nm\n10,0,10,180,550\n"))
    assert m.brdf is None and m.sigma is None and len(m) == 1


def test_crlf_bom_blanks_and_trailing_lines(tmp_path, path_kind):
    text = "\ufeff# a: b\r\n" + HEADER + "\r\n 10 , 0,10 ,180,550, 0.5\r\n\t20,0,20,180,550,1e-3\r\n\r\n\r\n"
    m = read_csv(write(tmp_path, text.encode("utf-8")))
    np.testing.assert_array_equal(m.theta_i, [10, 20])
    np.testing.assert_array_equal(m.brdf, [0.5, 1e-3])
    assert m.meta == {"a": "b"}


@pytest.mark.parametrize("variant", ["spectral", "rgb", "spaces", "crlf", "text column"])
def test_large_file_takes_the_vectorised_path(tmp_path, monkeypatch, variant):
    rng = np.random.default_rng(1)
    n = 20_000
    cols = [rng.uniform(0, 90, n), rng.uniform(0, 360, n), rng.uniform(0, 90, n), rng.uniform(0, 360, n)]
    brdf = rng.uniform(0, 2, n)
    if variant == "rgb":
        band = rng.integers(0, 3, n)
        head, bands = "theta_i,phi_i,theta_o,phi_o,channel,brdf", np.array(["R", "G", "B"])[band].tolist()
    else:
        band = rng.integers(0, 3, n)
        head, bands = HEADER, (450.0 + 100 * band).tolist()
    sep, eol = (" , ", "\r\n") if variant == "spaces" else (",", "\r\n" if variant == "crlf" else "\n")
    rows = [sep.join(map(str, row)) for row in zip(*[c.tolist() for c in cols], bands, brdf.tolist())]
    if variant == "text column":
        head, rows = head + ",note", [f"{row},n/a {k} é" for k, row in enumerate(rows)]
    path = write(tmp_path, eol.join([head, *rows]) + eol)
    monkeypatch.setattr(_table, "_parse_slow", None)  # calling it would fail
    m = read_csv(path)
    np.testing.assert_array_equal(m.theta_i, cols[0])
    np.testing.assert_array_equal(m.phi_o, cols[3])
    np.testing.assert_array_equal(m.brdf, brdf)
    np.testing.assert_array_equal(m.band, band)


def test_error_message_format(tmp_path):
    path = write(tmp_path, f"# one\n# two\n{HEADER}\n10,0,10,180,550,0.5\n95.0,0,10,180,550,0.5\n")
    with pytest.raises(DataError) as info:
        read_csv(path)
    e = info.value
    assert str(e) == f"{path}:5: column 'theta_i' (1): 95.0 is outside [0, 90] degrees"
    assert (e.line, e.column, e.index, e.path) == (5, "theta_i", 1, path)
    assert isinstance(e, ValueError)


def test_earliest_bad_line_is_reported(tmp_path, path_kind):
    text = f"{HEADER}\n10,0,10,180,550,0.5\n10,0,10,180,550,0.5\n10,0,10,180,550,-1\n10,0,95,180,550,0.5\n"
    with pytest.raises(DataError, match=r"data\.csv:4: column 'brdf' \(6\): -1\.0 is negative"):
        read_csv(write(tmp_path, text))


ROW = "10,0,10,180,550,0.5\n"
ROWS = ROW * 5
BAD = [
    # (file text, message pattern)
    ("", r"data\.csv: the file is empty"),
    ("\n  \n", r"data\.csv: the file is empty"),
    ("# only: comments\n", r"data\.csv: no header row: the file has only comment lines"),
    (f"# m: 1\n{HEADER}\n\n", r"data\.csv:2: no data rows after the header"),
    (ROWS, r"data\.csv:1: no header row: this line looks like data"),
    ("theta_i,phi_i,Theta_o,phi_o,wavelength_nm,brdf\n" + ROW, r"data\.csv:1: column 'Theta_o' \(3\): is this 'theta_o'\? Column names are case sensitive"),
    ("theta_i,phi_i,theta_0,phi_o,wavelength_nm,brdf\n" + ROW, r"data\.csv:1: missing column 'theta_o' \(is 'theta_0' meant to be 'theta_o'\?\)"),
    (HEADER.replace("brdf", "BRDF") + "\n" + ROW, r"data\.csv:1: column 'BRDF' \(6\): is this 'brdf'\?"),
    ("theta_i,phi_i,phi_o,wavelength_nm,brdf\n10,0,180,550,0.5\n", r"data\.csv:1: missing column 'theta_o'"),
    (HEADER + ",theta_i\n" + "10,0,10,180,550,0.5,10\n", r"data\.csv:1: column 'theta_i' \(7\): duplicated \(also column 1\)"),
    (HEADER + ",\n" + "10,0,10,180,550,0.5,\n", r"data\.csv:1: column 7 has no name"),
    (HEADER + ",channel\n" + "10,0,10,180,550,0.5,R\n", r"data\.csv:1: both 'wavelength_nm' \(5\) and 'channel' \(7\)"),
    ("theta_i,phi_i,theta_o,phi_o,brdf\n10,0,10,180,0.5\n", r"data\.csv:1: missing column 'wavelength_nm' \(or 'channel' for RGB data\)"),
    ("theta_i,phi_i,theta_o,phi_o,wavelength_nm,sigma\n10,0,10,180,550,0.1\n", r"data\.csv:1: column 'sigma' \(6\): 'sigma' without 'brdf'"),
    (f"{HEADER}\n{ROW}10,0,10,180,550\n", r"data\.csv:3: expected 6 fields \(theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\), found 5"),
    (f"{HEADER}\n{ROW}10,0,10,180,550,0.5,1\n", r"data\.csv:3: expected 6 fields .*, found 7"),
    (f"{HEADER}\n{ROW}10,0,abc,180,550,0.5\n", r"data\.csv:3: column 'theta_o' \(3\): 'abc' is not a number"),
    (f"{HEADER}\n{ROW}10,0,1_0,180,550,0.5\n", r"data\.csv:3: column 'theta_o' \(3\): '1_0' is not a number"),
    (f"{HEADER}\n{ROW}10,,10,180,550,0.5\n", r"data\.csv:3: column 'phi_i' \(2\): empty value"),
    (f"{HEADER}\n{ROW}10, ,10,180,550,0.5\n", r"data\.csv:3: column 'phi_i' \(2\): empty value"),
    (f"{HEADER}\n{ROW}10,0,10,180,550,nan\n", r"data\.csv:3: column 'brdf' \(6\): NaN is not allowed"),
    (f"{HEADER}\n{ROW}10,0,10,-inf,550,0.5\n", r"data\.csv:3: column 'phi_o' \(4\): -inf is not allowed"),
    (f"{HEADER}\n{ROW}10,0,10,180,550,1e400\n", r"data\.csv:3: column 'brdf' \(6\): inf is not allowed"),
    (f"{HEADER}\n{ROW}90.5,0,10,180,550,0.5\n", r"data\.csv:3: column 'theta_i' \(1\): 90\.5 is outside \[0, 90\] degrees"),
    (f"{HEADER}\n{ROW}10,0,-1,180,550,0.5\n", r"data\.csv:3: column 'theta_o' \(3\): -1\.0 is outside \[0, 90\] degrees"),
    (f"{HEADER}\n{ROW}10,0,10,180,550,-0.001\n", r"data\.csv:3: column 'brdf' \(6\): -0\.001 is negative"),
    (f"{HEADER}\n{ROW}10,0,10,180,0,0.5\n", r"data\.csv:3: column 'wavelength_nm' \(5\): 0\.0 is not a positive wavelength"),
    (f"{HEADER},sigma\n10,0,10,180,550,0.5,0.1\n10,0,10,180,550,0.5,0\n", r"data\.csv:3: column 'sigma' \(7\): 0\.0: sigma must be positive"),
    (f"{HEADER},sigma\n10,0,10,180,550,0.5,-0.1\n", r"data\.csv:2: column 'sigma' \(7\): -0\.1: sigma must be positive"),
    ("theta_i,phi_i,theta_o,phi_o,channel,brdf\n10,0,10,180,R,0.5\n10,0,10,180,X,0.5\n",
     r"data\.csv:3: column 'channel' \(5\): 'X' is not a channel \(R, G or B\)"),
    ("theta_i,phi_i,theta_o,phi_o,channel,brdf\n10,0,10,180,r,0.5\n", r"data\.csv:2: column 'channel' \(5\): 'r' is not a channel"),
    ("theta_i,phi_i,theta_o,phi_o,channel,brdf\n10,0,10,180,,0.5\n", r"data\.csv:2: column 'channel' \(5\): '' is not a channel"),
    (f"{HEADER}\n{ROW}\n{ROW}", r"data\.csv:3: empty line"),
    (f"{HEADER}\n{ROW}# late: comment\n{ROW}", r"data\.csv:3: a # line after the header"),
    (b"# caf\xe9\n" + HEADER.encode() + b"\n", r"data\.csv:1: byte 0xe9 at byte offset 5 \(byte 6 of the line\) is not UTF-8"),
    (f"{HEADER}\n{ROW}".encode() + b"10,0,10,180,550,0.5\xff\n", r"data\.csv:3: byte 0xff at byte offset 86 \(byte 20 of the line\)"),
    (f"{HEADER}\n" + "0.5,0,0.5,3.1,550,0.5\n" * 4, r"data\.csv:1: column 'theta_i' \(1\): every theta_i and theta_o is ≤ 1\.5708 .*look like radians.*# "
                                                    r"angle_unit: degrees"),
    (f"# angle_unit: radians\n{HEADER}\n{ROW}", r"data\.csv:1: angle_unit 'radians' is not supported"),
]


@pytest.mark.parametrize("text, pattern", BAD, ids=[re.sub(r"\W+", "_", p[:40]) for _, p in BAD])
def test_bad_input_raises_located_error(tmp_path, path_kind, text, pattern):
    with pytest.raises(DataError, match=pattern):
        read_csv(write(tmp_path, text))


def test_radians_hint_needs_more_than_a_few_rows_and_can_be_overridden(tmp_path):
    few = f"{HEADER}\n" + "0.5,0,0.5,180,550,0.5\n" * 3 + "0,0,0,0,550,0.5\n" * 5
    assert len(read_csv(write(tmp_path, few))) == 8
    many = f"# angle_unit: degrees\n{HEADER}\n" + "0.5,0,0.5,180,550,0.5\n" * 10
    m = read_csv(write(tmp_path, many))
    assert len(m) == 10 and m.meta["angle_unit"] == "degrees"


# The vectorised path decodes a block's numbers as one JSON array (msgspec) and hands a block
# with a field JSON does not take to numpy.fromstring: both must read every field as Python's
# float() does, the sign of zero included.
TOKENS = ["0", "-0", "-0.0", "-0e0", "+0", "1", "-1", "+1", ".5", "-.5", "5.", "1.e5", "1E5", "1e+5", "1e-5", "007", "0.1",
          "4.9e-324", "2.2250738585072011e-308", "2.2250738585072014e-308", "1.7976931348623157e308", "1e-400", "9007199254740993",
          "123456789012345678901234567890", "0.30000000000000004", "1.0000000000000000000000000000001", "1e400", "-1e400", "inf", "nan"]


def _table_values(tmp_path, tokens: list[str], name: str) -> np.ndarray:
    text = f"{HEADER}\n" + "".join(f"10,0,20,180,550,{t}\n" for t in tokens)
    return _table.read_table(write(tmp_path, text, name)).values["brdf"]


def _same_floats(got: np.ndarray, tokens: list[str]) -> None:
    want = np.array([float(t) for t in tokens])
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(np.signbit(got), np.signbit(want))


@pytest.mark.parametrize("token", TOKENS)
def test_fast_path_reads_each_number_as_float_does(tmp_path, path_kind, token):
    """Alone (its block goes by JSON or by fromstring) and among plain numbers (the same)."""
    _same_floats(_table_values(tmp_path, [token], "one.csv"), [token])
    _same_floats(_table_values(tmp_path, ["0.25", "-0", token, "3"], "four.csv"), ["0.25", "-0", token, "3"])


def test_fast_path_takes_json_numbers_without_fromstring(tmp_path, monkeypatch):
    """Numbers JSON takes never reach numpy.fromstring; one it does not take sends its block there."""
    calls = []
    real = np.fromstring
    monkeypatch.setattr(_table.np, "fromstring", lambda *a, **k: calls.append(1) or real(*a, **k))
    plain = ["0", "-0", "-0.0", "1e-5", "4.9e-324", "123456789012345678901234567890", "2.2250738585072011e-308"]
    _same_floats(_table_values(tmp_path, plain, "plain.csv"), plain)
    assert calls == []
    _same_floats(_table_values(tmp_path, [*plain, "+1"], "plus.csv"), [*plain, "+1"])
    assert calls == [1]


def test_fast_path_signed_zero_after_blanks_and_ignored_text(tmp_path, path_kind):
    text = "note,theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\nn/a, 10, -0,20,180,550, \t -0\nsome text,10,0,20,180,550,\t-0.0\n"
    table = _table.read_table(write(tmp_path, text))
    assert np.signbit(table.values["phi_i"]).tolist() == [True, False]
    assert np.signbit(table.values["brdf"]).tolist() == [True, True]
    np.testing.assert_array_equal(table.values["theta_i"], [10, 10])


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.floats(allow_nan=False, allow_infinity=False), min_size=1, max_size=40), st.sampled_from(["repr", ".17g", ".3e", "int"]))
def test_fast_path_reads_any_printed_float(tmp_path, numbers, style):
    tokens = [repr(x) if style == "repr" else format(x, style[1:]) if style != "int" else str(int(x)) for x in numbers]
    _same_floats(_table_values(tmp_path, tokens, "any.csv"), tokens)


# --- writing ------------------------------------------------------------------------------------


def spectral(n=4, sigma=True, brdf=True):
    rng = np.random.default_rng(n)
    return Measurement(
        theta_i=rng.uniform(0, 90, n),
        phi_i=rng.uniform(0, 360, n),
        theta_o=rng.uniform(0, 90, n),
        phi_o=rng.uniform(0, 360, n),
        band=np.arange(n) % 2,
        wavelength_nm=np.array([500.0, 600.0]),
        brdf=rng.uniform(0, 1, n) if brdf else None,
        sigma=rng.uniform(0.01, 0.1, n) if sigma and brdf else None,
        meta={"sample": "test: one", "count": 3},
    )


def test_write_layout(tmp_path):
    m = spectral(2).replace(theta_i=np.array([10.0, 0.1 + 0.2]))
    path = tmp_path / "out.csv"
    write_csv(m, path, extra_columns={"model": [1.5, 2.5]}, meta={"count": 4, "by": "test"})
    lines = path.read_text().splitlines()
    assert lines[:4] == ["# sample: test: one", "# count: 4", "# by: test", "theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf,sigma,model"]
    assert lines[4].startswith("10.0,") and lines[5].startswith("0.30000000000000004,")
    assert lines[4].split(",")[4] == "500.0" and lines[5].split(",")[4] == "600.0"
    assert lines[4].endswith(",1.5") and len(lines) == 6


@pytest.mark.parametrize("brdf, sigma", [(True, True), (True, False), (False, False)])
def test_round_trip_spectral(tmp_path, brdf, sigma):
    m = spectral(7, sigma=sigma, brdf=brdf)
    write_csv(m, tmp_path / "m.csv")
    assert_same(m, read_csv(tmp_path / "m.csv"))


def test_round_trip_rgb_with_brdf_override(tmp_path):
    m = spectral(6).replace(wavelength_nm=None, channels=("R", "G", "B"), band=np.arange(6) % 3)
    values = np.linspace(0.1, 0.6, 6)
    write_csv(m, tmp_path / "m.csv", brdf=values)
    back = read_csv(tmp_path / "m.csv")
    assert "channel" in (tmp_path / "m.csv").read_text()
    assert_same(m.replace(brdf=values), back)


def test_write_accepts_jax_arrays(tmp_path):
    import jax.numpy as jnp

    m = spectral(3)
    write_csv(m.replace(brdf=jnp.asarray(m.brdf)), tmp_path / "m.csv", brdf=jnp.asarray(m.brdf) * 2)
    np.testing.assert_array_equal(read_csv(tmp_path / "m.csv").brdf, m.brdf * 2)


def test_write_is_atomic_and_replaces(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text("old contents\n")
    with pytest.raises(ValueError, match="cannot be written"):
        write_csv(spectral(), path, meta={"bad key": 1})
    assert path.read_text() == "old contents\n"
    write_csv(spectral(), path)
    assert read_csv(path).meta["sample"] == "test: one"
    assert os.listdir(tmp_path) == ["m.csv"]  # no temporary file left behind


def test_write_failure_midway_leaves_no_temporary(tmp_path, monkeypatch):
    def boom(values):
        raise RuntimeError("disk full")

    monkeypatch.setattr(_csvio, "_strings", boom)
    with pytest.raises(RuntimeError):
        write_csv(spectral(), tmp_path / "m.csv")
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize(
    "kwargs, change, pattern",
    [
        ({"meta": {"key": "two\nlines"}}, {}, "cannot be written"),
        ({"extra_columns": {"brdf": [1, 2, 3, 4]}}, {}, "extra column name"),
        ({"extra_columns": {"a,b": [1, 2, 3, 4]}}, {}, "extra column name"),
        ({"extra_columns": {"model": [1, 2]}}, {}, "'model' has 2 values for 4 samples"),
        ({"brdf": [0.1, np.nan, 0.2, 0.3]}, {}, "'brdf' has non-finite values"),
        ({}, {"channels": ("R", "IR"), "wavelength_nm": None}, "channels .* cannot be written"),
        ({}, {"theta_i": np.array([]), "phi_i": np.array([]), "theta_o": np.array([]), "phi_o": np.array([]),
              "band": np.array([], int), "brdf": None, "sigma": None}, "no samples"),
    ],
)  # fmt: skip
def test_write_rejects_what_cannot_be_read_back(tmp_path, kwargs, change, pattern):
    with pytest.raises(ValueError, match=pattern):
        write_csv(spectral().replace(**change), tmp_path / "m.csv", **kwargs)
    assert not (tmp_path / "m.csv").exists()


angles = st.floats(0, 90, allow_subnormal=True)
azimuths = st.floats(0, 360, exclude_max=True)
positive = st.floats(1e-300, 1e300)


@st.composite
def measurements(draw):
    n = draw(st.integers(1, 12))
    rgb = draw(st.booleans())
    if rgb:
        channels = draw(st.lists(st.sampled_from("RGB"), min_size=1, max_size=3, unique=True))
        bands = dict(channels=tuple(sorted(channels, key="RGB".index)))
        nb = len(channels)
    else:
        wl = draw(st.lists(st.floats(1, 1e5), min_size=1, max_size=4, unique=True))
        bands = dict(wavelength_nm=np.array(sorted(wl)))
        nb = len(wl)
    n = max(n, nb)
    band = np.array(draw(st.permutations(list(range(nb)) + draw(st.lists(st.integers(0, nb - 1), min_size=n - nb, max_size=n - nb)))))
    arr = lambda s: np.array(draw(st.lists(s, min_size=n, max_size=n)), dtype=float)
    with_brdf = draw(st.booleans())
    keys = st.from_regex(r"[A-Za-z_][\w.-]{0,8}", fullmatch=True)
    values = st.text(st.characters(blacklist_categories=("Cs", "Cc", "Zl", "Zp")), max_size=20).map(str.strip)
    return Measurement(
        theta_i=arr(angles),
        phi_i=arr(azimuths),
        theta_o=arr(angles),
        phi_o=arr(azimuths),
        band=band,
        brdf=arr(st.floats(0, 1e300)) if with_brdf else None,
        sigma=arr(positive) if with_brdf and draw(st.booleans()) else None,
        meta=draw(st.dictionaries(keys.filter(lambda k: k != "angle_unit"), values, max_size=3)) | {"angle_unit": "degrees"},
        **bands,
    )


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(m=measurements())
def test_round_trip_property(tmp_path, m):
    path = tmp_path / "rt.csv"
    write_csv(m, path)
    assert_same(m, read_csv(path))
    block, _table.PARSE_BLOCK = _table.PARSE_BLOCK, 40  # the same file in blocks of a line or so
    try:
        assert_same(m, read_csv(path))
    finally:
        _table.PARSE_BLOCK = block


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_direction_pairs_are_numpy_unique_rows(data):
    """``Measurement.directions`` (runs of repeated rows sorted once) gives np.unique's pairs
    and inverse, whether the bands of a pair are listed together or shuffled."""
    n = data.draw(st.integers(1, 60))
    base = np.array(data.draw(st.lists(st.lists(st.sampled_from([0.0, 15.0, 30.0, 45.0]), min_size=4, max_size=4), min_size=n, max_size=n)))
    rows = np.repeat(base, data.draw(st.lists(st.integers(1, 3), min_size=n, max_size=n)), axis=0)
    if data.draw(st.booleans()):
        rows = rows[np.random.default_rng(data.draw(st.integers(0, 99))).permutation(len(rows))]
    m = Measurement(theta_i=rows[:, 0], phi_i=rows[:, 1], theta_o=rows[:, 2], phi_o=rows[:, 3],
                          band=np.zeros(len(rows), int), wavelength_nm=np.array([500.0]))
    pairs, index = m.directions()
    want, inverse = np.unique(rows, axis=0, return_inverse=True)
    np.testing.assert_array_equal(pairs, want)
    np.testing.assert_array_equal(index, inverse.ravel())


def test_replace_keeps_the_direction_pairs_while_the_angles_stay():
    rng = np.random.default_rng(5)
    n = 60
    angles = {k: np.repeat(rng.uniform(0, 80, n // 3), 3) for k in ("theta_i", "phi_i", "theta_o", "phi_o")}
    m = Measurement(**angles, band=np.tile(np.arange(3), n // 3), channels=("R", "G", "B"))
    pairs, index = m.directions()
    kept = m.replace(brdf=np.ones(n))
    assert kept.directions()[0] is pairs and kept.directions()[1] is index
    moved = m.replace(theta_i=angles["theta_i"] + 1.0)
    assert moved.directions()[0] is not pairs
    np.testing.assert_array_equal(moved.directions()[1], index)


def test_given_direction_pairs_are_checked():
    m = Measurement(theta_i=np.zeros(4), phi_i=np.zeros(4), theta_o=np.ones(4), phi_o=np.zeros(4), band=np.zeros(4, int),
                          wavelength_nm=np.array([500.0]))
    with pytest.raises(ValueError, match="pairs must have shape"):
        m.with_directions(np.zeros((1, 3)), np.zeros(4, int))
    with pytest.raises(ValueError, match="integers"):
        m.with_directions(np.zeros((1, 4)), np.zeros(4))
    assert m.repeats  # found (from m's own pairs) and kept on m
    given = m.with_directions([[0.0, 0.0, 1.0, 0.0]], np.zeros(4, np.int32))
    assert given is not m and given.directions()[1].dtype == np.int32 and len(m.directions()[0]) == 1
    assert "repeats" not in given.__dict__ and given.repeats  # found again, from the pairs given
    assert given.theta_i is m.theta_i  # the same samples: no copy, and no second check of them


# --- hostile input: binary files, long lines, old line endings ------------------------------------


def test_old_mac_line_endings_read_as_lines(tmp_path, path_kind):
    """A file whose lines end in CR alone (classic Mac OS) reads as the same file with LF."""
    rows = ["# sample: cr", HEADER, "10,0,30,180,550,0.1", "20,0,40,180,650,0.2"]
    lf = read_csv(write(tmp_path, "\n".join(rows) + "\n", "lf.csv"))
    cr = read_csv(write(tmp_path, "\r".join(rows) + "\r", "cr.csv"))
    assert_same(cr, lf)
    with pytest.raises(DataError, match=r"cr\.csv:4: column 'theta_i' \(1\): 'x' is not a number"):
        read_csv(write(tmp_path, "\r".join([*rows[:3], "x,0,40,180,650,0.2"]), "cr.csv"))


@pytest.mark.parametrize(
    "content, pattern",
    [
        (HEADER.encode() + b"\n10,0,30,180,550,0.1\x00\n", r"data\.csv:2: a NUL byte at byte offset 66: a binary file"),
        ((HEADER + "\n10,0,30,180,550,0.1\n").encode("utf-16"), r"data\.csv: UTF-16 text \(the file starts with a UTF-16 byte-order mark\); save it as UTF-8"),
        ((HEADER + "\n").encode("utf-32"), r"data\.csv: UTF-32 text"),
        ((HEADER + "\n").encode("utf-16-le"), r"data\.csv:1: a NUL byte at byte offset 1: a binary file, or text not saved as UTF-8 \(UTF-16\?\)"),
    ],
)
def test_binary_and_wide_text_files_are_named_for_what_they_are(tmp_path, content, pattern):
    with pytest.raises(DataError, match=pattern):
        read_csv(write(tmp_path, content))


def test_a_binary_file_is_refused_from_its_first_block(tmp_path):
    """Zeros (a sparse file) after a header: only the first block is read, however large the file."""
    from helpers import peak_traced_bytes

    path = tmp_path / "zeros.csv"
    with open(path, "wb") as f:
        f.write((HEADER + "\n").encode())
        f.truncate(64 << 20)

    def read():
        with pytest.raises(DataError, match=r"zeros\.csv:2: a NUL byte at byte offset 47"):
            read_csv(path)

    assert peak_traced_bytes(read) < 4 << 20


@pytest.mark.parametrize(
    "text, pattern",
    [
        ("x" * 1_000_000 + "\n", r"missing column 'theta_i' \(columns: x{80}…\)$"),
        (HEADER + "," + "n" * 1_000_000 + "\n10,0,30,180,550,0.1,1,1\n", r":2: expected 7 fields \(theta_i,.*,brdf,n{33}…\), found 8$"),
        (HEADER + "\n10,0,30,180,550," + "7" * 500 + "e" * 1_000_000 + "\n", r":2: column 'brdf' \(6\): '7{80}'… is not a number$"),
        ("channel,theta_i,phi_i,theta_o,phi_o,brdf\n" + "Q" * 1_000_000 + ",10,0,30,180,0.1\n", r"column 'channel' \(1\): 'Q{80}'… is not a channel"),
        (HEADER + "," + "c" * 1_000_000 + "," + "c" * 1_000_000 + "\n1,0,30,180,550,0.1,1,1\n", r":1: column 'c{80}'… \(8\): duplicated \(also column 7\)$"),
    ],
    ids=["header", "fields", "number", "channel", "column name"],
)
def test_an_error_quotes_at_most_80_characters_of_a_field(tmp_path, text, pattern):
    with pytest.raises(DataError, match=pattern) as err:
        read_csv(write(tmp_path, text))
    assert len(str(err.value)) < len(str(tmp_path)) + 300


def test_a_line_before_the_header_longer_than_the_limit_is_refused(tmp_path, monkeypatch):
    """A header (or comment) line past ``MAX_HEADER_BYTES`` is not decoded, split or quoted."""
    monkeypatch.setattr(_table, "MAX_HEADER_BYTES", 1000)
    with pytest.raises(DataError, match=r"data\.csv:2: 1001 bytes without a line break before the header row ends: not a measurement CSV"):
        read_csv(write(tmp_path, "# fine\n" + "t" * 1001 + "\n1,2\n"))
    assert len(read_csv(write(tmp_path, "# " + "x" * 990 + "\n" + HEADER + "\n10,0,30,180,550,0.1\n"))) == 1


def test_a_wide_file_reads_and_its_errors_stay_short(tmp_path):
    """10⁵ ignored columns: read; a row with one field short names the count, not every column."""
    extra = ",".join(f"c{i}" for i in range(100_000))
    ones = ",".join(["1"] * 100_000)
    assert len(read_csv(write(tmp_path, f"{HEADER},{extra}\n10,0,30,180,550,0.1,{ones}\n"))) == 1
    with pytest.raises(DataError, match=r"expected 100006 fields \(theta_i,phi_i,.{60,80}…\), found 100005$"):
        read_csv(write(tmp_path, f"{HEADER},{extra}\n10,0,30,180,550,0.1,{ones[2:]}\n"))


# --- large files are mapped and parsed a block at a time (issue 20, item 16) ------------------


def _big_csv(path, n=200_000, bad_row=None):
    rng = np.random.default_rng(0)
    rows = np.column_stack([rng.uniform(0, 80, n), np.zeros(n), rng.uniform(0, 80, n), rng.uniform(0, 360, n), np.full(n, 550.0), rng.uniform(0.01, 3, n)])
    lines = [",".join(f"{v:.6f}" for v in r) for r in rows]
    if bad_row is not None:
        lines[bad_row] = lines[bad_row][:-1] + "\udcff"  # one byte that is not UTF-8
    body = "\n".join(lines).encode("utf-8", "surrogateescape")
    path.write_bytes("\ufeff# note: ü\ntheta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n".encode() + body + b"\n")
    return path


def test_a_mapped_file_reads_as_a_read_one(tmp_path, monkeypatch):
    import ctfit._io.files as files

    path = _big_csv(tmp_path / "big.csv", n=20_000)
    read = ctfit.read_csv(path)
    monkeypatch.setattr(files, "MAP_BYTES", 0)
    mapped = ctfit.read_csv(path)
    assert mapped.meta == read.meta == {"note": "ü"}
    for name in ("theta_i", "theta_o", "phi_o", "brdf"):
        np.testing.assert_array_equal(getattr(mapped, name), getattr(read, name))
    cr = tmp_path / "cr.csv"
    cr.write_bytes(path.read_bytes().replace(b"\n", b"\r\n"))
    np.testing.assert_array_equal(ctfit.read_csv(cr).brdf, read.brdf)


@pytest.mark.parametrize("mapped", [False, True])
def test_a_byte_that_is_not_utf8_far_into_the_file_is_located(tmp_path, monkeypatch, mapped):
    import ctfit._io.files as files

    monkeypatch.setattr(files, "MAP_BYTES", 0 if mapped else 1 << 40)
    monkeypatch.setattr(files, "_CHECK_BLOCK", 1 << 12)  # the bad byte in a later block
    path = _big_csv(tmp_path / "bad.csv", n=5_000, bad_row=4_000)
    with pytest.raises(DataError, match=r"bad\.csv:4003: byte 0xff at byte offset \d+ .* is not UTF-8"):
        ctfit.read_csv(path)


def test_a_large_file_is_not_held_in_memory(tmp_path, monkeypatch):
    """Mapped, the file's bytes are never copied whole: the traced peak of reading drops by
    about the file's size (what is left: the columns and one block's temporaries)."""
    import tracemalloc

    import ctfit._io.files as files

    path = _big_csv(tmp_path / "big.csv")
    size = path.stat().st_size

    def peak():
        tracemalloc.start()
        ctfit.read_csv(path)
        top = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return top

    monkeypatch.setattr(files, "MAP_BYTES", 1 << 40)
    whole = peak()
    monkeypatch.setattr(files, "MAP_BYTES", 0)
    assert peak() < whole - 0.8 * size


def test_metadata_naming_a_file_that_is_not_utf8_is_written_as_utf8(tmp_path):
    """``ctfit simulate`` of a material file whose name is not UTF-8 writes that name in a ``#``
    line: its undecodable bytes as U+FFFD (the file is UTF-8 text, which lone surrogates are not)."""
    m = Measurement(theta_i=np.array([30.0]), phi_i=np.zeros(1), theta_o=np.array([30.0]), phi_o=np.array([180.0]),
                    band=np.zeros(1, int), wavelength_nm=np.array([550.0]), brdf=np.array([0.25]))
    write_csv(m, tmp_path / "one.csv", meta={"material": os.fsdecode(b"caf\xe9.toml")})
    assert read_csv(tmp_path / "one.csv").meta["material"] == "caf\ufffd.toml"


def test_angles_the_reader_would_take_for_radians_are_written_with_their_unit(tmp_path):
    """``write_csv`` of θ all within π/2 degrees (a narrow goniometer near normal), or of φ within
    ±2π degrees with fractions beside larger θ: the file says ``# angle_unit: degrees`` and reads
    back (the reader refused what ctfit wrote); other files are written without that line."""
    rng = np.random.default_rng(0)
    n = 50
    narrow = ctfit.Measurement(theta_i=rng.uniform(0, 1.5, n), phi_i=np.zeros(n), theta_o=rng.uniform(0, 1.5, n), phi_o=rng.uniform(0, 360, n),
                               band=np.zeros(n, int), wavelength_nm=np.array([550.0]), brdf=rng.uniform(0.1, 1, n))
    small_phi = narrow.replace(theta_i=rng.uniform(0, 80, n), phi_o=rng.uniform(-6, 6, n))
    usual = narrow.replace(theta_i=rng.uniform(0, 80, n))
    for name, m in (("narrow", narrow), ("small_phi", small_phi), ("usual", usual)):
        path = tmp_path / f"{name}.csv"
        ctfit.write_csv(m, path)
        assert ("# angle_unit: degrees" in path.read_text()) == (name != "usual")
        back = ctfit.read_csv(path)
        np.testing.assert_array_equal(back.theta_i, m.theta_i)
        np.testing.assert_allclose(np.mod(back.phi_o, 360), np.mod(m.phi_o, 360), rtol=1e-15)


def test_a_number_past_float64s_range_is_named_as_such(tmp_path):
    """``1e400`` reads as inf: the message says why a number in the file is infinite."""
    path = tmp_path / "big.csv"
    path.write_text("theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n10,0,20,180,500,1e400\n")
    with pytest.raises(ctfit.DataError, match=r"big\.csv:2: column 'brdf' \(6\): inf is not allowed .*beyond ±1\.8e308, float64's range"):
        ctfit.read_csv(path)


def test_a_band_of_unknown_wavelength_reads_back_unknown(tmp_path):
    """Single-band data without a wavelength (an ALTA file's) written as CSV gets '# band: unknown
    …' and reads back unknown: the stand-in 550 nm read as a real band, and a fit of it was given
    a colour. The line with several bands is refused, naming it."""
    m = Measurement(theta_i=np.array([10.0, 20.0]), phi_i=np.zeros(2), theta_o=np.array([30.0, 40.0]), phi_o=np.full(2, 180.0),
                    band=np.zeros(2, int), wavelength_nm=np.array([550.0]), brdf=np.array([0.1, 0.2]), band_unknown=True)
    write_csv(m, tmp_path / "u.csv")
    assert "# band: unknown (no known wavelength; 550 nm stands in)" in (tmp_path / "u.csv").read_text()
    back = read_csv(tmp_path / "u.csv")
    assert back.band_unknown and back.band_labels == ["unknown band"] and np.array_equal(back.brdf, m.brdf)
    known = m.replace(band_unknown=False)
    write_csv(known, tmp_path / "k.csv")
    assert not read_csv(tmp_path / "k.csv").band_unknown and "# band" not in (tmp_path / "k.csv").read_text()
    (tmp_path / "two.csv").write_text("# band: unknown\ntheta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n10,0,30,180,450,0.1\n10,0,30,180,650,0.2\n")
    with pytest.raises(DataError, match=r"two.csv:1: '# band: unknown' marks data of one band .* the file has 2 wavelengths"):
        read_csv(tmp_path / "two.csv")
