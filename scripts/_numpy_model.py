"""The Cook–Torrance model and its least-squares residual in plain NumPy: the SciPy peer of the
fit benchmarks (``bench_fit.py``, ``fit_tradeoffs.py``).

Same model as ctfit: normalised Cook–Torrance, Σ_j w_j Beckmann D(m_j), the paper's V-cavity G,
the paper's unpolarised Fresnel with the effective index from F0 (k = 0); a metal (d = 0), with
``diffuse=True`` (or ``"F0/pi"``) the paper's homogeneous material R = s R_s + (1 − s) F0/π, with
``diffuse="spectrum"`` R = s R_s + (1 − s) R_d, R_d per band. Unconstrained coordinates, as SciPy's
``least_squares(method="lm")`` needs: u = (logit F0 (W bands), log m (J lobes), w_1..w_{J−1} as
logits against w_0 (softmax)[, logit s][, log R_d (W)]); ctfit's own fit varies box
coordinates inside bounds instead (``docs/fitting.md``), the sampler these ones. The residual
weightings are ctfit's (the ``--loss`` choices of ``docs/fitting.md``), and "log-ratio": ln f − ln y
on the samples with y > 0 (``bench_real.py``).

Imports NumPy only, so that a SciPy process timed as a whole (``bench_fit.py``) pays for nothing
else; :func:`read_csv_numpy` reads a spectral or RGB measurement CSV for it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["np_geometry", "np_fresnel_f0", "NumpyProblem", "NumpyData", "read_csv_numpy", "NUMPY_LOSSES"]

NUMPY_LOSSES = ("absolute", "relative", "robust-relative", "sigma", "cosine", "log", "log-ratio")
NUMPY_DIFFUSES = (False, True, "F0/pi", "spectrum")
TINY = 1e-300


def np_geometry(pairs):
    def direction(theta, phi):
        t, p = np.deg2rad(theta), np.deg2rad(np.mod(phi, 360))
        return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.sin(np.deg2rad(90 - theta))], axis=-1)

    l, v = direction(pairs[:, 0], pairs[:, 1]), direction(pairs[:, 2], pairs[:, 3])
    cos_l, cos_v = l[:, 2], v[:, 2]
    valid = (cos_l > 0) & (cos_v > 0)
    n = np.array([0.0, 0.0, 1.0])
    l = np.where(valid[:, None], l, n)
    v = np.where(valid[:, None], v, n)
    cos_l, cos_v = l[:, 2], v[:, 2]
    h = l + v
    h_len = np.linalg.norm(h, axis=1)
    cross = h[:, 0] ** 2 + h[:, 1] ** 2
    return dict(cos_l=cos_l, cos_v=cos_v, cos_h=h[:, 2] / h_len, tan2=cross / h[:, 2] ** 2, cos_vh=0.5 * h_len, valid=valid)


def np_fresnel_f0(c, f0):
    r = np.sqrt(np.maximum(f0, 1e-30))
    c2 = c * c
    s2 = 1 - c2
    one_plus_r = 1 + r
    u = (1 - r) / one_plus_r
    a = 4 * r / (one_plus_r * one_plus_r)
    g2 = c2 + s2 * a
    g = np.sqrt(g2)
    gcu = g + c * u
    p = c * g + s2 * u
    num = 16 * f0 * (c2 * g2 + s2 * s2 * u * u)
    den = (one_plus_r * one_plus_r * gcu * gcu) ** 2 * (p * p)
    return np.clip(num / den, 0, 1)


class NumpyData:
    """The fields of a :class:`ctfit.Measurement` that :class:`NumpyProblem` reads, without ctfit."""

    def __init__(self, theta_i, phi_i, theta_o, phi_o, band, n_bands: int, brdf, sigma=None):
        self.theta_i, self.phi_i, self.theta_o, self.phi_o = (np.asarray(a, dtype=float) for a in (theta_i, phi_i, theta_o, phi_o))
        self.band, self.n_bands = np.asarray(band, dtype=np.int64), int(n_bands)
        self.brdf, self.sigma = np.asarray(brdf, dtype=float), None if sigma is None else np.asarray(sigma, dtype=float)

    def directions(self):
        """Unique direction pairs (P, 4) and each sample's index into them (as ctfit's)."""
        rows = np.stack([self.theta_i, np.mod(self.phi_i, 360), self.theta_o, np.mod(self.phi_o, 360)], axis=1)
        pairs, index = np.unique(rows, axis=0, return_inverse=True)
        return pairs, index.reshape(-1)


def read_csv_numpy(path) -> NumpyData:
    """A measurement CSV (``docs/measurement-formats.md``: ``#`` lines, a header naming theta_i,
    phi_i, theta_o, phi_o, wavelength_nm or channel (R, G, B), brdf[, sigma]) read with
    ``numpy.loadtxt``; no checks beyond NumPy's (the files are the benchmark's own)."""
    with open(path, encoding="utf-8") as f:
        skip = 0
        for line in f:
            skip += 1
            if line.strip() and not line.lstrip().startswith("#"):
                names = [c.strip().strip('"') for c in line.split(",")]
                break
    rgb = {"channel": lambda c: "RGB".index(c.strip())} if "channel" in names else {}
    cols = np.loadtxt(path, delimiter=",", skiprows=skip, ndmin=2, dtype=float, converters={names.index(k): f for k, f in rgb.items()}).T
    col = dict(zip(names, cols))
    wl, band = np.unique(col["channel" if rgb else "wavelength_nm"], return_inverse=True)
    return NumpyData(col["theta_i"], col["phi_i"], col["theta_o"], col["phi_o"], band, len(wl), col["brdf"], col.get("sigma"))


class NumpyProblem:
    """r(u) on the samples for a ``lobes``-lobe material, u = (logit F0 (W), log m (J), logit w (J − 1)
    [, logit s with ``diffuse``][, log R_d (W) with ``diffuse="spectrum"``]).

    ``loss`` as in ctfit: absolute f − y; relative r = (f − y)/max(y, floor), the floor
    max(0.1 × median y, 10⁻⁶ max y); robust-relative r·√(2/(√(1 + (r/0.05)²) + 1)) (SciPy's
    ``soft_l1`` with ``f_scale=0.05``, as a residual); sigma (f − y)/σ;
    cosine (f − y) cos θ_i; log ln(1 + f cos θ_i) − ln(1 + y cos θ_i); and log-ratio ln f − ln y
    where y > 0 (0 elsewhere).
    """

    def __init__(self, data, lobes: int = 2, loss: str = "sigma", diffuse: bool | str = False):
        if loss not in NUMPY_LOSSES:
            raise ValueError(f"loss must be one of {NUMPY_LOSSES}, got {loss!r}")
        if diffuse not in NUMPY_DIFFUSES:
            raise ValueError(f"diffuse must be one of {NUMPY_DIFFUSES}, got {diffuse!r}")
        pairs, index = data.directions()
        self.shape = (len(pairs), data.n_bands)
        self.geom = np_geometry(pairs)
        g = self.geom
        self.g_red = np.minimum(1 / (g["cos_l"] * g["cos_v"]), np.minimum(2 * g["cos_h"] / g["cos_vh"] / g["cos_l"], 2 * g["cos_h"] / g["cos_vh"] / g["cos_v"]))
        self.tan2 = np.minimum(g["tan2"], 1e12)
        self.index, self.band = index, data.band
        self.grid = len(pairs) * data.n_bands <= 1.5 * len(index)
        self.y, self.sigma = data.brdf, data.sigma
        self.w_bands = data.n_bands
        self.lobes, self.loss, self.diffuse, self.rd = lobes, loss, bool(diffuse), diffuse == "spectrum"
        y_pos = self.y[self.y > 0]
        self.floor = max(0.1 * float(np.median(y_pos)), 1e-6 * float(np.max(y_pos))) if len(y_pos) else 1.0
        self.cos_i = np.cos(np.deg2rad(pairs[:, 0]))[index]

    def params(self, u):
        """(F0 (W,), m (J,), w (J,)) from the free values ``u``; with ``diffuse``, s as a fourth, with
        ``diffuse="spectrum"`` R_d (W,) as a fifth."""
        w_b, j = self.w_bands, self.lobes
        f0 = 1 / (1 + np.exp(-u[:w_b]))
        m = np.exp(u[w_b : w_b + j])
        w = np.exp(np.concatenate([[0.0], u[w_b + j : w_b + 2 * j - 1]]))
        out = (f0, m, w / w.sum())
        if self.diffuse:
            out += (1 / (1 + np.exp(-u[w_b + 2 * j - 1])),)
        return out + (np.exp(u[w_b + 2 * j : 2 * w_b + 2 * j]),) if self.rd else out

    def model(self, u):
        f0, m, w, *s = self.params(u)
        rd = s[1] if self.rd else f0 / np.pi
        t = self.tan2[:, None]
        d = np.exp(-t / m**2) * (1 + t) ** 2 / m**2
        spec = (0.25 / np.pi) * self.g_red * (d @ w)
        valid = self.geom["valid"]
        spec = np.where(valid, spec, 0.0)
        if self.grid:  # F per (pair, band) cell, as ctfit lays out dense data
            f = (np_fresnel_f0(self.geom["cos_vh"][:, None], f0[None, :]) * spec[:, None])[self.index, self.band]
        else:  # F per sample: scattered data, every sample its own pair
            f = np_fresnel_f0(self.geom["cos_vh"][self.index], f0[self.band]) * spec[self.index]
        if self.diffuse:
            f = s[0] * f + np.where(valid[self.index], (1 - s[0]) * rd[self.band], 0.0)
        return f

    def residual(self, u):
        f, y = self.model(u), self.y
        if self.loss == "sigma":
            return (f - y) / self.sigma
        if self.loss == "absolute":
            return f - y
        if self.loss == "relative":
            return (f - y) / np.maximum(y, self.floor)
        if self.loss == "robust-relative":
            r = (f - y) / np.maximum(y, self.floor)
            return r * np.sqrt(2.0 / (np.hypot(1.0, r / 0.05) + 1.0))
        if self.loss == "cosine":
            return (f - y) * self.cos_i
        if self.loss == "log-ratio":
            pos = y > 0
            return np.where(pos, np.log(np.maximum(f, TINY)) - np.log(np.where(pos, y, 1.0)), 0.0)
        return np.log1p(f * self.cos_i) - np.log1p(y * self.cos_i)
