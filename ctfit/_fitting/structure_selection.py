"""Which structure the data supports: nested candidates fitted in turn, kept by BIC or, on large data, by their error on held-out pairs."""

from __future__ import annotations

import concurrent.futures
import dataclasses
import os
import queue
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._model import FAMILIES, GEOMETRIES, MAX_LOBES, Measurement, Params, Structure, brdf, n_from_f0, normal_reflectance, x64_enabled
from .least_squares import FitResult, check_fit_arguments, fit, fit_to_tolerance, prefetch_fit
from .losses import default_loss
from .problem import geometry_deg
from .quality import TAIL_LIMIT, errors_below_uncertainty
from .validate import check_data_scale, check_dtype, n_free_parameters

__all__ = ["select_structure", "choose_structure", "structure_label", "screening_sample", "heldout_sample", "heldout_errors", "model_errors",
           "model_median_error",
           "DIFFUSE_FORMS",
           "SCREEN_SAMPLES", "SCREEN_TOLERANCE", "HELDOUT_PAIRS", "CHOICE_GAIN", "TAIL_RATIO",
           "EXACT_ERROR"]


def select_structure(
    data: Measurement, candidates: list[Structure], *, progress: Callable[[Iterable], Iterable] | None = None, **kwargs: Any
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
    rd_freed = big.lobes == small.lobes >= 1 and small.diffuse == "F0/pi" and big.diffuse == "spectrum"  # R_d(λ) = F0(λ)/π is one R_d(λ)
    return same and big.family == small.family and (one_more_lobe or diffuse_added or rd_freed)


def _embedded_start(inner: FitResult, big: Structure) -> Params:
    """``inner``'s fitted parameters as a start of the larger structure ``big``, same model:
    the new lobe gets weight 0 and the slope of the m grid farthest (in log) from the fitted
    ones; a new diffuse part gets s = 1 (its R_d then starts at the default); a free R_d(λ) in
    place of R_d = F0/π starts at F0/π."""
    p, small = inner.material.params, inner.material.structure
    m, w = np.asarray(p.m, dtype=float), np.asarray(p.w, dtype=float)
    if big.lobes > small.lobes:
        grid = np.geomspace(0.01, 0.8, 9)
        new = grid[np.argmax(np.min(np.abs(np.log(grid)[:, None] - np.log(m)[None, :]), axis=1))]
        m, w = np.append(m, new), np.append(w, 0.0)
    s = np.asarray(p.s) if small.has_s else (np.asarray(1.0) if big.has_s else None)
    rd = np.asarray(p.f0, dtype=float) / np.pi if (small.diffuse == "F0/pi" and big.diffuse == "spectrum" and p.f0 is not None) else p.rd
    return Params(s=s, m=m, w=w, f0=p.f0 if big.fresnel == "f0" else None, n=p.n if big.fresnel != "f0" else None, k=p.k, rd=rd)


UNUSED_WEIGHT = 1e-6
"""A lobe of a larger candidate whose weight is below this is one it does not use (:func:`_fewer_lobes`)."""


def _fewer_lobes(res: FitResult, tried: list, fit_screen: Callable, better: Callable) -> tuple[Structure, FitResult] | None:
    """Where the candidate ``res``, chosen over one lobe fewer, leaves lobes unused (weight below
    :data:`UNUSED_WEIGHT`): the structure without them, solved from ``res``'s other lobes (its entry
    in ``tried`` replaced), when it is not worse (``better``). Then the larger one won by its extra
    steps, not its lobes: a one-lobe metal stopped at the candidates' step budget lost to a
    three-lobe one that reached the exact fit with two lobes of weight 0 and 7·10⁻¹⁸. Else None."""
    p, st = res.material.params, res.material.structure
    keep = np.asarray(p.w, dtype=float) >= UNUSED_WEIGHT
    if keep.all() or not keep.any():
        return None
    smaller = Structure(**{**st.__dict__, "lobes": int(keep.sum())})
    w = np.asarray(p.w, dtype=float)[keep]
    start = dataclasses.replace(p, m=np.asarray(p.m, dtype=float)[keep], w=w / w.sum())
    return _smaller_unless_worse(res, smaller, start, tried, fit_screen, better)


def _smaller_unless_worse(res: FitResult, smaller: Structure, start: Params, tried: list, fit_screen: Callable,
                          better: Callable) -> tuple[Structure, FitResult] | None:
    """``smaller`` (a structure without a part ``res`` does not use) solved from ``start`` alone,
    and its fit, in place of ``res`` unless ``res`` is better; its entry in ``tried`` replaced (or
    added). Else None."""
    again = fit_screen(smaller, start, False)
    if better(res, again):
        return None
    for i, (st_tried, _) in enumerate(tried):
        if st_tried == smaller:
            tried[i] = (smaller, again)
            break
    else:
        tried.append((smaller, again))
    return smaller, again


def _without_unused_diffuse(res: FitResult, tried: list, fit_screen: Callable, better: Callable) -> tuple[Structure, FitResult] | None:
    """Where the candidate ``res`` has a diffuse part it does not use (d = 1 − s below
    :data:`UNUSED_WEIGHT`) and its family allows none (:data:`DIFFUSE_FORMS`): the structure
    without it, solved from ``res``'s lobes and Fresnel parameters (its entry in ``tried`` added or
    replaced), when it is not worse (``better``). Else None. On a copper that ``ctfit simulate``
    made without noise, a free R_d(λ) at s = 1 (the model of no diffuse part, 62 more parameters)
    was chosen by 0.1 point of held-out median (the lobe solved from elsewhere); fitted to all the
    data, s slid to 1 − 3·10⁻⁷ and R_d(λ) to 0.55, which the loss does not see (10⁻⁷ sr⁻¹ below
    its floor) but its tenth of samples deep in the Beckmann tail does: "the Cook–Torrance model
    does not represent this material", for data it made."""
    p, st = res.material.params, res.material.structure
    if not st.has_s or p.s is None or None not in DIFFUSE_FORMS.get(st.family, ()) or 1.0 - float(p.s) >= UNUSED_WEIGHT:
        return None
    smaller = Structure(**{**st.__dict__, "diffuse": None})
    return _smaller_unless_worse(res, smaller, _lobes_start(res, smaller), tried, fit_screen, better)


def _lobes_start(res: FitResult, other: Structure, own: FitResult | None = None) -> Params:
    """``res``'s lobes, s and Fresnel parameters as a start of ``other`` (same family and lobe
    count, another diffuse part or Fresnel form: a metal's F0(λ) from its n(λ), k(λ), or its n(λ)
    the effective index of its F0(λ) with k = 0); what ``other`` needs beyond them starts at the
    defaults. ``own``: a fit of ``other``'s form with other lobes, whose Fresnel parameters, s and
    R_d are taken instead."""
    p, st = res.material.params, res.material.structure
    if own is not None and np.isfinite(own.stats.get("cost", np.inf)):
        q = own.material.params
        return Params(s=q.s, m=np.asarray(p.m, dtype=float), w=np.asarray(p.w, dtype=float), f0=q.f0, n=q.n, k=q.k, rd=q.rd)
    s = np.asarray(p.s) if (other.has_s and st.has_s) else None
    rd = p.rd if (other.has_rd and st.has_rd) else None
    f0, n, k = p.f0, p.n, p.k
    if other.fresnel == "f0" and f0 is None and n is not None:
        f0 = np.asarray(normal_reflectance(st, p), dtype=float)
    if other.fresnel == "conductor" and n is None and f0 is not None:
        n, k = n_from_f0(np.clip(np.asarray(f0, dtype=float), 0.0, 0.999)), np.zeros(np.shape(f0))
    return Params(s=s, m=np.asarray(p.m, dtype=float), w=np.asarray(p.w, dtype=float), f0=f0 if other.fresnel == "f0" else None,
                  n=n if other.fresnel != "f0" else None, k=k if other.fresnel == "conductor" else None, rd=rd)


SCREEN_SAMPLES = 4096
"""Above about this many samples, the data-chosen default compares its candidates on a random
subset of the direction pairs holding about this many (:func:`screening_sample`), then fits the
structure chosen to all the data: the choice costs a fraction of the fits on the whole file."""
SCREEN_TOLERANCE = 3e-4
"""The candidates fitted to a screening sample stop (and count as converged) where one more
Gauss–Newton step promises less than this relative decrease of their cost. It saves the slow
tails of the fits (:func:`~ctfit._fitting.least_squares.fit_to_tolerance`): on the test-bed
(docs/real-materials.md) 20–38 % of the default's solver steps against 10⁻⁵, with the same
choice and the same final fit on every file. The candidates are compared on held-out pairs,
whose medians moved by 0.1–1 % (up to 5 % for a candidate far from the choice) between the
two: the choice is then fitted to all the data at full tolerance."""
DEFAULT_FAMILIES = ("metal", "plastic")
"""The families the data-chosen default tries (:data:`~ctfit.FAMILIES`)."""
DEFAULT_LOBES = (1, 2, 3)
"""The lobe counts the data-chosen default tries."""
DIFFUSE_FORMS = {"metal": (None, "F0/pi", "spectrum"), "plastic": ("spectrum", "transmitted")}
"""The diffuse parts each family tries: a metal without one, with the paper's R_d = F0/π or with
its own R_d(λ) (a strong, coloured specular part over a diffuse one: sheen of fabric, metallic
paint); a plastic with its own R_d(λ), Lambertian or seen through its interface. A metal is tried
with the paper's effective index (F0(λ), k = 0) in each of these, and, without a diffuse part, with
its own n(λ) and k(λ) too (the exact conductor Fresnel: ``choose_structure``'s ``fresnel``)."""


def structure_label(st: Structure) -> str:
    """A short name of a structure, as the structure-choice table prints it.

    >>> import ctfit
    >>> ctfit.structure_label(ctfit.Structure(family="plastic", lobes=2, diffuse="transmitted"))
    'plastic, 2 lobes, diffuse transmitted'
    """
    parts = [st.family, f"{st.lobes} lobe{'s' if st.lobes != 1 else ''}"]
    if st.fresnel == "conductor":
        parts.append("conductor")
    parts.append(f"diffuse {st.diffuse}" if st.diffuse else "no diffuse")
    return ", ".join(parts)


def choose_structure(
    data: Measurement, *, families: Sequence[str] = DEFAULT_FAMILIES, lobes: Sequence[int] = DEFAULT_LOBES, diffuse: Sequence[str | None] | None = None,
    geometry: str = "v-cavity", fresnel: str | None = None, progress: Callable[[Iterable], Iterable] | None = None, **kwargs: Any,
) -> tuple[FitResult, list[tuple[Structure, FitResult]]]:
    """The data-chosen default structure: family × diffuse part × lobe count, by BIC or, on large
    data, by the median relative error on held-out direction pairs.

    Every (family, diffuse part) of ``families`` (:data:`DIFFUSE_FORMS`, or the one ``diffuse`` given) is
    fitted with the fewest ``lobes``; the one preferred (:func:`_better`) then gets more lobes in turn
    (nested starts, :func:`select_structure`) while that improves; if it got more, the family's other diffuse
    parts are fitted with as many lobes too (from its lobes: a diffuse part chosen at one lobe may have
    stood in for a second lobe). Fits of one measurement in one loss, so their BICs compare. A candidate
    with more free parameters than samples is not tried. A candidate with one lobe more is solved from the
    smaller one's fit and from the grid seeds (``starts``: where its new lobe goes is open); one that only
    adds or changes the diffuse part, from the smaller one's fit alone (its lobes are placed). Data of more
    than :data:`SCREEN_SAMPLES` samples is screened: the candidates are fitted to a random subset of its
    direction pairs and compared by their median relative error on other pairs (:func:`heldout_sample`,
    :func:`heldout_errors`; their BICs scaled to the whole data for the table;
    ``stats["structure_screening"]`` the sizes). The candidates are fitted without the report
    (``report=False``: no standard errors, residual summary or warnings; their ``quality`` holds the
    median relative error and its 90th percentile alone; the choice: :func:`_better`), each seed
    :data:`CANDIDATE_STEPS` steps at most (solved on where that could change the choice: :class:`_Candidates`);
    the structure chosen is then fitted to all the data, with the report, from its candidate's fit.
    ``fresnel``: a metal's Fresnel form, "f0" (the paper's effective index)
    or "conductor" (its own n, k) in every candidate; None (default): "f0" in each diffuse form and
    "conductor" without a diffuse part as well. Returns the best fit and every
    (structure, fit) tried, in order.

    >>> import numpy as np, ctfit
    >>> params = ctfit.Params(s=np.asarray(0.4), m=np.array([0.3]), w=np.ones(1), n=np.full(2, 1.52), rd=np.array([0.019, 0.022]))  # the paper's
    >>> rubber = ctfit.Material(ctfit.Structure(family="plastic", diffuse="spectrum"), params, wavelength_nm=np.array([450.0, 650.0]))  # plastic
    >>> data = ctfit.simulate(rubber, n_pairs=600, noise=0.01, seed=1)
    >>> best, tried = ctfit.choose_structure(data, lobes=(1, 2))
    >>> best.material.structure.family, best.material.structure.lobes
    ('plastic', 1)
    """
    combos = _first_combos(data, families, lobes, diffuse, geometry, fresnel, kwargs)
    screen, held, n_full = screening_sample(data), heldout_sample(data), len(data)
    tolerance = SCREEN_TOLERANCE if screen is not data else None
    user_start = kwargs.pop("start", None)
    given = user_start is None  # the choice gives nested starts unless the caller gave a start
    tried: list[tuple[Structure, FitResult]] = []
    candidates = _Candidates(screen, held, n_full, tolerance, kwargs)

    def fit_screen(st: Structure, start: Params | None, seeded: bool = True) -> FitResult:
        return candidates.fit(st, start if given else user_start, given and not seeded)

    def fit_tried(st: Structure, start: Params | None, seeded: bool = True) -> FitResult:
        tried.append((st, fit_screen(st, start, seeded)))
        return tried[-1][1]

    better = candidates.better

    # Each stage's later fits have their programs made (loaded or compiled) in the background
    # while its earlier fits run (:func:`~ctfit._fitting.least_squares.prefetch_fit`).
    with concurrent.futures.ThreadPoolExecutor(2) as background:
        ahead = lambda st, seeded=True: background.submit(prefetch_fit, screen, st, given_start=True,
                                                          **_seeding(kwargs, given and not seeded))
        tried.extend(_first_stage(combos, fit_screen, background, screen, given, kwargs, progress))
        best_st, best = _preferred(tried, better)
        for i, j in enumerate(lobes[1:], start=2):
            bigger = Structure(**{**best_st.__dict__, "lobes": j})
            if n_free_parameters(bigger, data.n_bands, kwargs.get("fixed", ())) > len(data):  # none determines them (_first_combos)
                break
            if i < len(lobes):
                ahead(Structure(**{**best_st.__dict__, "lobes": lobes[i]}))
            res = fit_tried(bigger, _embedded_start(best, bigger))
            if not better(res, best):
                break
            best_st, best = _fewer_lobes(res, tried, fit_screen, better) or (bigger, res)  # unused lobes: the smaller one, solved on
            if best_st is not bigger:
                break
        if best_st.lobes > lobes[0]:  # the other diffuse forms of the family, at the lobe count chosen
            best_st, best = _other_diffuse_parts(combos, best_st, best, fit_tried, ahead, better, tried)
        if diffuse in (None, "auto"):  # a diffuse part at d = 0: the structure without it
            best_st, best = _without_unused_diffuse(best, tried, fit_screen, better) or (best_st, best)
    return _fitted_to_all(data, best_st, best, tried, screen, held, user_start, kwargs), tried


def _fitted_to_all(data: Measurement, best_st: Structure, best: FitResult, tried: list, screen: Measurement, held: Measurement | None,
                   user_start: Params | None, kwargs: dict) -> FitResult:
    """The structure chosen, ``best_st``, fitted to all of ``data`` (with the report) from its
    candidate's fit ``best`` (from ``user_start`` where that found nothing), with the choice's
    table and screening sizes in its stats."""
    table = choice_table(tried, best, len(data))
    criterion = "held-out median relative error" if held is not None else "BIC"
    found = np.isfinite(best.stats["cost"])
    res = fit_to_tolerance(data, best_st, start=best.material.params if found else user_start, **_seeding(kwargs, bool(found)))
    res.stats["structure_choice"] = table
    res.stats["structure_screening"] = {"samples": len(screen), "of": len(data), "criterion": criterion,
                                        "heldout_samples": 0 if held is None else len(held)}
    return res


def _other_diffuse_parts(
    combos: list[Structure], chosen_st: Structure, chosen: FitResult, fit_screen: Callable[..., FitResult], ahead: Any, better: Callable[..., bool],
    tried: list[tuple[Structure, FitResult]],
) -> tuple[Structure, FitResult]:
    """The family's other diffuse parts (and Fresnel forms) of ``combos`` at ``chosen_st``'s lobe
    count, each from ``chosen``'s lobes alone, and of another Fresnel form from its other parameters
    in its own first-stage fit in ``tried`` and from the grid's seeds (programs made ``ahead``); the
    (structure, fit) ``better`` keeps. A conductor started from a 2-lobe effective-index fit (n the
    effective index, k = 0: the same F0, another angular Fresnel) crawled 256 steps on noise-free
    copper and ended unconverged at a median of 0.44 %; from its own one-lobe n(λ), k(λ) it is
    exact, but from there alone, with noise, it crawled along the valley of the n and k that give
    one F0: the fit of ``configs/copper-vase-conductor.toml`` (2 % noise) chosen from there read
    "converged" at 9× the cost that the grid's seeds reach in 4 steps."""
    best_st, best = chosen_st, chosen
    others = [Structure(**{**st.__dict__, "lobes": chosen_st.lobes}) for st in combos
              if st.family == chosen_st.family and (st.diffuse, st.fresnel) != (chosen_st.diffuse, chosen_st.fresnel)]
    first = {st: res for st, res in tried if st.lobes == tried[0][0].lobes}  # the first stage's fits
    owns = [first.get(Structure(**{**other.__dict__, "lobes": tried[0][0].lobes})) if other.fresnel != chosen_st.fresnel else None for other in others]
    for other, own in list(zip(others, owns))[1:]:
        ahead(other, seeded=own is not None)
    for other, own in zip(others, owns):
        res = fit_screen(other, _lobes_start(chosen, other, own), seeded=own is not None)
        if better(res, best):
            best_st, best = other, res
    return best_st, best


def _check_choice_arguments(data: Any, families: Any, lobes: Any, diffuse: Any, geometry: Any, fresnel: Any) -> None:
    """A ``TypeError`` or ``ValueError`` naming the argument of :func:`choose_structure` that is
    wrong: data that is not a Measurement raised AttributeError, ``lobes=0`` "'int' object is not
    subscriptable", ``families=("glass",)`` KeyError, ``geometry="x"`` blamed the diffuse part and
    ``fresnel="x"`` was ignored."""
    check_fit_arguments(data, None)
    for name, given, allowed in (("families", families, FAMILIES), ("lobes", lobes, range(1, MAX_LOBES + 1))):
        if isinstance(given, (str, bytes)) or np.ndim(given) != 1 or not len(given):
            raise TypeError(f"{name} must be a non-empty sequence, e.g. {(allowed[0],)!r}, got {given!r}")
        bad = [v for v in given if isinstance(v, bool) or v not in allowed]
        if bad:
            raise ValueError(f"{name} must be taken from {list(allowed) if name == 'families' else f'1..{MAX_LOBES}'}, got {bad[0]!r}")
    if list(lobes) != sorted(set(lobes)):
        raise ValueError(f"lobes must increase (the counts are tried in turn while each improves the fit), got {list(lobes)}")
    forms = (None, "auto", "none", "F0/pi", "spectrum", "constant", "transmitted")
    for name, value, allowed in (("diffuse", diffuse, forms), ("geometry", geometry, GEOMETRIES), ("fresnel", fresnel, (None, "f0", "conductor"))):
        if not isinstance(value, (str, type(None))) or value not in allowed:
            raise ValueError(f"{name} must be one of {list(allowed)}, got {value!r}")


def _first_combos(
    data: Measurement, families: Sequence[str], lobes: Sequence[int], diffuse: Sequence[str | None] | None, geometry: str, fresnel: str | None,
    options: dict,
) -> list[Structure]:
    """Every (family, diffuse part) of ``families`` (:data:`DIFFUSE_FORMS`, or the one ``diffuse``
    given) with the first of ``lobes`` lobes, those with more free parameters than ``data`` has samples left out
    (all of them too many: the first, whose fit's error says so); the arguments checked first, and the data's
    scale in the fits' ``options`` (loss, dtype) on all of it: a value refused by a screening sample's fit
    was named by its row of that sample, not of the data (row 3397 for line 5003 of the file)."""
    _check_choice_arguments(data, families, lobes, diffuse, geometry, fresnel)
    fixed = options.get("fixed", ())
    if data.brdf is not None:
        dtype, loss = options.get("dtype", jnp.float64), options.get("loss", "auto")
        check_dtype(dtype)
        check_data_scale(data, loss=default_loss(data) if loss == "auto" else loss, dtype=dtype)
    combos = []
    for family in families:
        for form in DIFFUSE_FORMS[family] if diffuse in (None, "auto") else (diffuse,):
            try:
                combos.append(Structure(lobes=lobes[0], geometry=geometry, fresnel=(fresnel or "f0") if family == "metal" else "n",
                                        diffuse=None if form == "none" else form, family=family))
            except ValueError:
                continue  # a diffuse part this family has not (e.g. "F0/pi" for a plastic)
        if family == "metal" and fresnel is None and diffuse in (None, "auto", "none"):  # a metal of its own n(λ), k(λ)
            combos.append(Structure(lobes=lobes[0], geometry=geometry, fresnel="conductor", diffuse=None, family=family))
    if not combos:
        raise ValueError(f"no structure of families {tuple(families)} has diffuse part {diffuse!r}")
    return [st for st in combos if n_free_parameters(st, data.n_bands, fixed) <= len(data)] or combos[:1]


def _first_stage(
    combos: list[Structure], fit_screen: Callable[..., FitResult], background: Any, screen: Any, given: bool, kwargs: dict, progress: Any
) -> list[tuple[Structure, FitResult]]:
    """Fit every (family, diffuse part) combination with the fewest lobes, each that contains an
    earlier one from that one's fit (:func:`_chains`: such combinations are fitted in turn, the
    chains side by side in threads); the programs of the later ones made in ``background``
    meanwhile. Returns every (structure, fit), in the order of ``combos``."""
    for i, st in enumerate(combos):
        nested = any(_contains(st, sm) for sm in combos[:i])
        if i > 0:
            background.submit(prefetch_fit, screen, st, given_start=not given or nested, **_seeding(kwargs, given and nested))
    finished: queue.Queue = queue.Queue()

    def chain(indices: list[int]) -> dict[int, FitResult]:
        fits: dict[int, FitResult] = {}
        try:
            for i in indices:
                st = combos[i]
                inner = [r for j, r in fits.items() if _contains(st, combos[j]) and np.isfinite(r.stats["cost"])]
                start = _embedded_start(min(inner, key=lambda r: r.stats["cost"]), st) if inner else None
                fits[i] = fit_screen(st, start, seeded=start is None)
                finished.put(i)
        finally:
            for i in indices[len(fits):]:
                finished.put(i)  # a chain that failed: the progress below still ends
        return fits

    chains = _chains(combos)
    with concurrent.futures.ThreadPoolExecutor(max(1, min(len(chains), os.cpu_count() or 1))) as pool:
        running = [pool.submit(chain, c) for c in chains]
        for _ in (progress or (lambda it: it))(finished.get() for _ in combos):
            pass
        fits = {i: r for f in running for i, r in f.result().items()}
    return [(st, fits[i]) for i, st in enumerate(combos)]


def _preferred(fits: list[tuple[Structure, FitResult]], better: Callable[..., bool]) -> tuple[Structure, FitResult]:
    """The (structure, fit) of ``fits`` that ``better`` keeps, taken in their order."""
    best = fits[0]
    for st, res in fits[1:]:
        if better(res, best[1]):
            best = (st, res)
    return best


def _chains(combos: list[Structure]) -> list[list[int]]:
    """The indices of ``combos`` in chains: a combination that contains earlier ones
    (:func:`_contains`) joins their chain (fitted after them, from their fits); the others start
    chains of their own, which need nothing from each other.

    >>> import ctfit
    >>> _chains([ctfit.Structure(diffuse=d) for d in (None, "F0/pi", "spectrum")]
    ...         + [ctfit.Structure(family="plastic", diffuse=d) for d in ("spectrum", "transmitted")])
    [[0, 1, 2], [3], [4]]
    """
    chains: list[list[int]] = []
    for i, st in enumerate(combos):
        homes = [c for c in chains if any(_contains(st, combos[j]) for j in c)]
        chains = [c for c in chains if c not in homes] + [sorted(j for c in homes for j in c) + [i]]  # chains it joins become one
    return sorted(chains)


def _seeding(kwargs: dict, start_only: bool) -> dict:
    """``kwargs`` of a fit; ``start_only``: solved from its start alone (``starts=0``: no grid seeds)."""
    return dict(kwargs, starts=0) if start_only else kwargs


HELDOUT_PAIRS = 2048
"""Screened data: the candidates are compared on up to this many direction pairs that the
screening sample left out (:func:`heldout_sample`), every band of each."""
CHOICE_GAIN = 0.02
"""Compared on held-out pairs, a candidate with more parameters is chosen over one with fewer only
if its median relative error there is lower by more than this fraction; one with fewer only
if not higher by more than it (:func:`_better`)."""
TAIL_RATIO = 2.0
"""A candidate whose 90th-percentile relative error (on the held-out pairs, or where not screened
on the samples fitted) is above :data:`~ctfit._fitting.quality.TAIL_LIMIT` — a tenth of the
samples off by 90 % or more, the quality warning's test — and more than this many times the
other's loses, whatever the BICs or the medians (:func:`_tail_verdict`). The BIC (of the
robust-relative loss, whose floor makes samples far below the typical one nearly free) and the
median do not see the worst tenth: on a copper that ``ctfit simulate`` made without noise
(4 bands, 3,000 samples), a free R_d(λ) was chosen, its tenth of the samples deep in the Beckmann
tail (10⁻³⁰ of the peak) off by 5·10⁵ %, and the fit of data the model itself made read "the
Cook–Torrance model does not represent this material"."""


CANDIDATE_STEPS = 32
"""Levenberg–Marquardt steps each seed of a candidate of the data-chosen default gets before the
candidates are compared (``max_steps`` if fewer; the solver "lm" only). A candidate stopped
there is solved on, from where it stopped and up to ``max_steps`` in all, only where that could
change a comparison (:class:`_Candidates`): most never need more, but one that cannot describe
the data may crawl for hundreds of steps (a plastic on a metal's data: its index at its bound,
s → 1 while R_d grows, 737 steps to converge to a cost twice the metal's). 32 and 24 made the
same choices as 64 on the test-bed and on 16 metal files; 16 did not (docs/fitting.md)."""
CANDIDATE_REACH = (2.0, 0.1)
"""How much lower a candidate stopped at :data:`CANDIDATE_STEPS` is taken to be able to end
(:func:`_reach`): this multiple of the relative decrease one more Gauss–Newton step promises
(``gauss_newton_decrease``), and this fraction of its cost at least."""


def _reach(res: FitResult) -> FitResult:
    """``res``, a fit stopped at its step budget, as it might end if solved on: its cost lower by
    the fraction :data:`CANDIDATE_REACH` gives (at most, and where the promise is not finite,
    99.9 %), its BIC and held-out median relative error with it (the error taken ∝ √cost). A
    stand-in for comparisons only."""
    s = res.stats
    factor, least = CANDIDATE_REACH
    promise = float(s["gauss_newton_decrease"])
    x = min(max(factor * promise, least), 0.999) if np.isfinite(promise) else 0.999  # no promise known: the most
    n = max(int(s["n_samples"]), 1)
    bic = s["bic"] - 2 * s["cost"] * x if s["loss"] == "sigma" else s["bic"] + n * np.log1p(-x)
    stats = s.copy()
    stats["cost"], stats["bic"] = s["cost"] * (1 - x), bic
    for key in ("heldout_median_relative_error", "heldout_p90_relative_error"):
        if key in s:
            stats[key] = s[key] * np.sqrt(1 - x)
    if "quality" in s:
        stats["quality"] = {k: v * np.sqrt(1 - x) for k, v in s["quality"].items()}
    return dataclasses.replace(res, stats=stats)


class _Candidates:
    """The data-chosen default's candidates, fitted to the screening sample without the report,
    each seed :data:`CANDIDATE_STEPS` steps at most, and compared (:meth:`better`). A candidate
    stopped at that budget is solved on where its :func:`_reach` would change a comparison; one
    that loses even so keeps its fit as it stopped (``fit_status`` "max_steps" in the table)."""

    def __init__(self, screen: Measurement, held: Measurement | None, n_full: int, tolerance: float | None, kwargs: dict):
        self.screen, self.held, self.n_full, self.tolerance, self.kwargs = screen, held, n_full, tolerance, kwargs
        self.max_steps = int(kwargs.get("max_steps", 256))
        # Levenberg–Marquardt on chunks takes its step limit at run time; the other solvers' one
        # program is compiled per limit, so they keep theirs (a budget would compile two more)
        self.budget = min(CANDIDATE_STEPS, self.max_steps) if kwargs.get("solver", "lm") == "lm" else self.max_steps
        self.solved_on: set[int] = set()  # id() of the fits solved on past the budget

    def fit(self, st: Structure, start: Params | None, start_only: bool) -> FitResult:
        """``st`` fitted from ``start`` (``start_only``: from it alone, else with the grid's seeds)."""
        res = fit_to_tolerance(self.screen, st, start=start, tolerance=self.tolerance, report=False,
                               **dict(_seeding(self.kwargs, start_only), max_steps=self.budget))
        return self._judged(res)

    def _judged(self, res: FitResult) -> FitResult:
        median, tail = model_errors(res, self.screen)
        res.stats["quality"] = {"median_relative_error": median, "p90_relative_error": tail}
        if self.held is not None:
            res.stats["heldout_median_relative_error"], res.stats["heldout_p90_relative_error"] = heldout_errors(res, self.held)
        return res

    def stopped(self, res: FitResult) -> bool:
        """Whether ``res`` stopped at the budget, short of ``max_steps``, and was not solved on: its
        best seed took every step of the budget, unconverged ("max_steps") or judged converged by a
        loose stationarity test (float32's 10⁻³: a two-lobe candidate so stopped 1.2 % above its
        minimum, and a third lobe was chosen over it)."""
        return int(res.stats["steps"]) >= self.budget and self.budget < self.max_steps and id(res) not in self.solved_on

    def solve_on(self, res: FitResult) -> None:
        """``res`` solved on from where it stopped (its seed alone), up to ``max_steps`` steps in
        all; ``res`` becomes that fit (its steps and time those of both)."""
        more = fit_to_tolerance(self.screen, res.material.structure, start=res.material.params, tolerance=self.tolerance, report=False,
                                **dict(_seeding(self.kwargs, True), max_steps=self.max_steps - self.budget))
        more = self._judged(more)
        more.stats["steps"] += res.stats["steps"]
        more.stats["time_s"] += res.stats["time_s"]
        for f in dataclasses.fields(res):
            setattr(res, f.name, getattr(more, f.name))
        self.solved_on.add(id(res))

    def better(self, new: FitResult, old: FitResult) -> bool:
        """:func:`_better`, each fit stopped at the budget first solved on where its :func:`_reach`
        would give the other verdict."""
        heldout = self.held is not None
        while True:
            verdict = _better(new, old, self.n_full, heldout)
            if not verdict and self.stopped(new) and _better(_reach(new), old, self.n_full, heldout):
                self.solve_on(new)
            elif verdict and self.stopped(old) and not _better(new, _reach(old), self.n_full, heldout):
                self.solve_on(old)
            else:
                return verdict


def _better(new: FitResult, old: FitResult, n_full: int, heldout: bool) -> bool:
    """Whether ``new`` is chosen over ``old``: the lower BIC (scaled to ``n_full`` samples), or with
    ``heldout`` the lower median relative error on the held-out pairs, more parameters having to
    gain :data:`CHOICE_GAIN` of it and fewer allowed to lose as much; either way, where one's
    worst tenth is far off and far worse than the other's, the other (:func:`_tail_verdict`)."""
    tail = _tail_verdict(new, old, heldout)
    if tail is not None:
        return tail
    if not heldout:
        return _full_bic(new, n_full) < _full_bic(old, n_full)
    a, b = (max(r.stats.get("heldout_median_relative_error", np.inf), _exact_error(r)) for r in (new, old))
    if not np.isfinite(a):
        return False
    if not np.isfinite(b):
        return True
    more = int(new.stats["n_params"]) - int(old.stats["n_params"])
    return a < b * (1 - CHOICE_GAIN) if more > 0 else a < b * (1 + CHOICE_GAIN) if more < 0 else a < b


EXACT_ERROR = 1e4
"""A held-out median relative error below this many times the fit's machine epsilon (2·10⁻¹² in
float64, 10⁻³ in float32, where the stationarity test's tolerance is 10⁻³) is an exact fit's, and
compares as that: exact candidates tie, and the one with fewer parameters is chosen (the BIC's
rule for a cost at rounding, ``least_squares._bic``). Noise-free copper: a second conductor lobe
"gained" 4 % on a held-out median of 4.9·10⁻¹⁴ (rounding) and was chosen."""


def _exact_error(res: FitResult) -> float:
    """:data:`EXACT_ERROR` × the machine epsilon of ``res``'s dtype."""
    return EXACT_ERROR * float(np.finfo(res.stats.get("dtype", "float64")).eps)


def _tail(res: FitResult, heldout: bool) -> float:
    """``res``'s 90th-percentile relative error on the held-out pairs (``heldout``) or on the
    samples it was fitted to; NaN where not known."""
    s = res.stats
    return float(s.get("heldout_p90_relative_error", np.nan) if heldout else s.get("quality", {}).get("p90_relative_error", np.nan))


def _tail_verdict(new: FitResult, old: FitResult, heldout: bool) -> bool | None:
    """True (``new``) or False (``old``) where one candidate's 90th-percentile relative error
    (:func:`_tail`) is above :data:`~ctfit._fitting.quality.TAIL_LIMIT` (the quality warning's)
    and more than :data:`TAIL_RATIO` times the other's; None where neither is, or one is unknown."""
    a, b = _tail(new, heldout), _tail(old, heldout)
    if not (np.isfinite(a) and np.isfinite(b)):
        return None
    if b > TAIL_LIMIT and b > TAIL_RATIO * a:
        return True
    if a > TAIL_LIMIT and a > TAIL_RATIO * b:
        return False
    return None


def _samples_of_pairs(data: Measurement, index: np.ndarray, kept: np.ndarray) -> Measurement:
    """The samples of ``data`` whose direction pair (``index``, :meth:`~ctfit.Measurement.directions`'s) is in ``kept``."""
    keep = np.isin(index, kept)
    fields = ("theta_i", "phi_i", "theta_o", "phi_o", "band", "brdf") + (("sigma",) if data.sigma is not None else ())
    return data.replace(**{k: np.asarray(getattr(data, k))[keep] for k in fields})


def _screening_pairs(data: Measurement, samples: int) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(direction pairs, each sample's pair, the pairs of the screening sample or None: all)."""
    pairs, index = data.directions()
    if len(data) <= samples or len(pairs) < 2:
        return pairs, index, None
    n_pairs = max(1, min(len(pairs), int(len(pairs) * samples // len(data))))  # at most ``samples``: whole chunks
    return pairs, index, np.random.default_rng(0).choice(len(pairs), n_pairs, replace=False)


def heldout_sample(data: Measurement, samples: int = SCREEN_SAMPLES, pairs: int = HELDOUT_PAIRS) -> Measurement | None:
    """The samples of up to ``pairs`` direction pairs (seed 1) that the screening sample of
    ``data`` (:func:`screening_sample`) left out: where screened candidates are compared, each by the
    median relative error of its model there (:func:`heldout_errors`). None for data that is not screened."""
    all_pairs, index, chosen = _screening_pairs(data, samples)
    if chosen is None:
        return None
    rest = np.setdiff1d(np.arange(len(all_pairs)), chosen)
    if len(rest) == 0:
        return None
    if len(rest) > pairs:
        rest = np.random.default_rng(1).choice(rest, pairs, replace=False)
    return _samples_of_pairs(data, index, rest)


def heldout_errors(res: FitResult, held: Measurement) -> tuple[float, float]:
    """The median and 90th-percentile relative error of ``res`` on the held-out samples ``held`` (:func:`model_errors`)."""
    return model_errors(res, held)


def model_median_error(res: FitResult, data: Measurement) -> float:
    """The median of :func:`model_errors`."""
    return model_errors(res, data)[0]


def model_errors(res: FitResult, data: Measurement) -> tuple[float, float]:
    """The median and the 90th percentile over the samples of ``data`` with y > 0 of |f − y| / y
    (a value below its uncertainty σ: left out, or |f − y|/σ,
    :func:`~ctfit._fitting.quality.errors_below_uncertainty`), f the model of ``res`` (both ∞
    where f is not finite somewhere), evaluated on the host (``brdf(..., xp=numpy)``: no program
    per structure) in the dtype of the fit's programs (float64 with ``jax_enable_x64``, else
    float32), at the geometry the fits lay out (``problem.geometry_deg``: the screen's pairs are
    those every candidate was fitted to, and their geometry is kept). ``data`` is a screening or
    held-out sample: a few thousand pairs."""
    pairs, index = data.directions()
    dt = np.float64 if x64_enabled() else np.float32
    params = jax.tree.map(lambda a: np.asarray(a, dtype=dt), res.material.params)
    with np.errstate(all="ignore"):  # the guards' unselected branches (double-where), as in JAX
        values = brdf(res.material.structure, params, geometry_deg(np.asarray(pairs, dtype=dt), on_host=True), xp=np)
    f, y = values[index, np.asarray(data.band)], np.asarray(data.brdf, dtype=float)
    ok = y > 0
    if not ok.any() or not np.all(np.isfinite(f[ok])):  # a model that is not finite somewhere is no candidate
        return np.inf, np.inf
    with np.errstate(over="ignore"):  # a finite model over a y near 0 (1e-310) is an infinite error: one sample, not the median
        err = np.abs(f[ok] - y[ok]) / y[ok]
    errors_below_uncertainty(err, y[ok], None if data.sigma is None else np.asarray(data.sigma)[ok])
    err = err[~np.isnan(err)]
    if not err.size:
        return np.inf, np.inf
    return float(np.median(err)), float(np.quantile(err, 0.9))


def screening_sample(data: Measurement, samples: int = SCREEN_SAMPLES) -> Measurement:
    """The data the candidates are compared on: all of it up to about ``samples`` samples, else
    the samples of a random subset of its direction pairs (every band of a pair kept; seed 0, so
    the choice is reproducible) holding at most about ``samples`` (a power of two: whole chunks
    of the fit's programs, no chunk of padding)."""
    _, index, chosen = _screening_pairs(data, samples)
    if chosen is None:
        return data
    return _samples_of_pairs(data, index, chosen)


def _full_bic(res: FitResult, n_full: int) -> float:
    """The BIC of a fit to a screening sample of n of ``n_full`` samples, scaled to all of them:
    the likelihood term (N ln(RSS/N), or χ²) grows with the samples, the penalty P ln N with ln N."""
    s = res.stats
    n, p = max(int(s["n_samples"]), 1), int(s["n_params"])
    if not np.isfinite(s["bic"]):
        return np.inf
    return (s["bic"] - p * np.log(n)) * (n_full / n) + p * np.log(n_full)


def choice_table(tried: list[tuple[Structure, FitResult]], best: FitResult, n_full: int | None = None) -> list[dict]:
    """Every candidate's structure, parameters, cost, BIC (scaled to ``n_full`` samples when the
    candidates were fitted to a screening sample), median relative error, whether it converged and
    which was chosen (the fit JSON's ``fit.structure_choice``)."""
    return [{"structure": structure_label(st), "params": int(r.stats["n_params"]), "cost": r.stats["cost"],
             "bic": _full_bic(r, n_full or int(r.stats["n_samples"])),
             "median_relative_error": r.stats.get("quality", {}).get("median_relative_error"),
             "heldout_median_relative_error": r.stats.get("heldout_median_relative_error"),
             "p90_relative_error": r.stats.get("quality", {}).get("p90_relative_error"),
             "heldout_p90_relative_error": r.stats.get("heldout_p90_relative_error"), "converged": bool(r.converged), "chosen": r is best}
            for st, r in tried]
