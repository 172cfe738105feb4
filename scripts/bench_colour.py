"""Colour of a rendered sphere: error against run time for five ways of computing it.

Every method shades the same sphere (orthographic camera, the renderer's lights, ambient
1 %: ``ctfit.render_scene``, ``ctfit.shade_linear``) and returns linear sRGB per pixel. The reference is the full spectral
computation at 1 nm over 360–830 nm (every CIE 1931 2° sample). Compared:

- ``spectral 5/10/20 nm``: eq. 1 per band on 380–780 nm every 5, 10 or 20 nm, integrated to
  XYZ with the equal-energy weights at that step and the D65 spectrum in the lights (what
  ``ctfit render`` does, at its default 5 nm);
- ``RGB (paper's approximation)``: the paper's shortcut (§4, ``ctfit.colour_shift_approximation``): the
  specular colour is the colour of F0 (from the 1 nm spectrum) moved towards the light's colour
  with max(0, F_avg(θ) − F0_avg)/(1 − F0_avg), F0_avg = Y of F0; the diffuse and ambient parts
  use the colour of R_d. Per pixel: three channels instead of λ bands;
- ``LUT 256 angles``: F(θ, λ) integrated to linear RGB once, at 1 nm, on 256 angles uniform in
  θ ∈ [0°, 90°]; per pixel θ = arccos(V·H) and linear interpolation in the table. Because
  D G/(N·L N·V) does not depend on λ, this is exact up to the interpolation in θ.

Two scenes: the renderer's two lights (V·H ≈ 0.92 and 0.90: near-normal Fresnel), and the
same plus a rim light from behind the sphere at 160° from the viewer (V·H = cos 80°, where
a metal's highlight changes colour; Figure 5). ΔE is CIEDE2000 between each method and the
reference, over the pixels on the sphere, after the reference's display scaling (its
brightest channel at 1; the same scale for every method), Lab relative to the D65 white.
Times: the jitted per-pixel shading + conversion to linear RGB on the first scene (2 lights),
warm, ``block_until_ready``, best of ``--repeat``, per million pixels on the sphere.

Usage: ``python scripts/bench_colour.py [--size 256] [--repeat 7] [--x64] [--write-docs]``
"""

from __future__ import annotations

import argparse
import datetime
import os
import pathlib
import platform
import sys
import time

import numpy as np
from _docs import write_section

ROOT = pathlib.Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
SECTION = "## Colour: error against run time"
MATERIALS = ("copper", "gold", "rust")


def _setup(x64: bool):
    import jax

    jax.config.update("jax_platforms", "cpu")
    if x64:
        jax.config.update("jax_enable_x64", True)
    return jax


def spectral_methods(jax, material, directions, solid_angles, ambient):
    """{method: (jitted fn(params, normals) -> linear sRGB, params)}: the renderer's shading
    (``ctfit.render_scene``, ``ctfit.shade_linear``) at 1 nm (the reference), 5, 10 and 20 nm."""
    import equinox as eqx
    import jax.numpy as jnp

    from ctfit import render_scene, shade_linear

    def spectral(wl):
        scene = render_scene(material, directions=directions, solid_angles=solid_angles, ambient=ambient, wavelength_nm=wl)

        @eqx.filter_jit
        def fn(p, n):
            return shade_linear(material.structure, scene._replace(params=p), n)

        return fn, jax.tree_util.tree_map(jnp.asarray, scene.params)

    out = {"spectral 1 nm (reference)": spectral(np.arange(360.0, 830.5, 1.0))}
    for step in (5.0, 10.0, 20.0):
        out[f"spectral {step:g} nm"] = spectral(np.arange(380.0, 780.5, step))
    return out


