"""Shared test helpers: structures, parameter sets, direction grids, and independent references.

The references here are written from the textbook formulas without looking at how ctfit
evaluates them (NumPy float64 and mpmath at 50 digits), so that a test comparing against them
checks the formulas, not a copy of the code.

- :data:`STRUCTURES`: every structure combination (distribution × geometry × Fresnel form ×
  diffuse kind × normalisation), two lobes.
- :func:`make_params`: a parameter set for any structure, in any dtype.
- :func:`reference_brdf`: R = s R_s + d R_d straight from Cook & Torrance (1982) eqs. 1–5, 8
  and the appendix Fresnel formula, in NumPy float64 (Smith's G1 with ``scipy.special.erf``).
- :func:`mp_fresnel_dielectric`, :func:`mp_fresnel_conductor`: 50-digit Fresnel references.
- :func:`directions`, :func:`angle_grid`: unit vectors from angles in degrees.
- :func:`gauss_legendre`: composite Gauss–Legendre nodes and weights on given breakpoints.
"""

from __future__ import annotations

import itertools
import sys

import mpmath
import numpy as np
from scipy import integrate, special

import ctfit
from ctfit import Params, Structure

__all__ = [
    "STRUCTURES",
    "structure_id",
    "make_params",
    "reference_brdf",
    "mp_fresnel_dielectric",
    "mp_fresnel_conductor",
    "directions",
    "angle_grid",
    "gauss_legendre",
    "PARAM_FIELDS",
]

PARAM_FIELDS = ("s", "m", "w", "f0", "n", "k", "rd")

STRUCTURES = [
    Structure(lobes=2, distribution=dist, geometry=geo, fresnel=fr, diffuse=diff, normalization=norm)
    for dist, geo, fr, diff, norm in itertools.product(
        ("beckmann", "gaussian"),
        ("v-cavity", "smith"),
        ("f0", "n", "conductor"),
        (None, "F0/pi", "spectrum", "constant"),
        ("normalized", "cook-torrance-1982"),
    )
]


def structure_id(st: Structure) -> str:
    return f"L{st.lobes}-{st.distribution}-{st.geometry}-{st.fresnel}-{st.diffuse}-{st.normalization}"


# Three bands with deliberately different materials: a dielectric, a mid, a metal-like band.
_F0 = (0.04, 0.5, 0.9)
_N = (1.5, 2.4, 4.0)
_N_COND = (0.2, 1.1, 2.5)
_K_COND = (3.0, 0.5, 4.0)
_RD = (0.05, 0.1, 0.2)


def make_params(structure: Structure, dtype=np.float64, *, m=(0.2, 0.5), w=None, s=0.7, f0=_F0, n=None, k=None, rd=_RD, rd_constant=0.08):
    """Params for ``structure`` on three bands (or as many as ``f0``/``n`` have), as ``dtype`` arrays."""
    import jax.numpy as jnp

    def arr(x):
        return jnp.asarray(np.asarray(x, dtype=np.float64), dtype=dtype)

    kw = {}
    if structure.lobes:
        mm = np.resize(np.asarray(m, dtype=np.float64), structure.lobes)
        ww = np.full(structure.lobes, 1.0 / structure.lobes) if w is None else np.asarray(w, dtype=np.float64)
        kw["m"], kw["w"] = arr(mm), arr(ww)
    if structure.needs_fresnel_params:
        if structure.fresnel == "f0":
            kw["f0"] = arr(f0)
        elif structure.fresnel == "n":
            kw["n"] = arr(_N if n is None else n)
        else:
            kw["n"] = arr(_N_COND if n is None else n)
            kw["k"] = arr(_K_COND if k is None else k)
    if structure.diffuse == "spectrum":
        kw["rd"] = arr(rd)
    elif structure.diffuse == "constant":
        kw["rd"] = arr(rd_constant)
    if structure.has_s:
        kw["s"] = arr(s)
    return Params(**kw)


# --------------------------------------------------------------------------- directions


def directions(theta_deg, phi_deg):
    """Unit vectors (..., 3) from polar angle and azimuth in degrees (NumPy float64)."""
    t = np.deg2rad(np.asarray(theta_deg, dtype=np.float64))
    p = np.deg2rad(np.asarray(phi_deg, dtype=np.float64))
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def angle_grid(thetas, phis_o, phi_i=0.0):
    """All (θ_i, θ_o, φ_o) combinations with φ_i fixed; returns flat (θ_i, φ_i, θ_o, φ_o) arrays."""
    ti, to, po = np.meshgrid(np.asarray(thetas, float), np.asarray(thetas, float), np.asarray(phis_o, float), indexing="ij")
    ti, to, po = ti.ravel(), to.ravel(), po.ravel()
    return ti, np.full_like(ti, phi_i), to, po


