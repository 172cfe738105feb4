"""``ctfit.evaluate_at``: the material at any directions (angles or unit vectors) and bands."""

import dataclasses

import numpy as np
import pytest

import ctfit

GOLD = ctfit.Material(ctfit.Structure(lobes=1, diffuse="F0/pi"), ctfit.Params(s=np.asarray(0.8), m=np.array([0.2]), w=np.ones(1), f0=np.array([0.4, 0.9])),
                      wavelength_nm=np.array([450.0, 650.0]))


def test_angles_match_evaluate_on_a_measurement():
    rng = np.random.default_rng(0)
    ti, to = rng.uniform(0, 85, 50), rng.uniform(0, 85, 50)
    pi, po = rng.uniform(0, 360, 50), rng.uniform(0, 360, 50)
    got = ctfit.evaluate_at(GOLD, theta_i=ti, phi_i=pi, theta_o=to, phi_o=po)
    rep = lambda a: np.repeat(a, 2)
    m = ctfit.Measurement(theta_i=rep(ti), phi_i=rep(pi), theta_o=rep(to), phi_o=rep(po), band=np.tile([0, 1], 50), wavelength_nm=GOLD.wavelength_nm)
    np.testing.assert_allclose(got.reshape(-1), ctfit.evaluate(GOLD, m), rtol=1e-12)


def test_unit_vectors_equal_angles_and_broadcasting_works():
    t = np.deg2rad(np.array([10.0, 40.0, 70.0]))
    l = np.stack([np.sin(np.deg2rad(30)) * np.ones(3), np.zeros(3), np.cos(np.deg2rad(30)) * np.ones(3)], -1)
    v = np.stack([-np.sin(t), np.zeros(3), np.cos(t)], -1)  # φ_o = 180°
    by_vectors = ctfit.evaluate_at(GOLD, l=l, v=v)
    by_angles = ctfit.evaluate_at(GOLD, theta_i=30.0, theta_o=[10.0, 40.0, 70.0], phi_o=180.0)
    assert by_angles.shape == (3, 2)
    np.testing.assert_allclose(by_vectors, by_angles, rtol=1e-10)
    grid = ctfit.evaluate_at(GOLD, theta_i=np.array([0.0, 45.0])[:, None], theta_o=np.linspace(0, 80, 5)[None, :], phi_o=180.0)
    assert grid.shape == (2, 5, 2)


def test_other_wavelengths_are_interpolated_and_the_horizon_gives_zero():
    at = ctfit.evaluate_at(GOLD, theta_i=20.0, theta_o=20.0, phi_o=180.0, wavelength_nm=[450.0, 550.0, 650.0])
    own = ctfit.evaluate_at(GOLD, theta_i=20.0, theta_o=20.0, phi_o=180.0)
    np.testing.assert_allclose(at[[0, 2]], own, rtol=1e-12)
    assert own[0] < at[1] < own[1]
    assert np.all(ctfit.evaluate_at(GOLD, theta_i=20.0, theta_o=95.0) == 0)


@pytest.mark.parametrize("kwargs", [{}, {"theta_i": 10.0}, {"theta_i": 10.0, "theta_o": 10.0, "l": [0, 0, 1]}, {"l": [0, 0, 1]}])
def test_directions_must_be_given_one_way(kwargs):
    with pytest.raises(ValueError, match="either as angles"):
        ctfit.evaluate_at(GOLD, **kwargs)


