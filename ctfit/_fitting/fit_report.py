"""What a fit reports besides its values: the constrained quantities, residual summaries,
standard errors from (JᵀJ)⁻¹ by the delta method, undetermined coordinates and warnings.

Standard errors are scaled by the residual variance unless the loss is sigma-weighted, and
reported only where JᵀJ is well conditioned; near-degenerate solutions get plain-language notes.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from .._model import PUBLIC_NAMES, Params, array_module, box_bounds, clip_box, n_from_f0, normal_reflectance, parameter
from .chunks import map_over_chunks
from .coordinates import flat_host, lobe_weights, to_params
from .fit_warnings import FitWarning
from .problem import Problem, model_values
from .seeded_solve import flat_bounds, gauss_newton_decrease
from .stationarity import active_set, stationary_decrease

__all__ = [
    "effective_index", "constrained_quantities", "residual_summary", "sorted_lobes", "standard_errors",
    "undetermined", "labelled", "coordinate_names", "fit_warnings", "report_core", "light_report_core", "quantity_jacobian",
    "summary_of_part", "summary_of_values", "combined_rms", "PARAM_FIELDS", "NO_STDERR_SINGULAR",
]

PARAM_FIELDS = ("s", "m", "w", "f0", "n", "k", "rd")
"""The fields of :class:`~ctfit.Params`, in order."""


def effective_index(f0, xp=jnp):
    """The paper's effective index of a fitted F0, finite where F0 rounds to 1 (about 10¹⁶ in
    float64, 10⁸ in float32, instead of :func:`~ctfit._model.fresnel_equations.n_from_f0`'s infinity);
    ``xp``: ``jax.numpy`` (traceable) or ``numpy`` (on the host)."""
    f0 = xp.asarray(f0)
    return n_from_f0(xp.minimum(f0, 1 - np.finfo(f0.dtype).eps))


def constrained_quantities(problem: Problem, unravel, f):
    """The reported (constrained) parameters from the flat free values, under their public names
    (``s``, ``m``, ``weight``, ``F0``, ``n``, ``k``, ``Rd``): F0 and the effective n are computed."""
    spec = problem.spec
    p = to_params(spec, unravel(f), problem.fixed)
    f0 = normal_reflectance(spec.structure, p) if spec.structure.needs_fresnel_params else None
    out = {PUBLIC_NAMES[k]: getattr(p, k) for k in ("s", "m", "w", "n", "k", "rd") if getattr(p, k) is not None}
    if f0 is not None:
        out["F0"] = f0
        if spec.structure.fresnel == "f0":
            out["n"] = effective_index(f0)
    return out


def residual_summary(problem: Problem, u: dict) -> dict:
    """What the report needs of the model at ``u``, chunk by chunk on a large problem
    (:func:`~ctfit._fitting.chunks.map_over_chunks`): the relative residuals ``rel``, stacked by chunk
    (the host reshapes them to the problem's layout; 0 where nothing is measured; float32, for
    the residual diagnostics), ``rmse`` and ``rel_rmse`` (as max|e| · rms(e / max|e|), so that
    squares cannot overflow), and ``bad``, how many measured cells have a model value that is
    not finite."""

    rel, stats, bad = map_over_chunks(problem, lambda part: summary_of_part(part, u))
    n = jnp.maximum(jnp.sum(problem.mask), 1)
    rmse, rel_rmse = (combined_rms(big, sq, n) for big, sq in stats)
    return dict(rel=rel, rmse=rmse, rel_rmse=rel_rmse, bad=jnp.sum(bad))  # rel reshaped on the host: no copy


def summary_of_part(part: Problem, u: dict):
    """One chunk's share of :func:`residual_summary` (:func:`summary_of_values` of the model's
    values at ``u``)."""
    return summary_of_values(model_values(part, u), part.y, part.mask, part.floor)


def summary_of_values(pred, y, mask, floor):
    """One chunk's share of the residual summary from the model's values ``pred`` on its cells
    (measured values ``y``, ``mask`` of the measured cells, relative residuals' ``floor``): its
    relative residuals (float32), (max|e|, Σ (e / max|e|)²) of the absolute and of the relative
    residuals, and its count of measured cells whose model value is not finite. NumPy in, NumPy
    out (the chunked fit's report, from ``fit_ne``'s values); traceable otherwise."""
    xp = array_module(pred, y)
    err = xp.where(mask, pred - y, 0)
    rel = err / xp.maximum(xp.abs(y), floor)
    stats = [_scaled_squares(e, xp) for e in (err, rel)]
    big = xp.asarray(np.finfo(np.float32).max, rel.dtype)
    rel = xp.clip(rel, -big, big).astype(np.float32)
    if xp is np:  # subnormal float32 values to 0, as XLA's conversion makes them: the same ranks (medians) as in a program
        rel[np.abs(rel) < np.finfo(np.float32).smallest_normal] = 0
    return rel, stats, xp.sum(mask & ~xp.isfinite(pred))


def _scaled_squares(e, xp=jnp):
    """(max|e|, Σ (e / max|e|)²) of one chunk."""
    big = xp.max(xp.abs(e))
    return big, xp.sum((e / xp.where(big > 0, big, 1)) ** 2)


def combined_rms(big, sq, n, xp=jnp):
    """The rms of all chunks from their (max|e|, Σ (e / max|e|)²): rescaled to the largest max
    (``xp``: ``jax.numpy`` inside a program, ``numpy`` on the host)."""
    top = xp.max(big)
    safe = xp.where(top > 0, top, 1)
    return xp.where(top == 0, xp.zeros((), big.dtype), top * xp.sqrt(xp.sum(sq * (big / safe) ** 2) / n))  # NaN stays NaN


def sorted_lobes(params: Params) -> tuple[Params, np.ndarray | None]:
    if params.m is None:
        return params, None
    order = np.argsort(np.asarray(params.m))
    return dataclasses.replace(params, m=np.asarray(params.m)[order], w=np.asarray(params.w)[order]), order


def standard_errors(jtj, jt: dict | None, scale2: float, order, free=None) -> dict | None:
    """Standard errors of the constrained parameters from JᵀJ and their Jacobian ``jt``.

    Only the ``free`` coordinates enter (not those held on a bound, nor those the data does not
    determine); a parameter that depends on no free coordinate gets NaN: it has no standard
    error (a bound that holds is the result; the effective index held at its cap where F0 = 1,
    which printed "1.8e16 ± 0")."""
    jtj = np.asarray(jtj)
    if jtj.size == 0 or jt is None:
        return None
    free = np.ones(jtj.shape[0], bool) if free is None else np.asarray(free, bool)
    sub = jtj[np.ix_(free, free)]
    cov_u = np.zeros_like(jtj)
    if sub.size:
        inverse = _inverse_if_conditioned(sub)
        if inverse is None:
            return None
        cov_u[np.ix_(free, free)] = inverse * scale2
    blocks = [np.asarray(jk).reshape(-1, jtj.shape[0]) for jk in jt.values()]
    jk = np.concatenate(blocks) if len(blocks) > 1 else blocks[0]  # every quantity's rows at once: one product, one pass
    with np.errstate(invalid="ignore", over="ignore"):  # a derivative that is infinite (dn/dF0 at F0 = 0) gives NaN, as einsum did
        var = np.sum((jk @ cov_u) * jk, axis=1)  # diag(J C Jᵀ) (a matrix product: a third of einsum's time here)
    v = np.sqrt(np.maximum(var, 0))
    nonzero = jk != 0
    v[~nonzero[:, free].any(axis=1)] = np.nan  # on a bound's coordinates alone, or on none (n held at its cap where F0 = 1): no error, not ± 0
    se, row = {}, 0
    for k, block in zip(jt, blocks):
        vk, row = v[row: row + len(block)], row + len(block)
        se[k] = vk[order] if k in ("m", "weight") and order is not None else vk.copy()
    return se


MAX_CONDITION = 1e12
"""JᵀJ on the free coordinates conditioned worse than this (2-norm): no standard errors."""


def _inverse_if_conditioned(sub: np.ndarray) -> np.ndarray | None:
    """The inverse of ``sub`` where its 2-norm condition number is finite and at most
    :data:`MAX_CONDITION`, else None. ‖A‖_F‖A⁻¹‖_F bounds the condition number from above: where
    that bound is ten times below the limit, the SVD that ``np.linalg.cond`` makes (0.09 ms, a
    third of a database file's standard errors) is not needed to say so."""
    try:
        inverse = np.linalg.inv(sub)
    except np.linalg.LinAlgError:
        inverse = None
    if inverse is not None:
        with np.errstate(invalid="ignore", over="ignore"):
            bound = np.linalg.norm(sub) * np.linalg.norm(inverse)
        if bound <= MAX_CONDITION / 10:
            return inverse
    try:
        cond = np.linalg.cond(sub)
    except np.linalg.LinAlgError:
        return None
    return inverse if np.isfinite(cond) and cond <= MAX_CONDITION else None  # (a matrix inv refused is singular: cond is not finite)


def undetermined(jtj) -> np.ndarray:
    """Coordinates the data does not constrain at all: their row of JᵀJ is zero (to rounding,
    relative to the largest diagonal entry), e.g. R_d when s = 1 or the m of a lobe of weight 0."""
    d = np.abs(np.diag(np.asarray(jtj)))
    return d <= np.finfo(np.asarray(jtj).dtype).eps * 1e-2 * (np.max(d) if d.size else 0.0)


def labelled(u: dict, flags) -> list[str]:
    """Public labels ("s", "F0[2]", "weight[1]") of the flat coordinates where ``flags`` is set."""
    out, i = [], 0
    for k in sorted(u):
        size = int(np.size(u[k]))
        for j in range(size):
            if flags[i]:
                out.append(parameter(k).public + (f"[{j}]" if np.ndim(u[k]) else ""))
            i += 1
    return out


def coordinate_names(u: dict) -> list[str]:
    """The parameter name of every flat coordinate (``ravel_pytree`` order: sorted names)."""
    return [k for k in sorted(u) for _ in range(int(np.size(u[k])))]


NO_STDERR_SINGULAR = "JᵀJ is singular or ill-conditioned (cond > 1e12)"
"""Why a fit has no standard errors, unless another reason is given (:func:`fit_warnings`)."""


def fit_warnings(params: Params, stderr, not_determined=(), no_stderr_because: str = NO_STDERR_SINGULAR) -> list[FitWarning]:
    """Plain-language notes on a degenerate or suspicious solution: lobes that merge or vanish, s
    or F0 on a bound, coordinates the data does not determine, standard errors not computed
    (``no_stderr_because``: why, where ``stderr`` is None)."""
    out = []
    if params.m is not None and len(params.m) > 1:
        m = np.asarray(params.m)
        for a, b in zip(m[:-1], m[1:]):
            if abs(b - a) <= 0.02 * max(a, b):
                out.append(FitWarning(f"degenerate: two lobes with nearly equal m ({a:.4g}, {b:.4g}); one lobe may suffice", "degenerate", "m"))
        for j, w in enumerate(np.asarray(params.w)):
            if w == 0.0:
                out.append(FitWarning(f"degenerate: lobe {j} has weight 0 (on its bound): the data needs fewer lobes, and this lobe's m = {m[j]:.4g} means "
                                      "nothing",
                                      "degenerate", "weight"))
            elif w < 1e-3:
                out.append(FitWarning(f"degenerate: lobe {j} (m = {m[j]:.4g}) has weight {w:.2g} → 0; fewer lobes may suffice", "degenerate", "weight"))
            elif stderr is not None and "weight" in stderr and w < 2 * np.asarray(stderr["weight"])[j]:
                out.append(FitWarning(f"degenerate: lobe {j} (m = {m[j]:.4g}) has weight {w:.2g} ± {np.asarray(stderr['weight'])[j]:.2g}, "
                                      "not significantly above 0; fewer lobes may suffice", "degenerate", "weight"))
    if params.s is not None:
        s = float(params.s)
        if s == 0.0:
            out.append(FitWarning("s = 0 (on its bound): the data shows no specular part, and m, F0 are not determined by it", "on_bound", "s"))
        elif s == 1.0:
            out.append(FitWarning("s = 1 (on its bound): the data shows no diffuse part", "on_bound", "s"))
        elif s < 1e-4:
            out.append(FitWarning(f"s = {s:.2g} is near its lower bound: the data shows almost no specular part", "on_bound", "s"))
        elif s > 1 - 1e-4:
            out.append(_near_one(s, params.rd))
    if params.f0 is not None and _f0_at_bound(np.asarray(params.f0, dtype=float), None if stderr is None else stderr.get("F0")):
        out.append(FitWarning("F0 at a bound (0 or 1) in some bands: the effective index is at its limit there", "on_bound", "F0"))
    if not_determined:
        names = ", ".join(parameter(k).public for k in dict.fromkeys(not_determined))
        out.append(FitWarning(f"degenerate: the data does not determine {names} (no standard error there): the model has more freedom than the data shows",
                               "degenerate", names))
    if stderr is None:
        out.append(FitWarning(f"standard errors not computed: {no_stderr_because}", "no_standard_errors"))
    return out


def _f0_at_bound(f0: np.ndarray, se) -> bool:
    """Whether F0 lies within 10⁻⁶ of 0 or 1 in some band and is not determined away from it (no
    standard error there, or one over a third of its distance): F0 = 9.986·10⁻⁷ ± 9.6·10⁻¹⁰, the
    truth 10⁻⁶, is no bound."""
    gap = np.minimum(f0, 1 - f0)
    near = gap < 1e-6
    if se is None:
        return bool(np.any(near))
    err = np.broadcast_to(np.asarray(se, dtype=float), f0.shape)
    return bool(np.any(near & ~(np.isfinite(err) & (gap > 3 * err))))


DIFFUSE_SHOWN = 1e-3
"""A diffuse part whose albedo (1 − s) π R_d reaches this in some band is one the data shows."""


def _near_one(s: float, rd) -> FitWarning:
    """The note on s just below 1: almost no diffuse part, unless R_d grew as d = 1 − s shrank (a
    diffuse part of its own, free per band, trades with s): then only d R_d is determined."""
    albedo = None if rd is None else (1 - s) * np.pi * np.asarray(rd, dtype=float)
    if albedo is None or not np.all(np.isfinite(albedo)) or np.max(albedo) < DIFFUSE_SHOWN:
        return FitWarning(f"s = {s:.6g} is near its upper bound: the data shows almost no diffuse part", "on_bound", "s")
    return FitWarning(f"degenerate: s = {s:.6g} is near its upper bound, but R_d grew to {np.max(rd):.3g} sr⁻¹: the diffuse part, (1 − s) π R_d up to "
                      f"{np.max(albedo):.3g}, is there, and s and R_d are not determined apart (only (1 − s) R_d is)", "degenerate", "s")


def report_core(problem: Problem, u: dict, cost, jtr, jtj, zero_cost, xp=jnp) -> dict:
    """What the report needs at the solution ``u`` (its ½‖r‖² ``cost``, Jᵀr, JᵀJ; the cost of a
    zero model): :func:`light_report_core`'s, with JᵀJ on the free coordinates and the Jacobian
    of the reported quantities (the standard errors'). Uses only ``problem.spec`` and
    ``problem.fixed``: any chunk of the problem serves. ``xp``: ``jax.numpy`` (traced: the Jacobian
    by ``jax.jacfwd``) or ``numpy`` (on the host, host arrays in: :func:`quantity_jacobian`, no program)."""
    out = light_report_core(problem, u, cost, jtr, jtj, zero_cost, xp)
    keep = ~out["on_bound"]
    jtj = xp.where(keep[:, None] & keep[None, :], jtj, 0)
    if xp is jnp:
        flat, unravel = ravel_pytree(u)
        jt = jax.jacfwd(lambda f: constrained_quantities(problem, unravel, f))(flat) if flat.size else None
    else:
        jt = quantity_jacobian(problem, u)
    return dict(out, jtj=jtj, jt=jt, zero_cost=zero_cost)


def quantity_jacobian(problem: Problem, u: dict) -> dict | None:
    """``jax.jacfwd`` of :func:`constrained_quantities` at the box coordinates ``u`` (host arrays), on
    the host: each reported quantity's derivatives, shape (*its shape, coordinates), in
    ``ravel_pytree``'s order; None without free coordinates. Exact, by the chain rule: the box
    map is the identity but for m = exp(u) (dm/du = m) and the lobes' weights, which are affine
    in each stick-breaking fraction (:func:`~ctfit._fitting.coordinates.lobe_weights`: a column
    is the difference of the weights at that fraction 1 and 0); a bound's clip has derivative 1
    (:func:`~ctfit._model.parameters.clip_box`). F0 of n (and k) and the effective index of F0
    by their derivatives: dF0/dn = (2(n − 1) − 2(n + 1)F0)/D, dF0/dk = 2k(1 − F0)/D with
    D = (n + 1)² + k², and dn/dF0 = 1/(√F0 (1 − √F0)²) below F0 = 1 − ε (0 above it, where
    :func:`effective_index` holds n; infinite at F0 = 0, as the traced derivative)."""
    spec, st = problem.spec, problem.spec.structure
    names = sorted(u)
    sizes = [int(np.size(u[k])) for k in names]
    total = sum(sizes)
    if not total:
        return None
    u = {k: np.asarray(v) for k, v in u.items()}
    params = to_params(spec, u, problem.fixed, np)
    dtype = np.result_type(*u.values())
    d: dict = {}
    at = 0
    for name, size in zip(names, sizes):
        value = np.asarray(getattr(params, name))
        jac = np.zeros(value.shape + (total,), dtype)
        if name == "w":
            v = clip_box(u["w"], *box_bounds("w"))
            for i in range(size):
                hi, lo = v.copy(), v.copy()
                hi[i], lo[i] = 1, 0
                jac[:, at + i] = lobe_weights(hi, "box", np) - lobe_weights(lo, "box", np)
        elif value.size != size:  # a plastic's one index, the same in every band
            jac[..., at] = 1
        else:
            jac.reshape(size, total)[np.arange(size), at + np.arange(size)] = value.ravel() if name == "m" else 1
        d[name] = jac
        at += size

    def of(name):
        return d[name] if name in d else np.zeros(np.shape(getattr(params, name)) + (total,), dtype)

    out = {PUBLIC_NAMES[k]: of(k) for k in ("s", "m", "w", "n", "k", "rd") if getattr(params, k) is not None}
    if st.needs_fresnel_params:
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            if st.fresnel == "f0":
                f0 = np.asarray(params.f0)
                out["F0"] = of("f0")
                r = np.sqrt(f0)
                dn = np.where(f0 < 1 - np.finfo(f0.dtype).eps, 1 / (r * (1 - r) ** 2), 0)
                out["n"] = dn[..., None] * of("f0")
            else:
                n = np.asarray(params.n)
                k = np.asarray(params.k) if st.fresnel == "conductor" else np.zeros_like(n)
                f0 = np.asarray(normal_reflectance(st, params))
                den = (n + 1) ** 2 + k ** 2
                out["F0"] = ((2 * (n - 1) - 2 * (n + 1) * f0) / den)[..., None] * of("n")
                if st.fresnel == "conductor":
                    out["F0"] = out["F0"] + (2 * k * (1 - f0) / den)[..., None] * of("k")
    return {name: np.asarray(v, dtype) for name, v in out.items()}


def light_report_core(problem: Problem, u: dict, cost, jtr, jtj, zero_cost, xp=jnp) -> dict:
    """What comparing a fit needs at its solution ``u``: the active set, the Gauss–Newton
    decrease on the free coordinates and the parameters (no standard errors: the data-chosen
    default's candidates, :func:`~ctfit._fitting.least_squares.fit_to_tolerance` with ``report=False``).
    ``xp``: ``jax.numpy`` (traced, inside :func:`report_core`) or ``numpy`` (on the host, host
    arrays in: the candidates' light report, no program per structure)."""
    flat = ravel_pytree(u)[0] if xp is jnp else flat_host(u)
    lower, upper = flat_bounds(problem, u, xp)
    on_bound = active_set(flat, jtr, lower, upper)  # held on a bound: a result, not a failure
    dec = stationary_decrease(flat, jtr, jtj, lower, upper, xp)  # a projected step's: one through a bound near by promises what it cannot take
    params = to_params(problem.spec, u, problem.fixed, xp)
    params = {k: getattr(params, k) for k in PARAM_FIELDS}  # plain containers: the executable's output is stored (_runtime/stored_programs.py)
    if problem.spec.structure.needs_fresnel_params and problem.spec.structure.fresnel == "f0":
        params["n"] = effective_index(params["f0"], xp)  # reported beside F0
    return dict(on_bound=on_bound, gn_decrease=gauss_newton_decrease(jtj, jtr, cost, zero_cost, xp, dec=dec), params=params)