def gauss_legendre(breakpoints, order=32):
    """Nodes and weights of a composite Gauss–Legendre rule on the intervals between ``breakpoints``."""
    x, w = np.polynomial.legendre.leggauss(order)
    b = np.unique(np.asarray(breakpoints, dtype=np.float64))
    lo, hi = b[:-1, None], b[1:, None]
    nodes = 0.5 * (hi - lo) * x + 0.5 * (hi + lo)
    weights = 0.5 * (hi - lo) * w
    return nodes.ravel(), weights.ravel()


# --------------------------------------------------------------------------- references


def mp_fresnel_dielectric(c, n, dps=50):
    """The paper's unpolarised Fresnel formula (appendix) at ``dps`` digits; c = cos θ, real n ≥ 1.

    F = ½ (g − c)²/(g + c)² {1 + [c(g + c) − 1]²/[c(g − c) + 1]²}, g² = n² + c² − 1.
    Inputs are taken as exact binary values.
    """
    with mpmath.workdps(dps):
        c, n = mpmath.mpf(float(c)), mpmath.mpf(float(n))
        g = mpmath.sqrt(n * n + c * c - 1)
        return 0.5 * (g - c) ** 2 / (g + c) ** 2 * (1 + (c * (g + c) - 1) ** 2 / (c * (g - c) + 1) ** 2)


def mp_fresnel_dielectric_f0(c, f0, dps=50):
    """:func:`mp_fresnel_dielectric` with the paper's effective index n = (1 + √F0)/(1 − √F0)."""
    with mpmath.workdps(dps):
        r = mpmath.sqrt(mpmath.mpf(float(f0)))
        return mp_fresnel_dielectric_exact(mpmath.mpf(float(c)), (1 + r) / (1 - r), dps)


def mp_fresnel_dielectric_exact(c, n, dps=50):
    with mpmath.workdps(dps):
        g = mpmath.sqrt(n * n + c * c - 1)
        return 0.5 * (g - c) ** 2 / (g + c) ** 2 * (1 + (c * (g + c) - 1) ** 2 / (c * (g - c) + 1) ** 2)


def mp_fresnel_conductor(c, n, k, dps=50):
    """Unpolarised reflectance of a complex index η = n + i k from the complex Fresnel amplitudes.

    r_s = (cos θ − η cos θ_t)/(cos θ + η cos θ_t), r_p = (η cos θ − cos θ_t)/(η cos θ + cos θ_t),
    η cos θ_t = √(η² − sin²θ) (Born & Wolf §1.5.2 with Snell's law continued to complex η);
    F = ½ (|r_s|² + |r_p|²).
    """
    with mpmath.workdps(dps):
        c = mpmath.mpf(float(c))
        eta = mpmath.mpc(float(n), float(k))
        s2 = 1 - c * c
        eta_ct = mpmath.sqrt(eta * eta - s2)
        ct = eta_ct / eta
        rs = (c - eta_ct) / (c + eta_ct)
        rp = (eta * c - ct) / (eta * c + ct)
        return (abs(rs) ** 2 + abs(rp) ** 2) / 2


def _np_fresnel_dielectric(c, n):
    g = np.sqrt(n * n + c * c - 1)
    return 0.5 * (g - c) ** 2 / (g + c) ** 2 * (1 + (c * (g + c) - 1) ** 2 / (c * (g - c) + 1) ** 2)


def _np_fresnel_conductor(c, n, k):
    eta = n + 1j * k
    eta_ct = np.sqrt(eta * eta - (1 - c * c))
    ct = eta_ct / eta
    rs = (c - eta_ct) / (c + eta_ct)
    rp = (eta * c - ct) / (eta * c + ct)
    return 0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2)


def _gaussian_constant(m, normalized):
    """c in D̂ = c exp(−(α/m)²): 1/m² (1982), or such that 2 ∫ D̂ cos α sin α dα = 1."""
    if not normalized:
        return 1 / m**2
    pts = [x for x in (m, 3 * m) if x < np.pi / 2]
    val, _ = integrate.quad(lambda a: np.exp(-((a / m) ** 2)) * np.cos(a) * np.sin(a), 0, np.pi / 2, points=pts or None, limit=200, epsabs=0, epsrel=1e-13)
    return 1 / (2 * val)


def _smith_g1(cos_t, m):
    sin_t = np.sqrt(np.maximum(1 - cos_t * cos_t, 0))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        a = cos_t / (m * sin_t)
        g1 = 2 / (1 + special.erf(a) + np.exp(-a * a) / (a * np.sqrt(np.pi)))
    return np.where(sin_t == 0, 1.0, np.where(a > 30, 1.0, g1))


