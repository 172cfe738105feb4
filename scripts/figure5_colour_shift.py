"""Reproduce Cook & Torrance (1982) Figure 5: the colour of copper's reflection against incidence angle.

Three rows of swatches, 0° to 90° in 5° steps, under CIE D65 (the paper's "D6500"), CIE 1931 2°
observer, shown in sRGB:

1. exact: the reflectance spectrum F(θ, λ) with the paper's effective index per wavelength,
   n(λ) = (1 + √F0(λ))/(1 − √F0(λ)), k = 0;
2. the paper's approximation: the normal-incidence colour interpolated towards the light's
   colour with max(0, F_avg(θ) − F0_avg)/(1 − F0_avg), F0_avg the luminance (Y) of F0(λ);
3. the conductor Fresnel with the tabulated n(λ), k(λ).

Below, the CIEDE2000 differences between the rows against angle (0.5° steps). The colours
are reflectance colours (a perfect mirror is white, sRGB (1, 1, 1)); the scene is scaled as
the paper does — the brightest swatch at the maximum luminance its chromaticity allows —
which here is the white at 90°, so the scale is 1.

Copper: the table that ships with ctfit, ``ctfit/data/optical_constants/Cu.csv`` (Johnson & Christy
1972 via refractiveindex.info), read with :func:`ctfit.read_optical_constants`.

Usage: python scripts/figure5_colour_shift.py [-o docs/figures/figure5_copper_colour_shift.png]
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

from ctfit import (  # noqa: E402
    XYZ_to_RGB,
    average_normal_reflectance,
    colour_shift_approximation,
    colour_shift_spectral,
    eotf_inverse_sRGB,
    f0_from_nk,
    read_optical_constants,
    rgb_conversion,
    scale_to_display,
    spectral_weights,
)

OUT = ROOT / "docs" / "figures" / "figure5_copper_colour_shift.png"


def load_copper():
    """(wavelength_nm, n, k, source description) of the Cu table that ships with ctfit."""
    table = read_optical_constants("Cu")
    return table["wavelength_nm"], table["n"], table["k"], "ctfit/data/optical_constants/Cu.csv (Johnson & Christy 1972)"


def colours(cos, weights, f0, n, k):
    """XYZ (3 rows × angles × 3): exact effective index, approximation, conductor."""
    exact_f0 = np.asarray(colour_shift_spectral(cos, weights, f0=f0))
    exact_nk = np.asarray(colour_shift_spectral(cos, weights, n=n, k=k))
    f0_mean = average_normal_reflectance(f0, weights)
    approx = np.asarray(colour_shift_approximation(exact_f0[0], weights.white_XYZ, f0_mean, cos))
    return np.stack([exact_f0, approx, exact_nk]), float(f0_mean)


def cos_of(deg):
    c = np.cos(np.radians(deg))
    return np.where(deg >= 90, 0.0, c)


def compute():
    """The figure's data: swatch angles, their sRGB (3 rows), the display scale, F0_avg, the fine
    angles and the ΔE00 between the rows there, and the data's source."""
    import colour

    wl_data, n_data, k_data, source = load_copper()
    wl = np.arange(360.0, 831.0)  # the observer's 1 nm grid; n, k linear, held at the ends
    n = np.interp(wl, wl_data, n_data)
    k = np.interp(wl, wl_data, k_data)
    f0 = np.asarray(f0_from_nk(n, k))
    weights = spectral_weights(wl, "D65")
    conv = rgb_conversion("sRGB", weights.white_XYZ, "CAT02")

    swatch_deg = np.arange(0.0, 90.1, 5)
    xyz, f0_mean = colours(cos_of(swatch_deg), weights, f0, n, k)
    rgb_lin = np.asarray(XYZ_to_RGB(xyz, conv))
    display, scale = scale_to_display(rgb_lin, conv.luminance)
    srgb = np.clip(np.asarray(eotf_inverse_sRGB(display)), 0, 1)

    fine_deg = np.arange(0.0, 90.01, 0.5)
    xyz_f, _ = colours(cos_of(fine_deg), weights, f0, n, k)
    lab = colour.XYZ_to_Lab(xyz_f, weights.white_xy)
    de = {
        "approximation vs exact (effective index)": colour.delta_E(lab[1], lab[0], method="CIE 2000"),
        "conductor (n, k) vs exact (effective index)": colour.delta_E(lab[2], lab[0], method="CIE 2000"),
        "approximation vs conductor (n, k)": colour.delta_E(lab[1], lab[2], method="CIE 2000"),
    }
    return swatch_deg, srgb, float(scale), f0_mean, fine_deg, de, source


