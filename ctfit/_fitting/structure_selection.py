"""Which structure the data supports: nested candidates fitted in turn, the lowest BIC kept."""

from __future__ import annotations

import numpy as np

from .._model import Measurement, Params, Structure
from .least_squares import FitResult, fit
from .validate import n_free_parameters

__all__ = ["select_structure"]


def select_structure(
    data: Measurement, candidates: list[Structure], *, progress=None, **kwargs
) -> tuple[FitResult, list[tuple[Structure, FitResult]]]:
    """Fit each candidate structure and keep the one with the lowest BIC (Schwarz 1978).

    Candidates nest: a candidate that contains an earlier one (one lobe more, or a diffuse part
    added) also starts from that one's fit, embedded so that it gives the same model (the new
    lobe with weight 0, or s = 1), so its cost is never above the smaller candidate's.
    Candidates with more free parameters than the data has samples are left out (all of them
    too many: the first one's error). ``progress`` wraps the candidate loop (e.g. a progress
    bar); ``kwargs`` go to :func:`fit`.

    >>> import numpy as np, ctfit
    >>> gold = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None),
    ...                       ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.4, 0.9])),
    ...                       wavelength_nm=np.array([450.0, 650.0]))
    >>> data = ctfit.simulate(gold, n_pairs=300, noise=0.01, seed=1)
    >>> best, tried = ctfit.select_structure(data, [ctfit.Structure(lobes=j, diffuse=None) for j in (1, 2)])
    >>> best.material.structure.lobes, len(tried)
    (1, 2)
    """
    enough = [st for st in candidates if n_free_parameters(st, data.n_bands, kwargs.get("fixed", ())) <= len(data)]
    results: list[tuple[Structure, FitResult]] = []
    for st in (progress or (lambda it: it))(enough or candidates[:1]):
        inner = [r for sm, r in results if _contains(st, sm) and np.isfinite(r.stats["cost"])]
        start = None
        if inner and "start" not in kwargs:
            start = _embedded_start(min(inner, key=lambda r: r.stats["cost"]), st)
        results.append((st, fit(data, st, start=start, **kwargs)))
    ok = [(st, r) for st, r in results if np.isfinite(r.stats["bic"])]
    best = min(ok or results, key=lambda sr: sr[1].stats["bic"])[1]
    return best, results


def _contains(big: Structure, small: Structure) -> bool:
    """Whether ``small``'s models are ``big``'s with one lobe's weight 0 or with s = 1."""
    same = all(getattr(big, a) == getattr(small, a) for a in ("distribution", "geometry", "fresnel", "normalization"))
    one_more_lobe = big.lobes == small.lobes + 1 and big.diffuse == small.diffuse and small.lobes >= 1
    diffuse_added = big.lobes == small.lobes >= 1 and small.diffuse is None and big.diffuse is not None
    return same and (one_more_lobe or diffuse_added)


def _embedded_start(inner: FitResult, big: Structure) -> Params:
    """``inner``'s fitted parameters as a start of the larger structure ``big``, same model:
    the new lobe gets weight 0 and the slope of the m grid farthest (in log) from the fitted
    ones; a new diffuse part gets s = 1 (its R_d then starts at the default)."""
    p, small = inner.material.params, inner.material.structure
    m, w = np.asarray(p.m, dtype=float), np.asarray(p.w, dtype=float)
    if big.lobes > small.lobes:
        grid = np.geomspace(0.01, 0.8, 9)
        new = grid[np.argmax(np.min(np.abs(np.log(grid)[:, None] - np.log(m)[None, :]), axis=1))]
        m, w = np.append(m, new), np.append(w, 0.0)
    s = np.asarray(p.s) if small.has_s else (np.asarray(1.0) if big.has_s else None)
    return Params(s=s, m=m, w=w, f0=p.f0 if big.fresnel == "f0" else None, n=p.n if big.fresnel != "f0" else None, k=p.k, rd=p.rd)