def reference_brdf(structure: Structure, params: Params, l, v):
    """R (sr⁻¹) for direction pairs l, v (P, 3) × bands, shape (P, B), in NumPy float64.

    Textbook transcription; directions on or below the horizon give 0.
    """
    p = {f: (None if getattr(params, f) is None else np.asarray(getattr(params, f), dtype=np.float64)) for f in PARAM_FIELDS}
    l = np.asarray(l, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    cl, cv = l[:, 2], v[:, 2]
    valid = (cl > 0) & (cv > 0)
    h = l + v
    h = h / np.linalg.norm(h, axis=1, keepdims=True)
    ch = h[:, 2]
    c = np.sum(v * h, axis=1)
    alpha = np.arccos(np.clip(ch, -1, 1))
    tan2 = np.tan(alpha) ** 2
    normalized = structure.normalization == "normalized"
    # Band count and F0.
    if structure.fresnel == "f0":
        f0 = p["f0"]
    elif structure.fresnel == "n":
        f0 = None if p["n"] is None else ((p["n"] - 1) / (p["n"] + 1)) ** 2
    else:
        f0 = None if p["n"] is None else ((p["n"] - 1) ** 2 + p["k"] ** 2) / ((p["n"] + 1) ** 2 + p["k"] ** 2)
    bands = next((np.size(x) for x in (p["f0"], p["n"], p["rd"]) if x is not None and np.ndim(x) > 0), 1)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        out = np.zeros((len(cl), bands))
        if structure.lobes:
            total = np.zeros_like(cl)
            for mj, wj in zip(p["m"], p["w"]):
                if structure.distribution == "beckmann":
                    d = np.exp(-tan2 / mj**2) / (mj**2 * ch**4)
                else:
                    d = _gaussian_constant(mj, normalized) * np.exp(-((alpha / mj) ** 2))
                if structure.geometry == "v-cavity":
                    g = np.minimum(1, np.minimum(2 * ch * cv / c, 2 * ch * cl / c))
                else:
                    g = _smith_g1(cl, mj) * _smith_g1(cv, mj)
                total += wj * d * g
            k_const = 1 / (4 * np.pi) if normalized else 1 / np.pi
            spec = k_const * total / (cl * cv)
            cc = c[:, None]
            if structure.fresnel == "f0":
                r = np.sqrt(p["f0"])
                n_eff = np.where(r < 1, (1 + r) / np.where(r < 1, 1 - r, 1), np.inf)
                F = np.where(np.isinf(n_eff), 1.0, _np_fresnel_dielectric(cc, n_eff))
                F = np.where(p["f0"] == 0, 0.0, F)
            elif structure.fresnel == "n":
                F = _np_fresnel_dielectric(cc, p["n"])
            else:
                F = _np_fresnel_conductor(cc, p["n"], p["k"])
            rs = F * spec[:, None]
        if structure.diffuse is None:
            out = rs
        else:
            rd = f0 / np.pi if structure.diffuse == "F0/pi" else p["rd"]
            rd = np.broadcast_to(rd, (len(cl), bands))
            out = p["s"] * rs + (1 - p["s"]) * rd if structure.has_s else rd
    return np.where(valid[:, None], out, 0.0)


def ctfit_brdf(structure, params, l, v):
    """ctfit's R for direction vectors (convenience wrapper)."""
    import jax.numpy as jnp

    return ctfit.brdf(structure, params, ctfit.geometry(jnp.asarray(l), jnp.asarray(v)))


def patch_module(monkeypatch, module, name, value):
    """Set ``module.name`` for one test, where every importer sees it: a package keeps what it
    has handed out once (``lazy_loader``), so the module's package, and each package above it
    that exports the name (``ctfit.fit_batch``), holds the value for the test and is left as it
    was after it (a package that first handed the name out during the test kept the test's
    value for good: ``test_exported`` found ``ctfit.fit_batch`` a test's spy)."""
    monkeypatch.setattr(module, name, value)
    parts = module.__name__.split(".")
    for k in range(len(parts) - 1, 0, -1):
        package = sys.modules[".".join(parts[:k])]
        if k == len(parts) - 1 or name in getattr(package, "__all__", ()):
            monkeypatch.setitem(package.__dict__, name, value)  # undone after the test: as it was, or not there


def peak_traced_bytes(call) -> int:
    """The most memory Python's allocators held while ``call()`` ran (``tracemalloc``)."""
    import tracemalloc

    tracemalloc.start()
    try:
        call()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
