"""One rule for samples: ``ctfit.Measurement`` refuses what the CSV reader refuses (and texel
stores, tests/test_texel_maps.py), naming the field and the row; ``fit`` names a ``data`` that is
not a Measurement."""

import pathlib

import numpy as np
import pytest

import ctfit


def measurement(**changes):
    base = dict(theta_i=np.array([30.0, 40.0, 50.0]), phi_i=np.zeros(3), theta_o=np.array([30.0, 40.0, 50.0]), phi_o=np.full(3, 180.0),
                band=np.array([0, 1, 0]), wavelength_nm=np.array([450.0, 650.0]), brdf=np.array([1.0, 2.0, 3.0]))
    return ctfit.Measurement(**{**base, **changes})


@pytest.mark.parametrize("changes, error, words", [
    (dict(theta_i=np.array([30.0, 120.0, 50.0])), ValueError, "theta_i[1]: 120.0 is outside [0, 90] degrees"),
    (dict(theta_o=np.array([30.0, 40.0, np.nan])), ValueError, "theta_o[2]: NaN is not allowed"),
    (dict(phi_i=np.array([0.0, np.inf, 0.0])), ValueError, "phi_i[1]: inf is not allowed"),
    (dict(brdf=np.array([1.0, -2.0, 3.0])), ValueError, "brdf[1]: -2.0 is negative"),
    (dict(sigma=np.array([0.1, 0.0, 0.1])), ValueError, "sigma[1]: 0.0: sigma must be positive"),
    (dict(brdf=np.array([1.0, 2.0, 3.0]) + 1j), TypeError, "brdf must be a 1-D array of real numbers, got complex128"),
    (dict(brdf=np.array(["a", "b", "c"])), TypeError, "brdf must be a 1-D array of real numbers"),
    (dict(band=np.array([0, 7, 0])), ValueError, "band[1] = 7 is not a band index: the data has 2 bands (0..1)"),
    (dict(band=np.array([0.0, 1.0, 0.0])), TypeError, "band must be a 1-D array of integers"),
    (dict(wavelength_nm=np.array([-5.0, 650.0])), ValueError, "wavelength_nm[0]: -5.0 is not a positive wavelength in nm"),
    (dict(wavelength_nm=np.array([650.0, 450.0])), ValueError, "wavelength_nm[1]: the wavelengths must be strictly increasing"),
])
def test_a_measurement_refuses_what_a_reader_refuses(changes, error, words):
    with pytest.raises(error) as caught:
        measurement(**changes)
    assert words in str(caught.value)


def test_the_csv_reader_and_measurement_give_the_same_reason(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text("theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n30,0,30,180,550,1\n120,0,30,180,550,1\n")
    with pytest.raises(ctfit.DataError) as from_csv:
        ctfit.read_csv(path)
    with pytest.raises(ValueError) as from_memory:
        measurement(theta_i=np.array([30.0, 120.0, 50.0]))
    assert from_csv.value.reason in str(from_memory.value)


@pytest.mark.parametrize("data", [None, [1, 2], "data.csv", pathlib.Path("data.csv"), {"brdf": [1.0]}])
def test_fit_names_data_that_is_not_a_measurement(data):
    with pytest.raises(TypeError, match="data must be a ctfit.Measurement, got"):
        ctfit.fit(data)
    with pytest.raises(TypeError, match="structure must be a ctfit.Structure"):
        ctfit.fit(measurement(), structure="lobes=2")


def test_sample_names_data_that_is_not_a_measurement():
    gold = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.4, 0.9])),
                          wavelength_nm=np.array([450.0, 650.0]))
    with pytest.raises(TypeError, match="data must be a ctfit.Measurement"):
        ctfit.sample(gold, "data.csv", steps=2)


def per_pair(**changes):
    """Three samples, their angles held per direction pair: the first pair in two bands, the second in one."""
    base = dict(band=np.array([0, 1, 0]), wavelength_nm=np.array([450.0, 650.0]), brdf=np.array([1.0, 2.0, 3.0]))
    pairs = changes.pop("pairs", np.array([[30.0, 0, 30, 180], [40, 0, 40, 180]]))
    return ctfit.Measurement.from_direction_pairs(pairs, changes.pop("index", np.array([0, 0, 1])), **{**base, **changes})


@pytest.mark.parametrize("changes, words", [
    (dict(pairs=np.array([[30.0, 0, 30, 180], [40, 0, 120, 180]])), "theta_o[2]: 120.0 is outside [0, 90] degrees"),  # the first sample of that pair
    (dict(pairs=np.array([[30.0, 0, 30, 180], [40, np.nan, 40, 180]])), "phi_i[2]: NaN is not allowed"),
    (dict(index=np.array([0, 2, 1])), "index must point into the 2 direction pairs"),
    (dict(index=np.array([0, 1])), "theta_i has 2"),
    (dict(brdf=np.array([1.0, -2.0, 3.0])), "brdf[1]: -2.0 is negative"),
])
def test_a_measurement_held_per_pair_refuses_the_same(changes, words):
    with pytest.raises(ValueError) as caught:
        per_pair(**changes)
    assert words in str(caught.value)


def test_angles_held_per_pair_are_gathered_only_when_read():
    """``from_direction_pairs`` (a MERL table's reader): the samples' angles are not held until a
    field is read, through ``replace``, a copy, a pickle and a fit; read, they are what the
    constructor holds."""
    import copy
    import pickle

    m = per_pair()
    held = [m, m.replace(source="other"), copy.copy(m), pickle.loads(pickle.dumps(m))]
    ctfit.fit(m, ctfit.Structure(lobes=1, diffuse=None), starts=1)
    assert len(m) == 3 and not m.repeats
    for each in held:
        assert not {"theta_i", "phi_i", "theta_o", "phi_o"} & vars(each).keys()
        np.testing.assert_array_equal(each.directions()[0], [[30.0, 0, 30, 180], [40, 0, 40, 180]])
    expected = measurement(theta_i=np.array([30.0, 30.0, 40.0]), theta_o=np.array([30.0, 30.0, 40.0]))
    for name in ("theta_i", "phi_i", "theta_o", "phi_o"):
        np.testing.assert_array_equal(getattr(m, name), getattr(expected, name))
        assert getattr(m, name) is getattr(m, name)  # kept once read
    assert m.replace(theta_i=np.array([50.0, 40.0, 30.0])).directions()[0].tolist()[-1] == [50.0, 0.0, 30.0, 180.0]  # new angles: found by search