def test_any_number_of_directions_compiles_at_most_three_programs_and_padding_changes_no_value():
    """``evaluate`` and ``evaluate_at`` pad to 512, 2,048 or 8,192 direction pairs and cut more into
    blocks of 8,192: a loop over files of many sizes compiles three programs, not one per size (each
    took 0.3 s and its memory maps), and every value equals the model on the unpadded directions."""
    import jax

    from ctfit._model import evaluation

    mat = ctfit.Material(ctfit.Structure(lobes=2, diffuse="F0/pi"), ctfit.Params(s=np.asarray(0.7), m=np.array([0.15, 0.4]), w=np.array([0.3, 0.7]),
                         f0=np.array([0.3, 0.5, 0.9])), wavelength_nm=np.array([450.0, 550.0, 650.0]))
    rng = np.random.default_rng(3)
    sizes = (1, 2, 7, 511, 512, 513, 1500, 2049, 8191, 8193, 20_000)
    angles = [tuple(rng.uniform(0, hi, n) for hi in (89, 89, 360, 360)) for n in sizes]
    samples = [ctfit.simulate(mat, n, seed=n) for n in sizes]
    # The model on every size's directions at once (one reference program, not one per size): values per direction do not depend on the others
    model = lambda ti, pi, to, po: np.asarray(jax.jit(ctfit.brdf, static_argnums=0)(mat.structure, mat.params, ctfit.geometry_from_angles_deg(ti, pi, to, po)))
    ends = np.cumsum(sizes)[:-1]
    exact_at = np.split(model(*(np.concatenate([a[j] for a in angles]) for j in (0, 2, 1, 3))), ends)
    exact_each = np.split(model(*(np.concatenate([getattr(d, k) for d in samples]) for k in ("theta_i", "phi_i", "theta_o", "phi_o"))),
                          np.cumsum([len(d) for d in samples])[:-1])
    grid_before, vectors_before = evaluation._grid_values._cache_size(), evaluation._vector_values._cache_size()
    for n, (ti, to, pi, po), sample, exact, each in zip(sizes, angles, samples, exact_at, exact_each):
        got = ctfit.evaluate_at(mat, theta_i=ti, phi_i=pi, theta_o=to, phi_o=po)
        assert got.shape == (n, 3)
        np.testing.assert_allclose(got, exact, rtol=1e-13, atol=0)
        np.testing.assert_allclose(ctfit.evaluate(mat, sample), each[np.arange(len(sample)), sample.band], rtol=1e-13, atol=0)
        l = np.stack([np.sin(np.deg2rad(ti)), np.zeros(n), np.cos(np.deg2rad(ti))], -1)
        v = np.stack([-np.sin(np.deg2rad(to)), np.zeros(n), np.cos(np.deg2rad(to))], -1)
        np.testing.assert_allclose(ctfit.evaluate_at(mat, l=l, v=v), ctfit.evaluate_at(mat, theta_i=ti, theta_o=to, phi_o=180.0), rtol=1e-10, atol=1e-300)
    assert ctfit.evaluate_at(mat, theta_i=[], theta_o=[]).shape == (0, 3)  # none: shape (0, bands), as evaluate gives
    assert ctfit.evaluate_at(mat, l=np.zeros((0, 3)), v=np.zeros((0, 3))).shape == (0, 3)
    assert evaluation._grid_values._cache_size() - grid_before <= 3  # 512, 2,048, 8,192 rows
    assert evaluation._vector_values._cache_size() - vectors_before <= 3


@pytest.mark.parametrize("kwargs, words", [
    ({"theta_i": 30.0, "theta_o": [10.0, np.nan], "phi_o": 180.0}, "theta_o[1] is nan"),
    ({"theta_i": 30.0, "theta_o": 10.0, "phi_o": np.inf}, "phi_o is inf"),
    ({"l": [0.5, 0.0, 0.866], "v": [[0.0, 0.0, 1.0], [0.0, 0.0, 2.0]]}, "v must be unit vectors: |v[1]| = 2"),
    ({"l": [np.nan, 0.0, 1.0], "v": [0.0, 0.0, 1.0]}, "l[0] is nan"),
    ({"theta_i": 30.0, "theta_o": 10.0, "wavelength_nm": [np.nan]}, "wavelength_nm must be positive finite"),
])
def test_directions_and_wavelengths_that_are_no_numbers_or_not_unit_are_refused_by_name(kwargs, words):
    """A NaN or infinite angle, a vector of another length than 1 or a NaN wavelength gave NaN, 0 or a
    wrong value without a word: each is a ValueError naming the argument (and the entry)."""
    with pytest.raises(ValueError) as err:
        ctfit.evaluate_at(GOLD, **kwargs)
    assert words in str(err.value)


