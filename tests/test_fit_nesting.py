"""--lobes auto: each larger candidate starts from the fit it contains, so its cost is never
above that candidate's; conductor fits start from n, k that match the data's F0."""

import numpy as np
import pytest

import ctfit
from ctfit import normal_reflectance, simulate
from ctfit._fitting.structure_selection import _contains, _embedded_start

WL = np.linspace(400.0, 700.0, 6)


def test_every_candidate_costs_no_more_than_the_ones_it_contains():
    truth = ctfit.Material(ctfit.Structure(lobes=2, diffuse="F0/pi"),
                           ctfit.Params(s=np.asarray(0.8), m=np.array([0.08, 0.35]), w=np.array([0.5, 0.5]), f0=np.linspace(0.4, 0.9, 6)),
                           wavelength_nm=WL)
    data = simulate(truth, 400, noise=0.02, seed=4)
    cands = [ctfit.Structure(lobes=j, diffuse=d) for j in (1, 2, 3) for d in (None, "F0/pi")]
    best, table = ctfit.select_structure(data, cands, starts=2)
    cost = {(st.lobes, st.diffuse): r.stats["cost"] for st, r in table}
    pairs = [(big, small) for big in cands for small in cands if _contains(big, small)]
    assert len(pairs) == 7
    for big, small in pairs:
        assert cost[(big.lobes, big.diffuse)] <= cost[(small.lobes, small.diffuse)] * (1 + 1e-9), (big, small)
    assert best.material.structure.lobes >= 2


def test_embedded_start_gives_the_same_model():
    small = ctfit.Structure(lobes=1)
    big = ctfit.Structure(lobes=2, diffuse="F0/pi")
    data = simulate(ctfit.Material(small, ctfit.Params(m=np.array([0.2]), w=np.array([1.0]), f0=np.full(6, 0.7)), wavelength_nm=WL), 200, seed=1)
    inner = ctfit.fit(data, small)
    mid = ctfit.Structure(lobes=2)
    start = _embedded_start(inner, mid)
    assert start.w[1] == 0.0 and not np.isclose(start.m[1], start.m[0])
    a = ctfit.evaluate(inner.material, data)
    b = ctfit.evaluate(ctfit.Material(mid, start, wavelength_nm=WL), data)
    np.testing.assert_allclose(b, a, rtol=1e-12)
    assert not _contains(big, small)  # two steps apart: reached through (2 lobes) or (1 lobe + diffuse)


def test_conductor_fit_starts_near_a_low_f0():
    """n ≈ 1.1–1.3, k = 0 (F0 ≲ 0.02): the start from the data's scale finds it."""
    st = ctfit.Structure(lobes=1, fresnel="conductor")
    truth = ctfit.Material(st, ctfit.Params(m=np.array([0.2]), w=np.array([1.0]), n=np.array([1.3, 1.25, 1.2, 1.15, 1.1, 1.05]),
                                            k=np.zeros(6)), wavelength_nm=WL)
    data = simulate(truth, 400, noise=0.01, seed=2)
    res = ctfit.fit(data, st)
    assert res.converged
    np.testing.assert_allclose(res.material.params.m, [0.2], rtol=0.02)
    f0 = np.asarray(normal_reflectance(st, res.material.params))
    f0_true = ((truth.params.n - 1) / (truth.params.n + 1)) ** 2
    np.testing.assert_allclose(f0, f0_true, atol=2e-3)


def test_lobes_a_larger_candidate_leaves_unused_are_not_chosen():
    """A one-lobe metal with F0 = 10⁻⁴ and its own R_d: the one-lobe candidate stopped at the
    candidates' step budget, and a larger one that reached the exact fit with its extra lobes at
    weight 0 (and 7·10⁻¹⁸) was chosen. The one-lobe structure is now solved on from it, and chosen."""
    truth = ctfit.Material(ctfit.Structure(lobes=1, diffuse="spectrum"),
                           ctfit.Params(s=np.asarray(0.5), m=np.array([0.2]), w=np.ones(1), f0=np.full(3, 1e-4), rd=np.array([0.05, 0.1, 0.3])),
                           wavelength_nm=np.array([450.0, 550.0, 650.0]))
    best, tried = ctfit.choose_structure(simulate(truth, n_pairs=300, seed=0))
    st = best.material.structure
    assert (st.family, st.lobes, st.diffuse) == ("metal", 1, "spectrum"), [(s.family, s.lobes, s.diffuse) for s, _ in tried]
    assert best.converged and float(best.material.params.m[0]) == pytest.approx(0.2, rel=1e-6)
    assert sum(s == st for s, _ in tried) == 1  # its row in the table is the fit solved on, not a second one


@pytest.mark.parametrize(("kwargs", "error", "message"), [
    ({"lobes": 0}, TypeError, r"lobes must be a non-empty sequence, e\.g\. \(1,\), got 0"),
    ({"lobes": (9,)}, ValueError, r"lobes must be taken from 1\.\.8, got 9"),
    ({"lobes": (2, 1)}, ValueError, r"lobes must increase .*got \[2, 1\]"),
    ({"families": ("glass",)}, ValueError, r"families must be taken from \['metal', 'plastic'\], got 'glass'"),
    ({"families": "metal"}, TypeError, r"families must be a non-empty sequence"),
    ({"geometry": "x"}, ValueError, r"geometry must be one of \['v-cavity', 'smith', 'smith-rational'\], got 'x'"),
    ({"fresnel": "x"}, ValueError, r"fresnel must be one of \[None, 'f0', 'conductor'\], got 'x'"),
    ({"data": "s.csv"}, TypeError, r"data must be a ctfit\.Measurement, got str"),
])
def test_choose_structure_names_a_wrong_argument(kwargs, error, message):
    """Data that is not a Measurement raised AttributeError, ``lobes=0`` "'int' object is not
    subscriptable", ``families=("glass",)`` KeyError 'glass', ``geometry="x"`` an error about the
    diffuse part, and ``fresnel="x"`` was ignored (a fit came back); each names its argument now."""
    truth = ctfit.Material(ctfit.Structure(lobes=1), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.5, 0.9])),
                           wavelength_nm=np.array([450.0, 650.0]))
    kwargs = {"data": simulate(truth, 30, seed=1), **kwargs}
    with pytest.raises(error, match=message):
        ctfit.choose_structure(kwargs.pop("data"), **kwargs)
