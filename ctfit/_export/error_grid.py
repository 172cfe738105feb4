"""How far an exported material is from the fit: the relative difference of the BRDF over one grid.

The grid (``docs/export.md``): light at θ_i ∈ {5°, 15°, …, 85°}, φ_i = 0; viewer at
θ_o ∈ {5°, 15°, …, 85°} and φ_o ∈ {0°, 20°, …, 340°} — 9 × 9 × 18 = 1458 direction pairs, in
every band the comparison has. At each the relative difference is |f_target − f_fit| / f_fit;
values of the fit below 10⁻⁶ × its largest value on the grid (a specular-only tail) are left out,
or, with a diffuse part, below 10⁻⁶ × the diffuse part's largest value where that is lower: a
mirror-like lobe's peak on the grid (3.3·10⁶ sr⁻¹ at m = 0.001) put the floor above the whole
diffuse part, and the figures were of the 27 peak values of 4,374 (median 1.1 %, where all give 79 %).
"""

from __future__ import annotations

import numpy as np

__all__ = ["ERROR_GRID", "error_grid_angles", "relative_difference", "unit_directions"]

ERROR_GRID = "θ_i, θ_o ∈ {5°, 15°, …, 85°}, φ_i = 0, φ_o ∈ {0°, 20°, …, 340°} (1458 pairs; fit values < 1e-6 × max (of the diffuse part, if lower) left out)"
"""The hemisphere grid of every approximation error, in words (printed and written with it)."""

_FLOOR = 1e-6


def error_grid_angles():
    """(θ_i, φ_i, θ_o, φ_o) in degrees, flat arrays of the 1458 direction pairs of :data:`ERROR_GRID`.

    Examples
    --------
    >>> from ctfit._export.error_grid import error_grid_angles
    >>> ti, pi, to, po = error_grid_angles()
    >>> ti.shape, float(ti.min()), float(ti.max()), float(po.max())
    ((1458,), 5.0, 85.0, 340.0)
    """
    theta = np.arange(5.0, 90.0, 10.0)
    ti, to, po = np.meshgrid(theta, theta, np.arange(0.0, 360.0, 20.0), indexing="ij")
    return ti.reshape(-1), np.zeros(ti.size), to.reshape(-1), po.reshape(-1)


def relative_difference(target, fit, diffuse_peak: float = 0.0) -> dict:
    """Median and maximum of |target − fit| / fit over the entries where fit > 0 and fit ≥ 10⁻⁶ max(fit),
    or ≥ 10⁻⁶ ``diffuse_peak`` (the largest value of the fit's diffuse part; 0: none) where that is
    lower (0 and 0 where the fit and the target are 0 everywhere: a black material); ``compared``:
    how many entries that is, of ``values``.

    Examples
    --------
    >>> from ctfit._export.error_grid import relative_difference
    >>> relative_difference([1.1, 2.0, 5e-9], [1.0, 2.0, 1e-9])
    {'median': 0.05, 'max': 0.1, 'compared': 2, 'values': 3}
    >>> relative_difference([3e9, 0.06, 0.07], [3e9, 0.05, 0.05], diffuse_peak=0.05)["median"]  # a mirror-like peak: the diffuse values count
    0.2
    """
    target, fit = np.asarray(target, float), np.asarray(fit, float)
    floor = _FLOOR * (min(np.max(fit), diffuse_peak) if diffuse_peak > 0 else np.max(fit))
    keep = (fit > 0) & (fit >= floor)
    if not keep.any():  # a black fit: exact where the target is black too
        if np.any(target != 0):
            raise ValueError("the fit is 0 over the whole grid and the export is not: no relative difference")
        return {"median": 0.0, "max": 0.0, "compared": 0, "values": int(fit.size)}
    rel = np.abs(target[keep] - fit[keep]) / fit[keep]
    return {"median": round(float(np.median(rel)), 12), "max": round(float(np.max(rel)), 12), "compared": int(keep.sum()), "values": int(fit.size)}


def unit_directions(theta_deg, phi_deg) -> np.ndarray:
    """Unit vectors (…, 3) of directions in degrees (normal +z), in NumPy float64.

    Examples
    --------
    >>> from ctfit._export.error_grid import unit_directions
    >>> unit_directions(90.0, 90.0).round(12).tolist()
    [0.0, 1.0, 0.0]
    """
    t, p = np.radians(np.asarray(theta_deg, float)), np.radians(np.asarray(phi_deg, float))
    return np.stack(np.broadcast_arrays(np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)), axis=-1)
