"""MERL .binary files: index mapping, half/difference angles, end-to-end reading of written tables."""

import math

import numpy as np
import pytest

from ctfit import (
    DataError,
    angles_deg_to_half_diff_deg,
    half_diff_deg_to_angles_deg,
    merl_table,
    read_merl,
    write_merl,
)
from ctfit._io.merl import MERL_SCALE, merl_cell_centres, merl_phi_d_index, merl_theta_d_index, merl_theta_h_index


def model(th, td, pd):
    """An analytic isotropic RGB 'BRDF' that varies along every table axis."""
    return (0.1 + np.cos(th) ** 8, 0.2 + np.sin(td) * np.cos(th), 0.3 + 0.1 * np.cos(2 * pd) + 0 * th)


@pytest.fixture(scope="module")
def merl_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("merl") / "model.binary"
    table = merl_table(model)
    write_merl(path, table)
    return path, table


def test_index_mapping_matches_the_reference_code():
    # θ_h: floor(sqrt(θ_h / (π/2) · 90 · 90)), clamped; θ ≤ 0 → 0
    assert merl_theta_h_index(-0.1) == 0 and merl_theta_h_index(0.0) == 0
    assert merl_theta_h_index(math.pi / 2) == 89 and merl_theta_h_index(2.0) == 89
    assert merl_theta_h_index((math.pi / 2) * (10.5 / 90) ** 2) == 10
    assert merl_theta_h_index(math.radians(45)) == int(math.sqrt(0.5 * 8100))  # = 63
    # θ_d: uniform, 1° bins
    np.testing.assert_array_equal(merl_theta_d_index(np.radians([0, 0.99, 1.01, 45.5, 89.9, 95])), [0, 0, 1, 45, 89, 89])
    # φ_d: folded into [0, π) (reciprocity), 1° bins
    np.testing.assert_array_equal(merl_phi_d_index(np.radians([0, 0.5, 179.5, -0.5, -90.5, 180.5, 359.5])), [0, 0, 179, 179, 89, 0, 179])


def test_cell_centres_are_the_inverse_of_the_index_mapping():
    th, td, pd = merl_cell_centres()
    np.testing.assert_array_equal(merl_theta_h_index(th), np.arange(90))
    np.testing.assert_array_equal(merl_theta_d_index(td), np.arange(90))
    np.testing.assert_array_equal(merl_phi_d_index(pd), np.arange(180))
    assert th[0] == pytest.approx((math.pi / 2) * (0.5 / 90) ** 2)


def test_half_diff_special_configurations():
    # θ_d = 0: light and viewer both along the half vector.
    ti, pi, to, po = half_diff_deg_to_angles_deg(30.0, 0.0, math.degrees(1.0))
    assert (ti, pi, to, po) == pytest.approx((30, 0, 30, 0))
    # θ_h = 0: the mirror configuration, θ_i = θ_o = θ_d, φ_o = φ_i + 180.
    ti, pi, to, po = half_diff_deg_to_angles_deg(0.0, 40.0, 90.0)
    assert (ti, pi, to, po) == pytest.approx((40, 90, 40, 270))
    # In the plane of incidence: θ_i = θ_h + θ_d, θ_o = θ_h − θ_d (light on the +x side).
    ti, pi, to, po = half_diff_deg_to_angles_deg(50.0, 20.0, 0.0)
    assert (ti, pi, to) == pytest.approx((70, 0, 30)) and po == pytest.approx(0, abs=1e-12)


def test_half_diff_round_trip():
    rng = np.random.default_rng(0)
    th, td, pd = rng.uniform(0.5, 40, 500), rng.uniform(0.5, 40, 500), rng.uniform(-179, 179, 500)
    angles = half_diff_deg_to_angles_deg(th, td, pd)
    assert max(angles[0].max(), angles[2].max()) < 90
    back = angles_deg_to_half_diff_deg(*angles)
    np.testing.assert_allclose(back, (th, td, pd), atol=1e-10)