def rgb_shader(structure, directions, solid_angles, ambient, ra_rgb, rd_rgb, fresnel_rgb):
    """Jitted fn(params, normals) -> linear sRGB of eq. 1 in three channels: the ambient and
    diffuse parts with the colours of R_a and R_d, the specular part with ``fresnel_rgb(V·H)``."""
    import equinox as eqx
    import jax.numpy as jnp

    from ctfit import VIEW_DIRECTION, geometry, specular_geometric

    st = structure
    view = jnp.asarray(VIEW_DIRECTION)
    e = [float(w) for w in solid_angles]
    dirs = [np.asarray(d, dtype=float) / np.linalg.norm(d) for d in directions]
    amb = ambient * sum(e) / np.pi

    @eqx.filter_jit
    def fn(p, n):
        total = amb * jnp.asarray(ra_rgb)
        for d, dw in zip(dirs, e):
            geom = geometry(jnp.asarray(d), view, n)
            cos_l = jnp.where(geom.valid, geom.cos_l, 0)[..., None]
            if st.has_specular:
                rs = specular_geometric(st, p, geom)[..., None] * fresnel_rgb(geom.cos_vh)
            if not st.has_diffuse:
                r = rs
            elif not st.has_specular:
                r = jnp.broadcast_to(jnp.asarray(rd_rgb), cos_l.shape[:-1] + (3,))
            else:
                r = p.s * rs + (1 - p.s) * jnp.asarray(rd_rgb)
            total = total + dw * cos_l * jnp.where(geom.valid[..., None], r, 0)
        return total

    return fn


def rgb_methods(jax, material, directions, solid_angles, ambient):
    """{method: (fn, params)} of the RGB methods (reflectance colours under D65 at 1 nm, white
    lights of Y = 1): the paper's approximation and, with a specular part, the 256-angle table;
    and the table's set-up time in ms (None without a specular part)."""
    import jax.numpy as jnp

    from ctfit import (
        XYZ_to_RGB,
        ambient_reflectance,
        average_normal_reflectance,
        colour_shift_approximation,
        diffuse_reflectance,
        fresnel,
        normal_reflectance,
        rgb_conversion,
        spectral_weights,
        spectrum_to_XYZ,
    )

    st = material.structure
    wl1 = np.arange(360.0, 831.0, 1.0)
    w1 = spectral_weights(wl1, "D65")
    conv = rgb_conversion("sRGB", w1.white_XYZ, "CAT02")
    p1 = jax.tree_util.tree_map(jnp.asarray, material.params_at(wavelength_nm=wl1))

    def colour_of(spectrum):
        r = np.broadcast_to(np.asarray(spectrum, dtype=float), wl1.shape)
        return np.asarray(XYZ_to_RGB(spectrum_to_XYZ(jnp.asarray(r), w1), conv), dtype=float)

    rd_rgb = colour_of(diffuse_reflectance(st, p1)) if st.has_diffuse else None
    scene = (st, directions, solid_angles, ambient, colour_of(ambient_reflectance(st, p1)), rd_rgb)
    if not st.has_specular:
        return {"RGB (paper's approximation)": (rgb_shader(*scene, None), p1)}, None
    f0 = np.asarray(normal_reflectance(st, p1), dtype=float)
    f0_rgb = colour_of(f0)
    f0_avg = float(average_normal_reflectance(jnp.asarray(f0), w1))

    def approx(c):
        return colour_shift_approximation(jnp.asarray(f0_rgb), jnp.ones(3), f0_avg, c)

    # The table: F(θ, λ) at 1 nm → linear sRGB, 256 angles uniform in θ.
    t0 = time.perf_counter()
    theta = np.linspace(0, np.pi / 2, 256)
    cos = np.cos(theta)
    cos[-1] = 0.0
    spectra = fresnel(st, p1, jnp.asarray(cos)[:, None])
    table = np.asarray(XYZ_to_RGB(spectrum_to_XYZ(spectra, w1), conv), dtype=float)
    lut_setup_ms = 1e3 * (time.perf_counter() - t0)
    step = (np.pi / 2) / 255

    def lut(c):
        x = jnp.arccos(jnp.clip(c, 0, 1)) / step
        i = jnp.clip(jnp.floor(x), 0, 254).astype(jnp.int32)
        f = (x - i)[..., None]
        tab = jnp.asarray(table).astype(c.dtype)
        return (1 - f) * tab[i] + f * tab[i + 1]

    methods = {"RGB (paper's approximation)": (rgb_shader(*scene, approx), p1), "LUT 256 angles": (rgb_shader(*scene, lut), p1)}
    return methods, lut_setup_ms


