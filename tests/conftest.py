"""Test configuration: float64 enabled for the suite (ctfit itself never switches it on)."""

import os
import pathlib

import jax

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_platforms", "cpu")

ROOT = pathlib.Path(__file__).resolve().parent.parent
SHARED = ROOT.parent / "shared"
MEASURED = SHARED / "data" / "measured"
os.environ.setdefault("MPLBACKEND", "Agg")