def test_the_old_radian_names_warn_and_keep_their_meaning():
    """``half_diff_to_angles_deg`` took radians and ``angles_deg_to_half_diff`` returned them:
    both still do, with a DeprecationWarning naming the degree functions that replace them."""
    import ctfit

    with pytest.warns(DeprecationWarning, match="half_diff_deg_to_angles_deg"):
        old = ctfit.half_diff_to_angles_deg(math.radians(50), math.radians(20), math.radians(30))
    np.testing.assert_allclose(old, half_diff_deg_to_angles_deg(50.0, 20.0, 30.0), rtol=1e-14)
    with pytest.warns(DeprecationWarning, match="angles_deg_to_half_diff_deg"):
        back = ctfit.angles_deg_to_half_diff(*old)
    np.testing.assert_allclose(np.degrees(back), (50.0, 20.0, 30.0), rtol=1e-12)


def test_read_back_a_written_table_end_to_end(merl_file):
    """Each sample's directions map back to the cell it came from, with that cell's value."""
    path, table = merl_file
    m = read_merl(path)
    assert m.channels == ("R", "G", "B") and m.sigma is None and m.meta["format"] == "MERL"
    above = int(m.meta["merl_cells_below_horizon"])
    assert len(m) == 3 * (90 * 90 * 180 - above) and 0 < above < 90 * 90 * 180 / 2
    assert max(m.theta_i.max(), m.theta_o.max()) < 90 and m.phi_i.min() >= 0 and m.phi_o.max() < 360
    np.testing.assert_array_equal(m.band[:3], [0, 1, 2])  # ordered by cell, then channel
    k = np.random.default_rng(0).choice(len(m), 50_000, replace=False)  # a sample keeps the test fast
    th, td, pd = np.radians(angles_deg_to_half_diff_deg(m.theta_i[k], m.phi_i[k], m.theta_o[k], m.phi_o[k]))
    cell = (merl_theta_h_index(th), merl_theta_d_index(td), merl_phi_d_index(pd))
    np.testing.assert_allclose(m.brdf[k], table[(m.band[k], *cell)], rtol=1e-15)
    # ... and equal the model at the recovered angles (ill-conditioned only where θ_h → 0 and θ_d → 90°).
    expected = np.choose(m.band[k], np.broadcast_arrays(*model(th, td, pd)))
    np.testing.assert_allclose(m.brdf[k], expected, rtol=1e-8)


def test_scale_factors_and_missing_cells(tmp_path):
    table = merl_table(lambda th, td, pd: 0.5 + 0 * th)
    table[1, 0, 0, :] = np.nan  # G unmeasured along one row of cells
    table[2, 0, 0, 0] = -1.0
    write_merl(tmp_path / "m.binary", table)
    raw = np.fromfile(tmp_path / "m.binary", "<f8", offset=12).reshape(3, 90, 90, 180)
    np.testing.assert_allclose(raw[:, 5, 5, 5], 0.5 / MERL_SCALE)
    assert raw[1, 0, 0, 3] == -1.0
    m = read_merl(tmp_path / "m.binary")
    assert m.meta["merl_unmeasured_values"] == "181"
    per_channel = np.bincount(m.band, minlength=3)
    assert per_channel[0] - per_channel[1] == 180 and per_channel[0] - per_channel[2] == 1
    np.testing.assert_allclose(m.brdf, 0.5, rtol=1e-15)


def _header(dims):
    return np.array(dims, "<i4").tobytes()