def delta_e(jax, rgb, ref, scale):
    import jax.numpy as jnp

    from ctfit import RGB_to_XYZ, XYZ_to_Lab, delta_E_CIE2000, rgb_conversion, spectral_weights

    w = spectral_weights(np.arange(360.0, 831.0, 1.0), "D65")
    conv = rgb_conversion("sRGB", w.white_XYZ, "CAT02")
    white = conv.white_XYZ
    lab = XYZ_to_Lab(RGB_to_XYZ(jnp.asarray(rgb * scale, dtype=float), conv), white)
    lab_ref = XYZ_to_Lab(RGB_to_XYZ(jnp.asarray(ref * scale, dtype=float), conv), white)
    return np.asarray(delta_E_CIE2000(lab_ref, lab), dtype=float)


def best_time(fn, args, repeat):
    out = fn(*args)
    out.block_until_ready()
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn(*args).block_until_ready()
        best = min(best, time.perf_counter() - t0)
    return best


def run(args):
    jax = _setup(args.x64)
    import ctfit
    from ctfit import AMBIENT_FRACTION, LIGHT_DIRECTIONS, SOLID_ANGLES, surface_normals

    surf = surface_normals("sphere", args.size)
    normals = surf.normal[surf.mask]
    dtype = np.float64 if args.x64 else np.float32
    n_jax = jax.numpy.asarray(normals.astype(dtype))
    rim = (np.sin(np.radians(160)), 0.0, np.cos(np.radians(160)))
    scenes = {
        "two lights": (LIGHT_DIRECTIONS, SOLID_ANGLES),
        "two lights + rim light": (LIGHT_DIRECTIONS + (rim,), SOLID_ANGLES + (2e-4,)),
    }
    rows = []  # (material, method, {scene: (mean, max)}, ms per Mpixel)
    setup = {}
    for name in MATERIALS:
        mat = ctfit.load_material(ROOT / "configs" / f"{name}.toml")
        results = {}
        times = {}
        for scene, (dirs, dws) in scenes.items():
            methods = spectral_methods(jax, mat, dirs, dws, AMBIENT_FRACTION)
            rgb_ways, lut_setup_ms = rgb_methods(jax, mat, dirs, dws, AMBIENT_FRACTION)
            methods.update(rgb_ways)
            if lut_setup_ms is not None:
                setup[name] = lut_setup_ms
            rgb = {m: np.asarray(fn(p, n_jax), dtype=float) for m, (fn, p) in methods.items()}
            ref = rgb["spectral 1 nm (reference)"]
            scale = 1 / ref.max()
            for m, v in rgb.items():
                de = delta_e(jax, v, ref, scale)
                results.setdefault(m, {})[scene] = (float(de.mean()), float(de.max()))
            if scene == "two lights":
                for m, (fn, p) in methods.items():
                    times[m] = best_time(fn, (p, n_jax), args.repeat) / len(normals) * 1e9  # ms per Mpixel
        for m in results:
            rows.append((name, m, results[m], times[m]))
        print(f"{name}: done", file=sys.stderr)
    return rows, setup, len(normals)