def test_a_material_without_a_parameter_per_band_has_every_band_alike(tmp_path):
    """An RGB matte of one R_d number (a spectral one too): ``evaluate_at`` gives each of its bands
    (it gave one column), ``evaluate`` each sample's band (it raised IndexError), ``ctfit eval``
    writes all three channels (it printed a traceback)."""
    from typer.testing import CliRunner

    from ctfit.cli import app

    rgb = ctfit.Material(ctfit.Structure(lobes=0, diffuse="constant"), ctfit.Params(rd=np.asarray(0.1)), channels=("R", "G", "B"))
    spectral = ctfit.Material(rgb.structure, rgb.params, wavelength_nm=np.array([450.0, 550.0, 650.0, 700.0]))
    for mat, bands in ((rgb, 3), (spectral, 4)):
        np.testing.assert_allclose(ctfit.evaluate_at(mat, theta_i=[10.0, 20.0], theta_o=[30.0, 40.0]), np.full((2, bands), 0.1), rtol=1e-12)
    assert ctfit.evaluate_at(spectral, theta_i=10.0, theta_o=30.0, wavelength_nm=[500.0, 600.0]).shape == (2,)
    m = ctfit.Measurement(theta_i=np.full(3, 30.0), phi_i=np.zeros(3), theta_o=np.full(3, 30.0), phi_o=np.full(3, 180.0), band=np.arange(3),
                          channels=("R", "G", "B"))
    np.testing.assert_allclose(ctfit.evaluate(rgb, m), np.full(3, 0.1), rtol=1e-12)
    (tmp_path / "grey.toml").write_text('name = "grey"\ns = 0\nd = 1\nchannels = ["R", "G", "B"]\nRd = 0.1\n')
    (tmp_path / "at.csv").write_text("theta_i,phi_i,theta_o,phi_o,channel\n30,0,30,180,R\n30,0,30,180,G\n30,0,30,180,B\n")
    r = CliRunner().invoke(app, ["eval", str(tmp_path / "grey.toml"), str(tmp_path / "at.csv"), "-o", str(tmp_path / "out.csv")])
    assert r.exit_code == 0, r.output
    assert [line.rsplit(",", 1)[1] for line in (tmp_path / "out.csv").read_text().splitlines()[-3:]] == ["0.1"] * 3


def test_a_material_that_does_not_fit_its_structure_or_a_bad_dtype_is_refused():
    """A structure of two lobes with one m evaluated that lobe twice (twice the BRDF), R_d of three
    values on two wavelengths gave three bands, an integer dtype NaN everywhere, a path an
    AttributeError: each is now an error naming what is wrong."""
    two = ctfit.Material(ctfit.Structure(lobes=2), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.5])), wavelength_nm=np.array([550.0]))
    with pytest.raises(ValueError, match="m has 1 values; its structure has 2 lobes"):
        ctfit.evaluate_at(two, theta_i=30.0, theta_o=30.0, phi_o=180.0)
    bands = ctfit.Material(ctfit.Structure(lobes=0, diffuse="spectrum"), ctfit.Params(rd=np.array([0.1, 0.2, 0.3])), wavelength_nm=np.array([450.0, 650.0]))
    with pytest.raises(ValueError, match="rd has 3 values for its 2 bands"):
        ctfit.evaluate(bands, ctfit.simulate(GOLD, 5, seed=0))
    with pytest.raises(ValueError, match="dtype must be a float type"):
        ctfit.evaluate_at(GOLD, theta_i=30.0, theta_o=30.0, dtype=np.int32)
    with pytest.raises(TypeError, match=r"material must be a ctfit.Material, got str \(read a file with ctfit.load_material\(path\)\)"):
        ctfit.evaluate_at("gold.toml", theta_i=30.0, theta_o=30.0)


