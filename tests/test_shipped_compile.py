"""The suite compiles its programs the cheapest way (``CHEAP_XLA_FLAGS``, tests/conftest.py);
ctfit compiles them for users with XLA's optimisation and its own efforts
(``ctfit._runtime.COMPILE_EFFORT``). Here the main paths run both ways, the shipped way in a
fresh process with its own empty cache, and must give the same numbers: a compile that changed
what a program computes would fail here, not only in users' hands."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import ctfit

from conftest import CHEAP_XLA_FLAGS, ROOT

WAVELENGTHS = np.array([450.0, 550.0, 650.0])


def _figures() -> dict:
    """The numbers compared: a model's values, a scattered two-lobe fit on chunks (raced on a
    sample of its rows), a one-lobe metal on a grid, and per-texel fits."""
    rng = np.random.default_rng(7)
    plastic = ctfit.Material(ctfit.Structure(lobes=2), ctfit.Params(m=np.array([0.15, 0.4]), w=np.array([0.6, 0.4]), s=np.array(0.8),
                             f0=np.array([0.5, 0.6, 0.7])), wavelength_nm=WAVELENGTHS)
    scattered = ctfit.simulate(plastic, n_pairs=12_000, seed=1)  # × 3 bands; one band of each pair kept: 12,000 samples
    keep = np.arange(len(scattered)) % 3 == np.repeat(np.arange(12_000) % 3, 3)
    scattered = scattered.replace(**{k: getattr(scattered, k)[keep] for k in ("theta_i", "phi_i", "theta_o", "phi_o", "band", "brdf")})
    scattered = scattered.replace(brdf=scattered.brdf * (1 + 0.02 * rng.standard_normal(len(scattered))))
    metal = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([0.2]), w=np.ones(1),
                           f0=np.array([0.9, 0.7, 0.5])), wavelength_nm=WAVELENGTHS)
    grid = ctfit.simulate(metal, n_pairs=3000, seed=2)
    grid = grid.replace(brdf=grid.brdf * (1 + 0.02 * rng.standard_normal(len(grid))))
    texels = np.stack([np.asarray(ctfit.evaluate(metal, grid)) * (1 + 0.02 * rng.standard_normal(len(grid))) for _ in range(4)])
    two = ctfit.fit(scattered, plastic.structure, loss="relative")
    one = ctfit.fit(grid, metal.structure)
    maps = ctfit.fit_batch([grid], metal.structure, values=texels)

    def params(p) -> dict:
        return {k: np.asarray(getattr(p, k)).tolist() for k in ("s", "m", "w", "f0", "n", "k", "rd") if getattr(p, k) is not None}

    return {
        "values": np.asarray(ctfit.evaluate(plastic, scattered)).tolist(),
        "two": {"params": params(two.material.params), "cost": float(two.stats["cost"]), "converged": bool(two.converged)},
        "one": {"params": params(one.material.params), "cost": float(one.stats["cost"]), "converged": bool(one.converged)},
        "texels": {"params": params(maps.params), "cost": np.asarray(maps.stats["cost"]).tolist()},
    }


SHIPPED = """
import json, sys
sys.path.insert(0, {tests!r})
import conftest  # float64, as in the suite; CTFIT_TEST_COMPILE=shipped: no flags of its own
import test_shipped_compile
print(json.dumps(test_shipped_compile._figures()))
"""


@pytest.mark.slow
def test_programs_compiled_as_shipped_compute_what_the_suite_s_programs_compute(tmp_path):
    flags = os.environ.get("XLA_FLAGS", "").replace(CHEAP_XLA_FLAGS, "").strip()
    assert "xla_backend_optimization_level" not in flags and CHEAP_XLA_FLAGS in os.environ["XLA_FLAGS"]  # the two compiles differ
    env = {**os.environ, "CTFIT_TEST_COMPILE": "shipped", "XLA_FLAGS": flags, "JAX_COMPILATION_CACHE_DIR": str(tmp_path / "cache")}
    done = subprocess.run([sys.executable, "-c", SHIPPED.format(tests=str(ROOT / "tests"))], capture_output=True, text=True,
                          env=env, timeout=600, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    shipped = json.loads(done.stdout.splitlines()[-1])
    here = _figures()
    for fit in ("two", "one", "texels"):
        for k, v in here[fit]["params"].items():
            np.testing.assert_allclose(shipped[fit]["params"][k], v, rtol=1e-8, atol=1e-12, err_msg=f"{fit}: {k}")
        np.testing.assert_allclose(shipped[fit]["cost"], here[fit]["cost"], rtol=1e-10, err_msg=fit)
    assert shipped["two"]["converged"] and here["two"]["converged"] and shipped["one"]["converged"] and here["one"]["converged"]
