"""The data files of ``bench_fit.py``, each written once into a scratch folder.

- **scattered**: every row its own direction pair (``ctfit.goniometer_directions``: light on a
  grid of incidence angles, viewer half uniform, half around the mirror direction) with one band
  drawn at random from 31 wavelengths 400–700 nm. Truth: two Beckmann lobes (m = 0.2, 0.4;
  w = 0.6, 0.4), V-cavity G, effective-index Fresnel, s = 0.9 with R_d = F0/π, F0 rising
  linearly from 0.5 to 0.95; 2 % relative Gaussian noise; no σ column (the fit's loss is then
  the relative one).
- **batch**: files of the scattered kind sharing one geometry (directions and bands), each with
  its own truth (m, w, s and the F0 level drawn around the scattered truth) and noise.
- **MERL**: a MERL ``.binary`` table of a one-lobe RGB metal (m = 0.15, F0 = 0.9, 0.7, 0.5, no
  diffuse part), 2 % noise, every cell above the horizon measured, or ``pairs`` of them.
- **texels**: one goniometer geometry (direction pairs × R, G, B) and per-texel values of a
  one-lobe RGB metal whose m and F0 vary from texel to texel.
- **Mitsuba**: Mitsuba 3's own ``roughconductor`` (copper, α = 0.15) rendered at goniometer
  directions by ``_mitsuba_fit.py render``.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import ctfit
from ctfit import Material, Measurement, Params, Structure, evaluate, goniometer_directions, write_csv

SCRIPTS = Path(__file__).resolve().parent
WL31 = np.linspace(400.0, 700.0, 31)
F0_TRUE = np.linspace(0.5, 0.95, 31)
M_TRUE, W_TRUE, S_TRUE = np.array([0.2, 0.4]), np.array([0.6, 0.4]), 0.9
NOISE = 0.02
SCATTERED = Structure(lobes=2, diffuse="F0/pi")
RGB = ("R", "G", "B")
METAL = Structure(lobes=1)
MERL_TRUTH = dict(m=0.15, f0=(0.9, 0.7, 0.5))


def scattered_material(m=M_TRUE, w=W_TRUE, s=S_TRUE, f0=F0_TRUE) -> Material:
    return Material(SCATTERED, Params(s=np.asarray(s), m=np.asarray(m), w=np.asarray(w), f0=np.asarray(f0)), wavelength_nm=WL31)


def scattered_geometry(n: int, seed: int) -> Measurement:
    """``n`` samples, each its own direction pair and a random band of 31; no values yet."""
    ti, pi, to, po = goniometer_directions(n, spread=0.8, seed=seed)  # 2.5 × the widest lobe's m, as ``simulate`` picks
    band = np.random.default_rng([seed, 3]).integers(0, len(WL31), n)
    return Measurement(theta_i=ti, phi_i=pi, theta_o=to, phi_o=po, band=band, wavelength_nm=WL31, source="<scattered>")


def noisy(material: Material, geometry: Measurement, seed: int) -> Measurement:
    """``geometry`` with the material's values times (1 + 2 % Gaussian noise), clipped at 0."""
    truth = evaluate(material, geometry)
    eps = np.random.default_rng([seed, 1]).standard_normal(truth.shape)
    return geometry.replace(brdf=np.maximum(truth * (1 + NOISE * eps), 0.0), sigma=None)


def write_scattered(path: Path, n: int, seed: int) -> Path:
    write_csv(noisy(scattered_material(), scattered_geometry(n, seed), seed), path)
    return path


def write_batch(folder: Path, n_files: int, n_samples: int, seed: int) -> list[Path]:
    """``n_files`` CSVs of one scattered geometry, each its own truth and noise."""
    folder.mkdir(parents=True, exist_ok=True)
    geometry = scattered_geometry(n_samples, seed)
    rng = np.random.default_rng([seed, 5])
    paths = []
    for i in range(n_files):
        m = M_TRUE * rng.uniform(0.85, 1.15, 2)
        w0 = rng.uniform(0.5, 0.7)
        mat = scattered_material(m=m, w=[w0, 1 - w0], s=rng.uniform(0.85, 0.95), f0=np.clip(F0_TRUE * rng.uniform(0.9, 1.05), 0, 0.99))
        paths.append(folder / f"sample-{i:04d}.csv")
        write_csv(noisy(mat, geometry, seed + 1 + i), paths[-1])
    return paths


def default_start_x0(lobes: int, n_bands: int, diffuse: bool) -> list[float]:
    """ctfit's default start (``ctfit.fit``'s default: m log-spaced 0.1 … 0.3, equal
    weights, F0 = 0.5, s = 0.5) in the NumPy model's coordinates (logit F0, log m, logit w, logit s)."""
    x = [np.zeros(n_bands), np.log(np.geomspace(0.1, 0.3, lobes)), np.zeros(lobes - 1)]
    return np.concatenate(x + ([np.zeros(1)] if diffuse else [])).tolist()