@pytest.mark.parametrize(
    "content, pattern",
    [
        (b"", r"truncated: 0 bytes; a MERL file starts with three int32"),
        (b"\x5a\x00\x00\x00", r"truncated: 4 bytes"),
        (_header((90, 90, 360)), r"dimensions \(90, 90, 360\) in the header .* a MERL file has \(90, 90, 180\)"),
        (_header((90, 90, 180)) + b"\0" * 800, r"truncated: 812 bytes; a \(90, 90, 180\) table of 3 channels takes 34992012 bytes"),
        (_header((90, 90, 180)) + b"\0" * (3 * 90 * 90 * 180 * 8 + 1), r"too long: 34992013 bytes"),
        (_header((90, 90, 180)) + np.r_[np.zeros(1458000 + 7), np.inf, np.zeros(2 * 1458000 - 8)].tobytes(),
         r"G table, cell \(0, 0, 7\) \(byte offset 11664068\): inf is not a finite number"),
        (_header((90, 90, 180)) + np.full(3 * 1458000, -1.0).tobytes(),
         r"no measured value: every cell is unmeasured \(negative\) or has the light or the viewer below the horizon"),
    ],
)  # fmt: skip
def test_bad_files_raise(tmp_path, content, pattern):
    (tmp_path / "bad.binary").write_bytes(content)
    with pytest.raises(DataError, match=r"bad\.binary: " + pattern):
        read_merl(tmp_path / "bad.binary")


@pytest.mark.parametrize(
    "table, pattern",
    [(np.zeros((3, 90, 90, 90)), r"shape \(3, 90, 90, 180\), got \(3, 90, 90, 90\)"), (np.full((3, 90, 90, 180), np.inf), "infinite"),
     (np.full((3, 90, 90, 180), 1e306), r"channel R, cell \(0, 0, 0\): 1e\+306 sr⁻¹ is too large for a MERL file"),  # (read_merl refused what it wrote)
     (np.ones((3, 90, 90, 180)) + 1j, "real BRDF values, got complex ones")],
)
def test_write_merl_rejects_bad_tables(tmp_path, table, pattern):
    with pytest.raises(ValueError, match=pattern):
        write_merl(tmp_path / "m.binary", table)
    assert not (tmp_path / "m.binary").exists()


def test_merl_table_checks_channel_count():
    with pytest.raises(ValueError, match="returned 2 channels"):
        merl_table(lambda th, td, pd: (th, td))


def test_the_reader_gives_its_direction_pairs(merl_file):
    """The pairs a MERL file hands over are what a search of its rows finds (as a set: in cell
    order, not lexicographic), each sample points at its own pair, and memory-light types."""
    m = read_merl(merl_file[0])
    pairs, index = m.directions()
    assert index.dtype == np.int32 and m.band.dtype == np.int8
    rows = np.stack([m.theta_i, m.phi_i, m.theta_o, m.phi_o], axis=1)
    np.testing.assert_array_equal(pairs[index], rows)
    searched, _ = m.replace(theta_i=m.theta_i.copy()).directions()  # new angles: found by search
    assert len(searched) == len(pairs) == len(np.unique(pairs, axis=0))
    np.testing.assert_array_equal(np.unique(pairs, axis=0), searched)
    assert not m.repeats and m.grid() is not None


def test_the_reader_holds_the_angles_per_cell(merl_file):
    """A MERL table's samples repeat their cell's direction pair in R, G and B: the measurement
    holds the pairs (a third of the per-sample angles' 32 bytes a sample), not the angles, until
    they are read. The arrays it holds: 24 bytes a sample here (56 with the angles: a warm fit
    of a whole table peaked 100 MiB higher)."""
    m = read_merl(merl_file[0])
    held = sum(a.nbytes for v in vars(m).values() for a in (v if isinstance(v, tuple) else (v,)) if isinstance(a, np.ndarray))
    assert held < 30 * len(m)
    assert m.theta_o[1] == m.theta_o[2] == m.directions()[0][0, 2]  # the first cell's R, G, B


def test_a_file_of_another_size_is_not_read_whole(tmp_path):
    """A large file named .binary (a sparse GiB): refused from its size, at most one table read."""
    from helpers import peak_traced_bytes

    path = tmp_path / "large.binary"
    with open(path, "wb") as f:
        f.write(_header((90, 90, 180)))
        f.truncate(1 << 30)

    def read():
        with pytest.raises(DataError, match=r"large\.binary: too long: 1073741824 bytes; a \(90, 90, 180\) table"):
            read_merl(path)

    assert peak_traced_bytes(read) < 64 << 20
