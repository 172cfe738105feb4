"""JAX's import reads the metadata of the jax-named distributions only (ctfit/_runtime/jax_plugin_scan.py),
finds the plugins it finds without ctfit, and leaves ``importlib.metadata`` as it was."""

import importlib.metadata
import json
import subprocess
import sys

from ctfit._runtime.jax_plugin_scan import jax_named

PROBE = r"""
import importlib.metadata as md, json, sys
reads = []
real = md.PathDistribution.read_text
def counting(self, filename):
    if filename in ("METADATA", "PKG-INFO"):
        reads.append(self._path.name)
    return real(self, filename)
md.PathDistribution.read_text = counting
if sys.argv[1] == "ctfit":
    import ctfit
import jax.numpy
from jax._src.numpy import array_constructors
md.PathDistribution.read_text = real
print(json.dumps(dict(reads=len(reads), plugin=repr(array_constructors.rocm_plugin_extension), wrapped=hasattr(md.distributions, "__wrapped__"),
                      finders=[type(f).__name__ for f in sys.meta_path], zeros=float(jax.numpy.zeros(2).sum()))))
"""


def _probe(first: str) -> dict:
    done = subprocess.run([sys.executable, "-c", PROBE, first], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_jax_imported_after_ctfit_reads_a_few_metadata_files_and_finds_the_same_plugins():
    alone, after_ctfit = _probe("jax"), _probe("ctfit")
    installed = len(list(importlib.metadata.distributions()))
    assert alone["reads"] >= installed  # JAX alone reads every distribution's metadata
    assert after_ctfit["reads"] <= 10 < installed, after_ctfit
    assert after_ctfit["plugin"] == alone["plugin"] and after_ctfit["zeros"] == 0.0
    assert not after_ctfit["wrapped"] and "_BeforeTheScan" not in after_ctfit["finders"]  # put back, taken out


def test_the_distributions_kept_are_those_whose_metadata_names_them_jax():
    dists = list(importlib.metadata.distributions())
    kept = {d.metadata["Name"] for d in dists if jax_named(d)}
    named = {d.metadata["Name"] for d in dists if d.metadata["Name"].lower().replace("-", "_").startswith("jax")}
    assert kept == named and {"jax", "jaxlib"} <= {n.lower() for n in kept}