def table(rows, setup, n_pixels, args) -> str:
    import jax

    lines = [
        SECTION,
        "",
        f"`scripts/bench_colour.py` ({datetime.date.today().isoformat()}; {platform.machine()} CPU, "
        f"{os.cpu_count()} cores shared with other jobs; Python {platform.python_version()}, JAX {jax.__version__}, "
        f"{'float64' if args.x64 else 'float32'}). A {args.size} × {args.size} sphere ({n_pixels} pixels on it), "
        "the renderer's camera and lights (`docs/rendering.md`). ΔE00 against the spectral computation at 1 nm "
        "(360–830 nm), after the reference's display scaling; mean and max over the sphere. Time: the jitted "
        "shading + conversion to linear sRGB for two lights, per million pixels on the sphere (warm, best of "
        f"{args.repeat}).",
        "",
        "| material | method | ΔE00 mean / max, two lights | ΔE00 mean / max, + rim light at 160° | ms per Mpixel |",
        "|---|---|---|---|---|",
    ]
    for name, m, res, ms in rows:
        a, b = res["two lights"], res["two lights + rim light"]
        lines.append(f"| {name} | {m} | {a[0]:.3g} / {a[1]:.3g} | {b[0]:.3g} / {b[1]:.3g} | {ms:.0f} |")
    if setup:
        lines += ["", "LUT set-up (256 angles × 471 wavelengths, once per material): " + ", ".join(f"{k} {v:.0f} ms" for k, v in setup.items()) + "."]
    # Per method: the worst ΔE anywhere, and the mean time over the materials.
    summary = {}
    for _, m, res, ms in rows:
        worst, times = summary.get(m, (0.0, []))
        summary[m] = (max(worst, *(v[1] for v in res.values())), times + [ms])
    ranked = sorted(((float(np.mean(t)), worst, m) for m, (worst, t) in summary.items()), key=lambda x: x[0])
    lines += ["", "| method | worst ΔE00 (any material, either scene) | mean ms per Mpixel |", "|---|---|---|"]
    lines += [f"| {m} | {worst:.3g} | {ms:.0f} |" for ms, worst, m in ranked]
    picks = []
    for limit in (0.01, 0.1, 1.0, 10.0):
        best = next(((ms, m) for ms, worst, m in ranked if worst <= limit), None)
        if best is not None:
            picks.append(f"ΔE00 ≤ {limit:g}: {best[1]}")
    lines += ["", "Cheapest method within a chosen error: " + "; ".join(picks) + "."]
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines += [
        "",
        f"Times are from a shared machine (load average {load:.1f} at the end of the run), good to a factor "
        "of about 1.5; the ranking is stable between runs. The per-pixel cost has a part that does not "
        "depend on the number of bands (the geometry, D and G per light), so 20 nm is not 4 × cheaper than 5 nm.",
    ]
    return "\n".join(lines) + "\n"


def plot(rows, path) -> None:
    """Pareto plot: worst ΔE00 (either scene) against ms per Mpixel, one point per material × method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5), constrained_layout=True)
    markers = {name: mk for name, mk in zip(sorted({r[0] for r in rows}), "osD^v")}
    methods = sorted({r[1] for r in rows})
    colours = dict(zip(methods, plt.rcParams["axes.prop_cycle"].by_key()["color"]))
    for name, m, res, ms in rows:
        worst = max(mx for _, mx in res.values())
        ax.scatter(ms, max(worst, 1e-5), marker=markers[name], color=colours[m], s=40)
    for m in methods:
        ax.scatter([], [], color=colours[m], label=m)
    for name, mk in markers.items():
        ax.scatter([], [], marker=mk, color="grey", label=name)
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.text(30, 1.15, "ΔE00 = 1 (just noticeable)", fontsize=8)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("ms per million pixels (two lights, float32, 2-core CPU)")
    ax.set_ylabel("worst ΔE00 against spectral 1 nm (floored at 1e-5)")
    ax.set_title("Colour: error against run time")
    ax.legend(fontsize=7, ncol=2)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=256, help="sphere image side in pixels")
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--x64", action="store_true", help="float64 (default float32, the renderer's default)")
    ap.add_argument("--write-docs", action="store_true", help=f"write the table to docs/benchmarks.md, section {SECTION!r}")
    ap.add_argument("--plot", type=pathlib.Path, help="write the Pareto plot (PNG) here")
    ap.add_argument("--docs", type=pathlib.Path, help=f"write the section {SECTION!r} of DIR/benchmarks.md and its plot to DIR/figures/")
    ap.add_argument("--small", action="store_true", help="a quick version (64-pixel spheres, 2 repeats)")
    args = ap.parse_args()
    if args.small:
        args.size, args.repeat = 64, 2
    if args.docs:
        args.plot = args.plot or args.docs / "figures" / "colour_error_vs_time.png"
        args.plot.parent.mkdir(parents=True, exist_ok=True)
    rows, setup, n = run(args)
    text = table(rows, setup, n, args)
    if args.plot:
        plot(rows, args.plot)
        text += f"\n\n![error against run time]({os.path.relpath(args.plot, args.docs or ROOT / 'docs')})\n"
    print(text)
    if args.write_docs or args.docs:
        write_section((args.docs or ROOT / "docs") / "benchmarks.md", SECTION, text)


if __name__ == "__main__":
    main()
