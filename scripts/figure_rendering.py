"""Figures for ``docs/rendering.md``: the ambient term's effect, and ``--compare`` on a one-lobe fit.

1. ``docs/figures/rendering_ambient.png``: copper, gold, obsidian, rust and lunar dust with the
   ambient fraction 0.01 (the default: ambient irradiance 1 % of the lights'), 0.1, and 104.7 —
   the literal reading I_ia = 0.01 I_i with dω = 10⁻⁴ + 2·10⁻⁴ sr.
2. ``docs/figures/rendering_compare.png``: data simulated from ``configs/copper-vase.toml``
   (two lobes, 2000 direction pairs, 400–700 nm every 20 nm, 2 % noise, seed 1), fitted with
   one lobe; the fit beside the nearest-measured rendering of the data.

Usage: python scripts/figure_rendering.py
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
FIGURES = ROOT / "docs" / "figures"


def main():
    import jax

    jax.config.update("jax_enable_x64", True)
    import ctfit
    from ctfit import render_compare, render_materials, save_png

    names = ("copper", "gold", "obsidian", "rust", "lunar-dust")
    mats = [ctfit.load_material(ROOT / "configs" / f"{n}.toml") for n in names]
    literal = 0.01 * np.pi / 3e-4
    rows = []
    for a, tag in ((0.01, "ambient 0.01"), (0.1, "ambient 0.1"), (literal, "I_ia = 0.01 I_i literally")):
        labels = [f"{m.name}, {tag}" if i == 0 else m.name for i, m in enumerate(mats)]
        rows.append(render_materials(mats, 144, labels=labels, ambient=a, wavelength_step=10.0))
    save_png(np.concatenate(rows), FIGURES / "rendering_ambient.png")
    print(f"wrote {FIGURES / 'rendering_ambient.png'}", file=sys.stderr)

    truth = ctfit.load_material(ROOT / "configs" / "copper-vase.toml")
    data = ctfit.simulate(truth, 2000, wavelength_nm=np.arange(400.0, 701.0, 20.0), noise=0.02, seed=1)
    result = ctfit.fit(data, ctfit.Structure(lobes=1, fresnel="f0"))
    fitted = result.material
    m = float(np.asarray(fitted.params.m)[0])
    print(f"one-lobe fit: m = {m:.3f}, rel. RMS {result.stats['rel_rmse']:.3f}", file=sys.stderr)
    img = render_compare(fitted, data, 256, labels=[f"one-lobe fit (m = {m:.2f})", "data, nearest measured pair"])
    save_png(img, FIGURES / "rendering_compare.png")
    print(f"wrote {FIGURES / 'rendering_compare.png'}", file=sys.stderr)


if __name__ == "__main__":
    main()
