"""The model-mismatch test-bed (``measurements/testbed/``) stays what its headers say: every file
reads, and its values are Mitsuba's BSDF, evaluated afresh from the header's own plugin at the
file's own directions."""

import json

import numpy as np
import pytest

import ctfit

from conftest import ROOT, load_script

mi = pytest.importorskip("mitsuba", reason="Mitsuba 3 is not installed (pip install mitsuba)")
pytestmark = pytest.mark.mitsuba

TESTBED = ROOT / "measurements" / "testbed"
FILES = sorted(TESTBED.glob("*.csv"))
make = load_script("make_testbed")


def test_testbed_has_one_file_per_case():
    assert [p.stem for p in FILES] == sorted(make.CASES)


@pytest.mark.parametrize("path", FILES, ids=lambda p: p.stem)
def test_testbed_file_reads_and_is_the_plugin_its_header_names(path):
    d = ctfit.read_measurement(path)
    assert len(d) == 3 * make.N_PAIRS and d.channels == ("R", "G", "B") and np.all(d.brdf > 0)
    assert d.meta["noise"] == "none" and d.meta["mitsuba"].startswith(mi.__version__)
    bsdf = json.loads(d.meta["bsdf"])
    assert bsdf == make.CASES[path.stem]["bsdf"]
    # The directions are the ones the header describes.
    case = make.CASES[path.stem]
    ti, pi, to, po = make.directions(make.N_PAIRS, case["spread"], case["seed"])
    for got, want in ((d.theta_i, ti), (d.phi_i, pi), (d.theta_o, to), (d.phi_o, po)):
        np.testing.assert_array_equal(got[::3], want)
    # A fresh evaluation of the header's plugin at a few of the file's own pairs (the script's float64 unit vectors:
    # a float32 ulp of a direction moves the α = 0.05 peak by 10⁻⁴). Mitsuba's scalar_rgb variant computes in float32,
    # and its rounding depends on the processor's instructions (Dr.Jit's): the file (made on an AMD EPYC) and an Intel
    # Xeon with AVX-512 differ by up to 1.3·10⁻⁶ of the value near the rough plastic's peak, so the check allows 10⁻⁵
    # (a wrong plugin or parameter is off by far more).
    mi.set_variant("scalar_rgb")
    plugin, ctx = mi.load_dict(bsdf), mi.BSDFContext()
    si = mi.SurfaceInteraction3f()
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    rows = np.random.default_rng(0).choice(make.N_PAIRS, 12, replace=False) * 3
    light, view = make.unit_vectors(d.theta_i[rows], d.phi_i[rows]), make.unit_vectors(d.theta_o[rows], d.phi_o[rows])
    for row, l, v in zip(rows, light, view):
        si.wi = mi.Vector3f(*l)
        fresh = np.array(plugin.eval(ctx, si, mi.Vector3f(*v)), dtype=float) / v[2]
        assert d.band[row : row + 3].tolist() == [0, 1, 2]
        np.testing.assert_allclose(d.brdf[row : row + 3], fresh, rtol=1e-5, err_msg=f"{path.name}, row {row}")