def write_merl_file(path: Path, pairs: int | None, seed: int) -> int:
    """A MERL table of the one-lobe RGB metal; ``pairs`` cells above the horizon measured (all
    when None), the rest marked unmeasured. Returns the number of samples a reader gets."""
    angles = lambda th, td, pd: ctfit.half_diff_deg_to_angles_deg(*(np.degrees(a) for a in (th, td, pd)))  # every cell's directions, in file order
    ti, pi, to = (a.reshape(-1) for a in ctfit.merl_table(lambda *c: angles(*c)[:3]))
    po = ctfit.merl_table(lambda *c: angles(*c)[3])[0].reshape(-1)
    above = (ti < 90) & (to < 90)
    cells = np.flatnonzero(above)
    rng = np.random.default_rng([seed, 9])
    if pairs is not None:
        cells = np.sort(rng.choice(cells, size=min(pairs, cells.size), replace=False))
    mat = Material(METAL, Params(m=np.array([MERL_TRUTH["m"]]), w=np.ones(1), f0=np.array(MERL_TRUTH["f0"])), channels=RGB)
    rep = lambda a: np.repeat(a[cells], 3)
    geometry = Measurement(theta_i=rep(ti), phi_i=rep(pi), theta_o=rep(to), phi_o=rep(po), band=np.tile(np.arange(3), cells.size), channels=RGB)
    values = noisy(mat, geometry, seed).brdf
    table = np.full((3, ti.size), np.nan)
    table[:, cells] = values.reshape(cells.size, 3).T
    ctfit.write_merl(path, table.reshape(3, 90, 90, 180))
    return values.size


def texel_case(n_texels: int, n_pairs: int, seed: int):
    """(geometry: ``n_pairs`` direction pairs × R, G, B; values (texels, samples); truth m
    (texels,), F0 (texels, 3)) for a one-lobe RGB metal varying over the texels."""
    ti, pi, to, po = goniometer_directions(n_pairs, spread=0.75, seed=seed)
    rep = lambda a: np.repeat(a, 3)
    geometry = Measurement(theta_i=rep(ti), phi_i=rep(pi), theta_o=rep(to), phi_o=rep(po), band=np.tile(np.arange(3), n_pairs), channels=RGB,
                           source="<texels>")
    rng = np.random.default_rng([seed, 11])
    m = rng.uniform(0.1, 0.3, n_texels)
    f0 = rng.uniform(0.3, 0.95, (n_texels, 3))
    geom = ctfit.geometry_from_angles_deg(*(jnp.asarray(a, dtype=float) for a in (ti, pi, to, po)))
    grid = jax.jit(jax.vmap(lambda m1, f: ctfit.brdf(METAL, Params(m=m1[None], w=jnp.ones(1), f0=f), geom)))
    values = np.concatenate([np.asarray(grid(m[a : a + 8192], f0[a : a + 8192])).reshape(-1, 3 * n_pairs) for a in range(0, n_texels, 8192)])
    values *= 1 + NOISE * rng.standard_normal(values.shape)
    return geometry, np.maximum(values, 0.0), m, f0


def mitsuba_case(folder: Path, n_pairs: int, seed: int, env: dict) -> dict:
    """Mitsuba's copper ``roughconductor`` rendered at ``n_pairs`` goniometer direction pairs:
    a CSV (R, G, B channels; BRDF = eval / cos θ_o) for ctfit, the same numbers as an .npz
    (unit vectors, eval) for the Mitsuba peer, and the truth (α, η, k, F0 per channel)."""
    ti, pi, to, po = goniometer_directions(n_pairs, spread=2.5 * 0.15, max_theta=85.0, seed=seed)
    light = np.asarray(ctfit.direction_from_angles_deg(ti, pi), dtype=float)
    view = np.asarray(ctfit.direction_from_angles_deg(to, po), dtype=float)
    dirs, rendered = folder / "mitsuba-directions.npz", folder / "mitsuba-rendered.npz"
    np.savez(dirs, light=light, view=view)
    done = subprocess.run([sys.executable, str(SCRIPTS / "_mitsuba_fit.py"), "render", str(dirs), str(rendered)], env=env, capture_output=True, text=True)
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or [f"exit status {done.returncode}"])[-1]
        raise RuntimeError(f"Mitsuba could not render: {last}")
    r = np.load(rendered)
    value = r["value"]  # (3, N): f_r · cos θ_o
    npz = folder / "mitsuba-peer.npz"
    np.savez(npz, light=light, view=view, value=value)
    csv = folder / "mitsuba.csv"
    rep = lambda a: np.repeat(a, 3)
    write_csv(Measurement(theta_i=rep(ti), phi_i=rep(pi), theta_o=rep(to), phi_o=rep(po), band=np.tile(np.arange(3), n_pairs), channels=RGB,
                          brdf=(value / view[:, 2]).T.reshape(-1)), csv)
    eta, k = r["eta"], r["k"]
    truth = dict(alpha=float(r["alpha"]), eta=eta.tolist(), k=k.tolist(), f0=np.asarray(ctfit.f0_from_nk(eta, k), dtype=float).tolist(),
                 zeros=float(np.mean(value == 0)))
    (folder / "mitsuba-truth.json").write_text(json.dumps(truth))
    return dict(csv=csv, npz=npz, truth=truth)