def test_bad_arguments_are_named():
    """Angles that do not broadcast named NumPy's "arg 0" and "arg 2"; ``simulate(noise="0.1")``
    compared an int with a str; ``render_materials(material)`` said a Material is not iterable;
    ``fit(max_steps=0)`` reported an infinite cost and ``starts=-1`` was taken. Each names its argument."""
    with pytest.raises(ValueError, match=r"the angles must broadcast together \(NumPy's rules\), got shapes theta_i \(2,\), phi_i \(\), theta_o \(3,\)"):
        ctfit.evaluate_at(GOLD, theta_i=[30.0, 40.0], theta_o=[30.0, 40.0, 50.0])
    with pytest.raises(ValueError, match="l and v must broadcast together"):
        ctfit.evaluate_at(GOLD, l=np.array([[0.0, 0.0, 1.0]] * 2), v=np.array([[0.0, 0.0, 1.0]] * 3))
    with pytest.raises(ValueError, match="noise must be a finite number ≥ 0, got '0.1'"):
        ctfit.simulate(GOLD, 10, noise="0.1")
    with pytest.raises(TypeError, match="materials must be a sequence of ctfit.Material"):
        ctfit.render_materials(GOLD, 16)
    data = ctfit.simulate(GOLD, 50, seed=0)
    for kw, words in ((dict(max_steps=0), "max_steps must be a whole number ≥ 1, got 0"), (dict(max_steps=1.5), "max_steps must be a whole number"),
                      (dict(starts=-1), "starts must be a whole number ≥ 0")):
        with pytest.raises(ValueError, match=words):
            ctfit.fit(data, GOLD.structure, **kw)


def test_fit_batch_checks_its_solve_options_as_fit_does():
    """``fit_batch`` and ``fit_texels`` take ``fit``'s options through one decorator: ``max_steps``
    and ``starts`` are checked there, once for all three."""
    data = ctfit.simulate(GOLD, 50, seed=0)
    with pytest.raises(ValueError, match="max_steps must be a whole number ≥ 1, got 0"):
        ctfit.fit_batch([data, data], GOLD.structure, max_steps=0)
    with pytest.raises(ValueError, match="starts must be a whole number ≥ 0"):
        ctfit.fit_batch([data], GOLD.structure, starts=-1)


def test_simulate_keeps_a_materials_one_visible_band():
    """docs: the material's own wavelengths within 400–700 nm, the 10 nm grid only where it lists
    none there; one band at 550 nm made 31 bands of one value."""
    one = ctfit.Material(ctfit.Structure(lobes=1), ctfit.Params(s=np.asarray(0.6), m=np.array([0.15]), w=np.ones(1), f0=np.array([0.3])),
                         wavelength_nm=np.array([550.0]))
    assert ctfit.simulate(one, 10).wavelength_nm.tolist() == [550.0]
    far = dataclasses.replace(one, wavelength_nm=np.array([900.0]))
    assert len(ctfit.simulate(far, 10).wavelength_nm) == 31


def test_a_material_of_a_band_of_unknown_wavelength_is_evaluated_on_that_band_alone():
    """A fit of an ALTA file (one band, wavelength unknown) was copied to every band of other data
    by ``evaluate`` (``ctfit eval`` wrote a spectrum of one value); it is refused, as ``simulate`` refuses it."""
    unknown = ctfit.Material(ctfit.Structure(lobes=1), ctfit.Params(s=np.asarray(0.6), m=np.array([0.15]), w=np.ones(1), f0=np.array([0.3])),
                             wavelength_nm=np.array([550.0]), band_unknown=True, name="alta fit")
    spectral = ctfit.simulate(GOLD, 5)
    with pytest.raises(ValueError, match=r"material 'alta fit' has one band of unknown wavelength .* no values at the bands of"):
        ctfit.evaluate(unknown, spectral)
    same = spectral.replace(brdf=None, sigma=None)
    own = ctfit.Measurement(theta_i=same.theta_i[:5], phi_i=same.phi_i[:5], theta_o=same.theta_o[:5], phi_o=same.phi_o[:5], band=np.zeros(5, int),
                            wavelength_nm=np.array([550.0]), band_unknown=True)
    assert np.all(np.isfinite(np.asarray(ctfit.evaluate(unknown, own))))
