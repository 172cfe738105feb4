"""Write ``measurements/testbed/``: BRDF samples that the Cook–Torrance model cannot represent
exactly, rendered by Mitsuba 3 BSDFs that are not this model (``measurements/testbed/README.md``).

Each case is one Mitsuba plugin (:data:`CASES`), evaluated like a goniophotometer measures:
``N_PAIRS`` direction pairs from ``ctfit.goniometer_directions`` (θ_i, θ_o ≤ 85°, half of the
pairs around the mirror direction), each pair turned by its own uniform azimuth (the BSDFs are
isotropic, so only φ_o − φ_i matters to them, but a reader sees varied φ_i), angles rounded to
0.01°. Values: Mitsuba's ``BSDF.eval`` (f_r · cos θ_o, ``scalar_rgb``) divided by cos θ_o, the
BRDF in sr⁻¹ per R, G, B channel, rounded to 7 significant digits (about float32's precision,
which Mitsuba computes in). No noise is added: what a fit cannot reach is the model's mismatch
alone. Every file's ``#`` header records the plugin (as the JSON ``mitsuba.load_dict`` takes),
the Mitsuba version and variant, the direction seed and these steps, so that
``tests/test_testbed.py`` can evaluate the file's own directions again and compare.

Deterministic: the same Mitsuba version writes the same files.

Run: ``python scripts/make_testbed.py [--out DIR] [--pairs N]``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import ctfit

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "measurements" / "testbed"
N_PAIRS = 6000
MAX_THETA = 85.0
VARIANT = "scalar_rgb"
CHANNELS = ("R", "G", "B")
DIGITS = 7

CASES = {
    "roughplastic": dict(
        seed=1, spread=0.375,
        bsdf={"type": "roughplastic", "distribution": "ggx", "alpha": 0.15, "int_ior": 1.49, "ext_ior": 1.0, "nonlinear": False,
              "diffuse_reflectance": {"type": "rgb", "value": [0.7, 0.3, 0.1]}},
        what="rough plastic: GGX specular (α = 0.15) of a dielectric (n = 1.49) over an orange diffuse base seen through its Fresnel transmission"),
    "plastic": dict(
        seed=2, spread=0.3,
        bsdf={"type": "plastic", "int_ior": 1.5, "ext_ior": 1.0, "nonlinear": False, "diffuse_reflectance": {"type": "rgb", "value": [0.1, 0.25, 0.6]}},
        what="smooth plastic: away from the exact mirror direction only its blue, Fresnel-weighted diffuse part is seen"),
    "principled": dict(
        seed=3, spread=0.3,
        bsdf={"type": "principled", "base_color": {"type": "rgb", "value": [0.2, 0.5, 0.25]}, "roughness": 0.35, "metallic": 0.0,
              "specular": 0.5, "clearcoat": 0.3, "clearcoat_gloss": 0.9},
        what="Disney principled BSDF: green dielectric base, roughness 0.35, a glossy clear coat (0.3)"),
    "blend-conductors": dict(
        seed=4, spread=0.2,
        bsdf={"type": "blendbsdf", "weight": 0.4,
              "bsdf_0": {"type": "roughconductor", "distribution": "ggx", "alpha": 0.05, "material": "Au"},
              "bsdf_1": {"type": "roughconductor", "distribution": "ggx", "alpha": 0.3, "material": "Cu"}},
        what="blend of two rough conductors: 60 % gold with GGX α = 0.05 and 40 % copper with α = 0.3 (two lobes of different colours)"),
}


def directions(n_pairs: int, spread: float, seed: int):
    """(θ_i, φ_i, θ_o, φ_o) in degrees, rounded to 0.01°: goniometer pairs, each turned by its own azimuth."""
    ti, pi, to, po = (np.asarray(a, dtype=float) for a in ctfit.goniometer_directions(n_pairs, spread=spread, max_theta=MAX_THETA, seed=seed))
    turn = np.random.default_rng([seed, 25]).uniform(0.0, 360.0, n_pairs)
    return np.round(ti, 2), np.round((pi + turn) % 360, 2) % 360, np.round(to, 2), np.round((po + turn) % 360, 2) % 360


def unit_vectors(theta_deg, phi_deg) -> np.ndarray:
    """(N, 3) float64 unit vectors (sin θ cos φ, sin θ sin φ, cos θ) in NumPy (ctfit's frame, ``docs/conventions.md``),
    the same in every process whatever JAX's precision."""
    t, p = np.deg2rad(np.asarray(theta_deg, dtype=float)), np.deg2rad(np.asarray(phi_deg, dtype=float))
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.sin(np.deg2rad(90 - np.asarray(theta_deg, dtype=float)))], axis=-1)


def evaluate(bsdf: dict, theta_i, phi_i, theta_o, phi_o) -> np.ndarray:
    """Mitsuba's BRDF (sr⁻¹, ``eval`` / cos θ_o) of the plugin ``bsdf`` at the pairs, shape (N, 3), rounded to ``DIGITS``."""
    import mitsuba as mi

    mi.set_variant(VARIANT)
    plugin, ctx = mi.load_dict(bsdf), mi.BSDFContext()
    light, view = unit_vectors(theta_i, phi_i), unit_vectors(theta_o, phi_o)
    out = np.zeros((len(light), 3))
    si = mi.SurfaceInteraction3f()
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    for i, (l, v) in enumerate(zip(light, view)):
        si.wi = mi.Vector3f(*l)
        out[i] = np.array(plugin.eval(ctx, si, mi.Vector3f(*v)), dtype=float) / v[2]
    return np.array([[float(f"{x:.{DIGITS}g}") for x in row] for row in out]).reshape(out.shape)


def measurement(name: str, n_pairs: int = N_PAIRS) -> ctfit.Measurement:
    """The test-bed case ``name`` as a measurement (R, G, B rows per pair), its ``#`` header in ``meta``."""
    import mitsuba as mi

    case = CASES[name]
    ti, pi, to, po = directions(n_pairs, case["spread"], case["seed"])
    values = evaluate(case["bsdf"], ti, pi, to, po)
    meta = {
        "sample": f"testbed/{name}: {case['what']}",
        "generator": "scripts/make_testbed.py (ctfit test-bed, issue 25); not a Cook–Torrance material",
        "mitsuba": f"{mi.__version__}, variant {VARIANT}",
        "bsdf": json.dumps(case["bsdf"], separators=(", ", ": ")),
        "directions": f"ctfit.goniometer_directions({n_pairs}, spread={case['spread']}, max_theta={MAX_THETA}, seed={case['seed']}); each pair "
                      f"turned by an azimuth uniform in [0, 360) from numpy.random.default_rng([{case['seed']}, 25]); angles rounded to 0.01 degrees",
        "values": f"BRDF in 1/sr per channel = BSDF.eval(BSDFContext(), wi = light, wo = viewer) / cos(theta_o), the unit vectors "
                  f"(sin t cos p, sin t sin p, cos t) computed in float64 from the rounded angles, rounded to {DIGITS} significant digits",
        "noise": "none",
    }
    rep = lambda a: np.repeat(a, 3)
    return ctfit.Measurement(theta_i=rep(ti), phi_i=rep(pi), theta_o=rep(to), phi_o=rep(po), band=np.tile(np.arange(3), n_pairs), channels=CHANNELS,
                             brdf=values.reshape(-1), meta=meta, source=f"<testbed {name}>")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--pairs", type=int, default=N_PAIRS)
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    for name in CASES:
        path = args.out / f"{name}.csv"
        ctfit.write_csv(measurement(name, args.pairs), path)
        print(f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB)", flush=True)


if __name__ == "__main__":
    main()
