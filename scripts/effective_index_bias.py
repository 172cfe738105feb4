"""Bias of the paper's effective index (k = 0) against the largest measured angle.

Data: Mitsuba 3 `roughconductor` (Beckmann m = 0.2, Smith G, exact conductor Fresnel with the
tabulated n, k of Cu and Au that ship with ctfit), no noise. Fits: one Beckmann lobe with Smith G
and the effective index n = (1+√F0)/(1−√F0), for several losses; and the conductor fit at the
largest angle for comparison. Prints max |F0_fit − F0_table| over 8 wavelengths and m error.

    python scripts/effective_index_bias.py [--pairs 500]
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))

from mitsuba_render import render  # noqa: E402

import ctfit  # noqa: E402

WL = np.linspace(420.0, 700.0, 8)
M = 0.2


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", type=int, default=500)
    args = ap.parse_args()
    print(f"{'metal':>5} {'max θ':>6} {'loss':>9} {'fresnel':>12} {'max |ΔF0|':>10} {'m error':>8} {'rel_rmse':>9}")
    for metal in ("Cu", "Au"):
        t = ctfit.read_optical_constants(metal)  # the table that ships with ctfit
        n = np.interp(WL, t["wavelength_nm"], t["n"])
        k = np.interp(WL, t["wavelength_nm"], t["k"])
        f0 = np.asarray(ctfit.f0_from_nk(n, k))
        for max_theta in (30.0, 50.0, 70.0, 85.0):
            data = render(args.pairs, WL, n, k, M, max_theta=max_theta, seed=1)
            runs = [("f0", loss) for loss in ("relative", "log", "cosine")]
            if max_theta == 85.0:
                runs.append(("conductor", "relative"))
            for fres, loss in runs:
                res = ctfit.fit(data, ctfit.Structure(lobes=1, geometry="smith", fresnel=fres), loss=loss)
                p = res.material.params
                f0_fit = np.asarray(ctfit.normal_reflectance(res.material.structure, p))
                name = "effective-n" if fres == "f0" else "conductor"
                print(
                    f"{metal:>5} {max_theta:>6.0f} {loss:>9} {name:>12} {np.max(np.abs(f0_fit - f0)):>10.4f} "
                    f"{abs(p.m[0] / M - 1):>8.2%} {res.stats['rel_rmse']:>9.4f}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
