"""Residual diagnostics: does the fit leave systematic structure that the model cannot represent?

Relative residuals e = (model − data)/max(data, floor) are grouped by angular variables that
separate the lobes a Cook–Torrance surface can and cannot produce:

- the angle between L and V (0° is exact retro-reflection: a retro-reflective lobe shows up as
  data far above the model there);
- the half-vector angle α (0° is the specular peak);
- the larger of θ_i and θ_o (grazing behaviour: Fresnel, shadowing).

In each bin of at least ``min_count`` samples the mean residual and its standard error are
computed. A bin is *systematic* when its mean departs from 0 by more than ``threshold``
(default 10 %) and by more than 4 standard errors. Every systematic group yields one plain
warning naming where the model is too high or too low.
"""

from __future__ import annotations

import numpy as np

from ._measurement import Measurement

__all__ = ["residual_structure"]


def _angle_lv(data: Measurement) -> np.ndarray:
    ti, to = np.deg2rad(data.theta_i), np.deg2rad(data.theta_o)
    dphi = np.deg2rad(data.phi_o - data.phi_i)
    cos = np.sin(ti) * np.sin(to) * np.cos(dphi) + np.cos(ti) * np.cos(to)
    return np.rad2deg(np.arccos(np.clip(cos, -1, 1)))


def _half_angle(data: Measurement) -> np.ndarray:
    def vec(t, p):
        t, p = np.deg2rad(t), np.deg2rad(p)
        return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)

    h = vec(data.theta_i, data.phi_i) + vec(data.theta_o, data.phi_o)
    norm = np.linalg.norm(h, axis=-1)
    return np.rad2deg(np.arccos(np.clip(h[:, 2] / np.maximum(norm, 1e-300), -1, 1)))


_GROUPS = (
    ("angle between L and V", _angle_lv, np.array([0, 2, 5, 10, 20, 40, 80, 180.0]), "retro-reflection"),
    ("half-vector angle α", _half_angle, np.array([0, 2, 5, 10, 20, 40, 90.0]), "the specular peak"),
    ("max(θ_i, θ_o)", lambda d: np.maximum(d.theta_i, d.theta_o), np.array([0, 30, 60, 75, 85, 90.0]), "grazing"),
)


def residual_structure(
    data: Measurement, model: np.ndarray, *, floor: float | None = None, threshold: float = 0.1, min_count: int = 20
) -> list[str]:
    """Plain-language warnings about systematic residual structure (empty when there is none)."""
    y = np.asarray(data.brdf, dtype=float)
    model = np.asarray(model, dtype=float)
    if floor is None:
        floor = 1e-3 * float(np.max(y)) if np.any(y > 0) else 1.0
    e = (model - y) / np.maximum(np.abs(y), floor)
    out = []
    for name, variable, edges, place in _GROUPS:
        x = variable(data)
        idx = np.clip(np.digitize(x, edges) - 1, 0, len(edges) - 2)
        worst = None
        for b in range(len(edges) - 1):
            sel = idx == b
            n = int(sel.sum())
            if n < min_count:
                continue
            mean = float(np.mean(e[sel]))
            se = float(np.std(e[sel], ddof=1) / np.sqrt(n))
            if abs(mean) > threshold and abs(mean) > 4 * se and (worst is None or abs(mean) > abs(worst[0])):
                worst = (mean, edges[b], edges[b + 1], n)
        if worst is not None:
            mean, lo, hi, n = worst
            side = "below" if mean < 0 else "above"
            span = f"[{lo:g}°, {hi:g}°" + ("]" if hi == edges[-1] else ")")  # the last bin holds its upper edge
            out.append(f"systematic residuals: the model is {abs(mean):.0%} {side} the data for {name} in {span} ({n} samples){_explain(place, mean, lo)}")
    return out


def _explain(place: str, mean: float, lo: float) -> str:
    if place == "retro-reflection" and mean < 0 and lo < 10:
        return " — a retro-reflection lobe, which the Cook–Torrance model cannot represent"
    if (place == "the specular peak" and lo < 5) or (place == "grazing" and lo >= 75):
        return f" (near {place})"
    return ""
