"""Residual diagnostics: does the fit leave systematic structure that the model cannot represent?

Relative residuals e = (model − data)/max(data, floor) are grouped by angular variables that
separate the lobes a Cook–Torrance surface can and cannot produce:

- the angle between L and V (0° is exact retro-reflection: a retro-reflective lobe shows up as
  data far above the model there), counted only away from the specular peak (half-vector angle
  α ≥ 10°): at normal incidence L ≈ V is the mirror direction too, where a missing or too narrow
  specular lobe is no retro-reflection;
- the half-vector angle α (0° is the specular peak);
- the larger of θ_i and θ_o (grazing behaviour: Fresnel, shadowing).

In each bin of at least ``min_count`` samples the mean residual and its standard error are
computed. A bin is *systematic* when its mean departs from 0 by more than ``threshold``
(default 10 %) and by more than 4 standard errors. Every systematic group yields one plain
warning naming where the model is too high or too low.

Samples whose value is exactly 0 are left out of the bins and judged on their own
(:func:`zero_samples_warning`): where 0 stands for a value not measured, their relative
residuals (the model over the floor) are not errors of the fit, and one sample in ten of them
made every bin's mean read "the model is 1,000–15,000 % above the data" for a fit exact on
every other sample.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from .._model import Measurement
from .fit_warnings import FitWarning
from .losses import loss_floor

__all__ = ["angle_lv_deg", "half_angle_deg", "pair_half_angle_deg", "relative_residual_structure", "residual_notes", "residual_structure",
           "zero_samples_warning", "ZERO_SAMPLES", "ZEROS_HINT"]


def _angle_lv(ti: np.ndarray, pi: np.ndarray, to: np.ndarray, po: np.ndarray) -> np.ndarray:
    ti, to = np.deg2rad(ti), np.deg2rad(to)
    cos = np.sin(ti) * np.sin(to) * np.cos(np.deg2rad(po - pi)) + np.cos(ti) * np.cos(to)
    return np.rad2deg(np.arccos(np.clip(cos, -1, 1)))


_OFF_PEAK_DEG = 10.0
"""The retro-reflection group counts samples at least this far (half-vector angle α) from the peak."""


def _angle_lv_off_peak(pairs: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """The angle between L and V, NaN (no bin) within ``_OFF_PEAK_DEG`` of the specular peak
    (``alpha``: the pairs' half-vector angles)."""
    return np.where(alpha >= _OFF_PEAK_DEG, _angle_lv(*pairs.T), np.nan)


def _half_angle(ti: np.ndarray, pi: np.ndarray, to: np.ndarray, po: np.ndarray) -> np.ndarray:
    ti, pi, to, po = (np.deg2rad(a) for a in (ti, pi, to, po))
    hx = np.sin(ti) * np.cos(pi) + np.sin(to) * np.cos(po)
    hy = np.sin(ti) * np.sin(pi) + np.sin(to) * np.sin(po)
    hz = np.cos(ti) + np.cos(to)
    return np.rad2deg(np.arctan2(np.hypot(hx, hy), hz))


def _max_theta(pairs: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    return np.maximum(pairs[:, 0], pairs[:, 2])


def angle_lv_deg(data: Measurement) -> np.ndarray:
    """The angle between L and V of every sample, in degrees (0: exact retro-reflection)."""
    return _angle_lv(data.theta_i, data.phi_i, data.theta_o, data.phi_o)


def half_angle_deg(data: Measurement) -> np.ndarray:
    """The half-vector angle α (between N and H) of every sample, in degrees (0: the specular peak):
    computed per direction pair (``data.directions()``) and kept for the next measurement of the
    same pairs (files of one geometry fitted together share them)."""
    pairs, index = data.directions()
    return pair_half_angle_deg(pairs)[index]


def pair_half_angle_deg(pairs: np.ndarray) -> np.ndarray:
    """α (degrees) of every direction pair (D, 4), computed once per array (:func:`_recent`) and block by
    block (small temporaries): the residual groups and :func:`half_angle_deg` share it."""
    return _recent(pairs, "half-angle", lambda: np.concatenate([_half_angle(*pairs[i: i + _BLOCK].T) for i in range(0, len(pairs), _BLOCK)]
                                                               or [np.zeros(0)]))


_kept: list = []  # (direction pairs, what, values): the last few computed from a set of pairs
_KEPT = 8


def _recent(pairs: np.ndarray, what: str, compute: Callable[[], Any]) -> Any:
    """``compute()``, a function of the direction pairs ``pairs`` (read-only), or what it gave
    for this same array lately (the array itself, not an equal one, is what matches)."""
    for p, w, values in list(_kept):
        if p is pairs and w == what:
            return values
    values = compute()
    if not pairs.flags.writeable:  # an array that may change is never matched later
        _kept.append((pairs, what, values))
        del _kept[:-_KEPT]
    return values


_GROUPS = (
    ("angle between L and V (α ≥ 10°)", _angle_lv_off_peak, np.array([0, 2, 5, 10, 20, 40, 80, 180.0]), "retro-reflection"),
    ("half-vector angle α", lambda pairs, alpha: alpha, np.array([0, 2, 5, 10, 20, 40, 90.0]), "the specular peak"),
    ("max(θ_i, θ_o)", _max_theta, np.array([0, 30, 60, 75, 85, 90.0]), "grazing"),
)


def residual_structure(
    data: Measurement, model: np.ndarray, *, floor: float | None = None, threshold: float = 0.1, min_count: int = 20
) -> list[FitWarning]:
    """Plain-language warnings about systematic residual structure (empty when there is none).

    >>> import dataclasses, numpy as np, ctfit
    >>> paint = ctfit.Material(ctfit.Structure(lobes=1), ctfit.Params(s=np.asarray(0.3), m=np.array([0.2]), w=np.ones(1),
    ...                        f0=np.array([0.05])), wavelength_nm=np.array([550.0]))
    >>> data = ctfit.simulate(paint, n_pairs=2000, seed=1)
    >>> ctfit.residual_structure(data, ctfit.evaluate(paint, data))
    []
    >>> rough = dataclasses.replace(paint, params=dataclasses.replace(paint.params, m=np.array([0.3])))
    >>> ctfit.residual_structure(data, ctfit.evaluate(rough, data))  # a lobe too wide  # doctest: +ELLIPSIS
    ['systematic residuals: the model is ...% above the data for ...
    """
    y = np.asarray(data.brdf, dtype=float)
    if floor is None:
        floor = loss_floor(y, "relative")
    e = np.asarray(model, dtype=float) - y
    e /= np.maximum(np.abs(y), floor)
    pairs, index = data.directions()
    return residual_notes(pairs, e, y == 0, float(floor), y.size, index=index, threshold=threshold, min_count=min_count)


def residual_notes(pairs: np.ndarray, rel: np.ndarray, zero: np.ndarray, floor: float, samples: int, *, index: Any = None, mask: Any = None,
                   threshold: float = 0.1, min_count: int = 20) -> list[FitWarning]:
    """:func:`relative_residual_structure` over the samples (or measured cells, ``mask``) whose value
    is not exactly 0, and :func:`zero_samples_warning` of those that are (``zero``, in ``rel``'s
    shape; ``samples`` measured in all)."""
    if mask is None:
        notes = relative_residual_structure(pairs, rel[~zero], index=index[~zero], threshold=threshold, min_count=min_count)
    else:
        notes = relative_residual_structure(pairs, rel, mask=mask & ~zero, threshold=threshold, min_count=min_count)
    note = zero_samples_warning(rel[zero], floor, samples, threshold=threshold)
    return notes + ([note] if note else [])


ZERO_SAMPLES = "samples exactly 0"
"""The ``region`` of :func:`zero_samples_warning`'s warning."""

ZEROS_HINT = 0.05
"""Samples exactly 0, as a share of all, from which a fit says so: :func:`zero_samples_warning`
and, in a fit that fails, :func:`~ctfit._fitting.quality.zeros_hint`."""


def zero_samples_warning(rel: np.ndarray, floor: float, samples: int, *, threshold: float = 0.1) -> FitWarning | None:
    """One warning where at least :data:`ZEROS_HINT` of the ``samples`` are exactly 0 and the model
    is above them: ``rel`` the relative residuals of those samples (the model's value over the
    ``floor``), their median above ``threshold``. They are left out of the other bins
    (:func:`residual_structure`); this says how many, and what the model is there.

    >>> print(zero_samples_warning(np.full(150, 40.0), 0.01, 1000))  # doctest: +ELLIPSIS
    systematic residuals: 150 samples (15%) are exactly 0 where the model is not (median 0.4 sr⁻¹ there; left out of the other ...
    """
    rel = np.asarray(rel, dtype=float)
    if not rel.size or rel.size < ZEROS_HINT * samples:
        return None
    median = float(np.median(rel))
    if not median > threshold:
        return None
    return FitWarning(f"systematic residuals: {rel.size:,} samples ({rel.size / samples:.0%}) are exactly 0 where the model is not (median "
                      f"{median * floor:.3g} sr⁻¹ there; left out of the other residual checks): if those are values that were not measured, "
                      "leave them out of the file", "systematic_residuals", region=ZERO_SAMPLES)


def relative_residual_structure(
    pairs: np.ndarray, rel: np.ndarray, *, index: Any = None, mask: Any = None, threshold: float = 0.1,
    min_count: int = 20,
) -> list[FitWarning]:
    """:func:`residual_structure` from relative residuals: ``rel`` (N,) per sample with ``index``
    each sample's direction pair, or (D, W) per direction pair and band with ``mask`` (True where
    measured; other cells are ignored). ``pairs`` (D, 4): the direction pairs in degrees.

    The angular variables are computed once per direction pair and the bins' means and spreads
    are weighted counts, so a MERL-sized file costs a few passes over its samples."""
    rel = np.asarray(rel)
    per_sample = mask is None
    blocks = [slice(i, i + _BLOCK) for i in range(0, len(rel), _BLOCK)]  # rows at a time: small temporaries
    alpha = _recent(pairs, "alpha", lambda: pair_half_angle_deg(pairs))  # what two of the groups are made of
    out = []
    for name, variable, edges, place in _GROUPS:
        bins = len(edges) - 1

        def bin_of(x: np.ndarray) -> np.ndarray:  # NaN (a sample the group leaves out) → the extra bin ``bins``
            return np.where(np.isnan(x), bins, np.clip(np.digitize(x, edges) - 1, 0, bins - 1)).astype(np.int8)

        b = _recent(pairs, name, lambda: np.concatenate([bin_of(variable(pairs[s], alpha[s]))
                                                         for s in (slice(i, i + _BLOCK) for i in range(0, len(pairs), _BLOCK))] or [np.zeros(0, np.int8)]))
        if per_sample:
            b = b[index]
        bins += 1  # the bins' sums below include the left-out bin; it is never reported
        n, total, spread = np.zeros(bins), np.zeros(bins), np.zeros(bins)
        for s in blocks:
            n += np.bincount(b[s], minlength=bins) if per_sample else np.bincount(b[s], weights=np.sum(mask[s], axis=1), minlength=bins)
            total += np.bincount(b[s], weights=rel[s] if per_sample else np.sum(np.where(mask[s], rel[s], 0.0), axis=1), minlength=bins)
        mean = total / np.maximum(n, 1)
        for s in blocks:  # Σ (e − mean)²: a second pass, no cancellation
            dev = rel[s] - mean[b[s]] if per_sample else np.where(mask[s], rel[s] - mean[b[s]][:, None], 0.0)
            dev = dev.astype(float) ** 2
            spread += np.bincount(b[s], weights=dev if per_sample else np.sum(dev, axis=1), minlength=bins)
        se = np.sqrt(spread / np.maximum(n - 1, 1) / np.maximum(n, 1))
        worst = None
        for k in np.flatnonzero(n[:-1] >= min_count):
            if abs(mean[k]) > threshold and abs(mean[k]) > 4 * se[k] and (worst is None or abs(mean[k]) > abs(worst[0])):
                worst = (float(mean[k]), edges[k], edges[k + 1], int(n[k]))
        if worst is not None:
            mean_k, lo, hi, samples = worst
            side = "below" if mean_k < 0 else "above"
            span = f"[{lo:g}°, {hi:g}°" + ("]" if hi == edges[-1] else ")")  # the last bin holds its upper edge
            wide = edges[:-1] >= 20  # the bins far from retro-reflection: the level a lobe stands out from
            baseline = float(np.sum(total[:-1][wide]) / max(np.sum(n[:-1][wide]), 1))
            out.append(FitWarning(f"systematic residuals: the model is {abs(mean_k):.0%} {side} the data for {name} in {span} ({samples} samples)"
                                  f"{_explain(place, mean_k, lo, baseline - threshold)}", "systematic_residuals", region=f"{name} in {span}"))
    return out


_BLOCK = 1 << 16
"""Rows (samples or direction pairs) per block in :func:`relative_residual_structure`."""


def _explain(place: str, mean: float, lo: float, lobe_below: float) -> str:
    """Where a systematic residual points; a retro-reflection *lobe* only where the model's deficit
    near L = V stands out (below ``lobe_below``) from its level far from it."""
    if place == "retro-reflection" and mean < min(0.0, lobe_below) and lo < 10:
        return " — a retro-reflection lobe, which the Cook–Torrance model cannot represent"
    if (place == "the specular peak" and lo < 5) or (place == "grazing" and lo >= 75):
        return f" (near {place})"
    return ""
