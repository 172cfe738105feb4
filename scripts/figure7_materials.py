"""After Cook & Torrance (1982) Figure 7: the bundled materials rendered side by side.

Row 1: the six metals (copper, gold, silver, aluminium, iron, stainless steel; conductor
Fresnel with tabulated n, k) and the paper's copper vase (two lobes, effective index from F0).
Row 2: the six nonmetals of the paper's Table I (carbon, rubber, obsidian, lunar dust, olive
drab, rust; s, d and m from the paper, Fresnel index and R_d illustrative) and the paper's
copper-coloured plastic vase. Spheres and vases as in ``docs/rendering.md``: orthographic
camera, two D65 lights with dω = 0.0001 and 0.0002 sr, ambient 1 %, spectral at 5 nm, each
tile exposed by the paper's rule with a white diffuse reference (a dark material stays dark).

Usage: python scripts/figure7_materials.py [-o docs/figures/figure7_materials.png] [--size 192]
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

OUT = ROOT / "docs" / "figures" / "figure7_materials.png"
METALS = ("copper", "gold", "silver", "aluminium", "iron", "stainless-steel", "copper-vase")
NONMETALS = ("carbon", "rubber", "obsidian", "lunar-dust", "olive-drab", "rust", "copper-plastic-vase")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", type=pathlib.Path, default=OUT)
    ap.add_argument("--size", type=int, default=192, help="tile side in pixels")
    args = ap.parse_args()

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import ctfit
    from ctfit import LIGHT_DIRECTIONS, SOLID_ANGLES, render_materials

    names = METALS + NONMETALS
    materials = [ctfit.load_material(ROOT / "configs" / f"{n}.toml") for n in names]
    shapes = ["vase" if n.endswith("vase") else "sphere" for n in names]
    t0 = time.perf_counter()
    grid = render_materials(materials, args.size, shapes, columns=len(METALS))
    print(f"rendered {len(materials)} tiles in {time.perf_counter() - t0:.1f} s", file=sys.stderr)

    h, w = grid.shape[:2]
    title_px = 64
    dpi = 100
    fig = plt.figure(figsize=(w / dpi, (h + title_px) / dpi), dpi=dpi, facecolor="#595959")
    ax = fig.add_axes((0, 0, 1, h / (h + title_px)))
    ax.imshow(grid, interpolation="none")
    ax.set_axis_off()
    dirs = ", ".join("(" + ", ".join(f"{c:g}" for c in d) + ")" for d in LIGHT_DIRECTIONS)
    fig.text(0.5, 1 - 22 / (h + title_px), "Cook–Torrance materials (after Cook & Torrance 1982, Fig. 7)", ha="center", va="center", color="white", fontsize=13)
    fig.text(
        0.5,
        1 - 46 / (h + title_px),
        f"two D65 lights towards {dirs}, dω = {SOLID_ANGLES[0]:g} and {SOLID_ANGLES[1]:g} sr; ambient 1 %; "
        "spectral at 5 nm → CIE 1931 2° → sRGB; each tile scaled by the paper's rule with a white reference",
        ha="center", va="center", color="#dddddd", fontsize=8.5,
    )  # fmt: skip
    args.output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.output, dpi=dpi, facecolor=fig.get_facecolor())
    print(f"wrote {args.output}", file=sys.stderr)


if __name__ == "__main__":
    main()
