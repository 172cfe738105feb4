"""The Cook–Torrance model and its least-squares residual in plain NumPy: the SciPy peer of the
fit benchmarks (``bench_fit.py``, ``fit_tradeoffs.py``).

Same model as ctfit for a metal: normalised Cook–Torrance, Σ_j w_j Beckmann D(m_j), the paper's
V-cavity G, the paper's unpolarised Fresnel with the effective index from F0 (k = 0), d = 0.
Same parameterisation as ``ctfit._problem``: u = (logit F0 (W bands), log m (J lobes),
w_1..w_{J−1} as logits against w_0 (softmax)), and the same residual weightings (``ctfit._problem.LOSSES``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["np_geometry", "np_fresnel_f0", "NumpyProblem", "NUMPY_LOSSES"]

NUMPY_LOSSES = ("absolute", "relative", "sigma", "cosine", "log")


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


class NumpyProblem:
    """r(u) on the samples for a ``lobes``-lobe metal, u = (logit F0 (W), log m (J), logit w (J − 1)).

    ``loss`` as in ctfit: absolute f − y; relative (f − y)/max(y, 10⁻³ max y); sigma (f − y)/σ;
    cosine (f − y) cos θ_i; log ln(1 + f cos θ_i) − ln(1 + y cos θ_i).
    """

    def __init__(self, data, lobes: int = 2, loss: str = "sigma"):
        if loss not in NUMPY_LOSSES:
            raise ValueError(f"loss must be one of {NUMPY_LOSSES}, got {loss!r}")
        pairs, index = data.directions()
        self.shape = (len(pairs), data.n_bands)
        self.geom = np_geometry(pairs)
        g = self.geom
        self.g_red = np.minimum(1 / (g["cos_l"] * g["cos_v"]), np.minimum(2 * g["cos_h"] / g["cos_vh"] / g["cos_l"], 2 * g["cos_h"] / g["cos_vh"] / g["cos_v"]))
        self.tan2 = np.minimum(g["tan2"], 1e12)
        self.index, self.band = index, data.band
        self.y, self.sigma = data.brdf, data.sigma
        self.w_bands = data.n_bands
        self.lobes, self.loss = lobes, loss
        y_pos = self.y[self.y > 0]
        self.floor = 1e-3 * float(np.max(y_pos)) if len(y_pos) else 1.0
        self.cos_i = np.cos(np.deg2rad(pairs[:, 0]))[index]

    def params(self, u):
        """(F0 (W,), m (J,), w (J,)) from the free values ``u``."""
        w_b, j = self.w_bands, self.lobes
        f0 = 1 / (1 + np.exp(-u[:w_b]))
        m = np.exp(u[w_b : w_b + j])
        w = np.exp(np.concatenate([[0.0], u[w_b + j :]]))
        return f0, m, w / w.sum()

    def model(self, u):
        f0, m, w = self.params(u)
        t = self.tan2[:, None]
        d = np.exp(-t / m**2) * (1 + t) ** 2 / m**2
        s = (0.25 / np.pi) * self.g_red * (d @ w)
        s = np.where(self.geom["valid"], s, 0.0)
        rgrid = np_fresnel_f0(self.geom["cos_vh"][:, None], f0[None, :]) * s[:, None]
        return rgrid[self.index, self.band]

    def residual(self, u):
        f, y = self.model(u), self.y
        if self.loss == "sigma":
            return (f - y) / self.sigma
        if self.loss == "absolute":
            return f - y
        if self.loss == "relative":
            return (f - y) / np.maximum(y, self.floor)
        if self.loss == "cosine":
            return (f - y) * self.cos_i
        return np.log1p(f * self.cos_i) - np.log1p(y * self.cos_i)