def plot(path, swatch_deg, srgb, f0_mean, fine_deg, de, source) -> None:
    """The swatches (three rows against angle) above the ΔE00 curves, written to ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    fig = plt.figure(figsize=(11, 6.4))
    grid = fig.add_gridspec(2, 1, height_ratios=[1.25, 1], hspace=0.28, left=0.2, right=0.97, top=0.9, bottom=0.09)
    ax = fig.add_subplot(grid[0])
    step = swatch_deg[1] - swatch_deg[0]
    extent = (swatch_deg[0] - step / 2, swatch_deg[-1] + step / 2, 3, 0)
    ax.set_facecolor("0.42")  # a neutral surround, so that the white swatches show
    for r, row in enumerate(srgb):
        for deg, px in zip(swatch_deg, row):
            ax.add_patch(Rectangle((deg - 0.42 * step, r + 0.1), 0.84 * step, 0.8, color=px, lw=0))
    ax.set_ylim(3, 0)
    labels = [
        "exact: F(θ, λ) with\neffective n(λ) from F0(λ)",
        f"paper's approximation\n(F0_avg = Y of F0 = {f0_mean:.3f})",
        "conductor Fresnel\nwith tabulated n(λ), k(λ)",
    ]
    ax.set_yticks([0.5, 1.5, 2.5], labels)
    ax.set_xticks(swatch_deg[::2])
    ax.set_xlim(extent[0], extent[1])
    ax.set_xlabel("angle of incidence θ (degrees)")
    ax.tick_params(length=0)
    for spine in ax.spines.values():
        spine.set_visible(False)
    ax.set_title(
        "Copper: colour of the reflection against angle of incidence (after Cook & Torrance 1982, Fig. 5)\n"
        f"CIE D65, CIE 1931 2° observer, sRGB; {source}",
        fontsize=10,
    )

    ax2 = fig.add_subplot(grid[1])
    for (label, values), style in zip(de.items(), ("-", "--", ":")):
        ax2.plot(fine_deg, values, style, lw=2, label=label)
    ax2.set_xlim(extent[0], extent[1])
    ax2.set_xticks(swatch_deg[::2])
    ax2.set_xlabel("angle of incidence θ (degrees)")
    ax2.set_ylabel("ΔE₀₀ (CIEDE2000)")
    ax2.axhline(1, color="0.6", lw=0.8)
    ax2.text(1, 1.15, "ΔE₀₀ = 1", color="0.45", fontsize=8)
    ax2.grid(alpha=0.3)
    ax2.legend(loc="upper left", fontsize=9, frameon=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=150)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=pathlib.Path, default=OUT)
    args = parser.parse_args(argv)

    swatch_deg, srgb, scale, f0_mean, fine_deg, de, source = compute()
    plot(args.output, swatch_deg, srgb, f0_mean, fine_deg, de, source)
    print(f"wrote {args.output} (display scale {scale:.6f}, F0_avg {f0_mean:.4f})")
    for (label, values) in de.items():
        i = int(np.argmax(values))
        print(f"  max ΔE00 {label}: {values[i]:.2f} at {fine_deg[i]:g}°")
    print("  sRGB hex by angle:")
    for name, row in zip(("exact-F0", "approx", "conductor"), srgb):
        hexes = ["#" + "".join(f"{round(v * 255):02x}" for v in px) for px in row]
        print(f"    {name:9s} " + " ".join(hexes[::3]))


if __name__ == "__main__":
    main()
