"""Least-squares fit of the Cook–Torrance parameters to BRDF samples, with optimistix.

The pieces live beside this module: starting points (``starts.py``), the seeded solve
(``seeded_solve.py``), standard errors and warnings (``fit_report.py``), the problem layout
(``problem.py``); this module joins them into ``fit_core`` and :func:`fit`.

``fit(data, structure, ...)`` → :class:`FitResult`. Steps:

1. Starting points: a grid over the rms slopes (one value per lobe, ascending), each scored
   by the loss after the best per-band amplitude (a linear least-squares problem) — one
   vmapped pass over the data. The best ``starts`` grid points seed the solver.
2. optimistix Levenberg–Marquardt from each seed in turn (``jax.lax.map``), with the
   Gauss–Newton matrix JᵀJ formed from the factored Jacobian, never the N × P matrix
   (:class:`~ctfit._fitting.solvers.StructuredLevenbergMarquardt`, :func:`~ctfit._fitting.jacobian.normal_equations`);
   the lowest finite cost wins. optimistix Gauss–Newton, Dogleg (normal equations with
   Cholesky) or BFGS on request; float64 unless float32 is asked for. Seeding, solve and everything the report
   needs are one compiled program (``fit_core``), so a run compiles once; where JAX's
   persistent cache is enabled the executable itself is kept on disk (``_runtime/stored_programs.py``), so a new
   process with the same structure, data shape and options skips tracing and compiling.
3. Standard errors from (JᵀJ)⁻¹ at the optimum (scaled by the residual variance unless the
   loss is sigma-weighted), mapped to the constrained parameters by the delta method, reported
   only where JᵀJ is well conditioned. Near-degenerate solutions are detected and reported.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
import weakref
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import DTypeLike

from .._model import Material, Measurement, Params, Structure, parameter, x64_enabled
from .._runtime import cached_call, release_free_pages
from .chunked_fit import ROWS, chunk_problems, chunked_core, prefetch, race_rows
from .chunks import sum_over_chunks
from .coordinates import bounds, from_params, to_params
from .diagnostics import ZERO_SAMPLES, residual_notes
from .fit_report import (
    NO_STDERR_SINGULAR,
    PARAM_FIELDS,
    coordinate_names,
    fit_warnings,
    labelled,
    report_core,
    residual_summary,
    sorted_lobes,
    standard_errors,
    undetermined,
)
from .fit_stats import FitStats
from .fit_warnings import FitWarning
from .jacobian import normal_equations
from .losses import LOSSES, default_loss, zero_model_cost
from .problem import Problem, make_problem
from .quality import quality_from_residuals, quality_warning, zeros_hint
from .seeded_solve import STATIONARY_TOLERANCE, explains_none, solve_seeds
from .starts import default_start, m_points, seed_points
from .status import FitStatus, fit_status
from .validate import check_dtype, check_fittable, check_solve_options, checked_start, fixed_names, nonfinite_reason

__all__ = ["fit", "fit_to_tolerance", "prefetch_fit", "seed_params", "fit_core", "FitResult", "PreparedFit", "prepare_fit", "finish_fit", "finish_light",
           "solve_prepared"]



@dataclasses.dataclass
class FitResult:
    """A fitted material and how the fit went.

    ``material`` is a full :class:`~ctfit.Material` (usable by every command); ``stats`` holds
    converged, steps, cost, rmse, rel_rmse, time_s, n_samples, n_params, bic; ``stderr`` the
    standard errors under the public names s, m, weight, F0, n, k, Rd (None where not computed); ``warnings``
    plain-language notes on degenerate or suspicious solutions.

    >>> import numpy as np, ctfit
    >>> gold = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None),
    ...                       ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.4, 0.9])),
    ...                       wavelength_nm=np.array([450.0, 650.0]))
    >>> res = ctfit.fit(ctfit.simulate(gold, n_pairs=300, noise=0.01, seed=1), gold.structure)
    >>> sorted(res.parameters), sorted(res.parameter_errors)
    (['F0', 'lobes', 'n', 's'], ['F0', 'lobes', 'n'])
    >>> 0 < res.parameter_errors["lobes"][0]["m"] < 0.01
    True
    """

    material: Material
    stats: FitStats
    stderr: dict | None
    warnings: list[FitWarning]
    loss: str
    solver: str

    @property
    def converged(self) -> bool:
        return bool(self.stats["converged"])

    @property
    def status(self) -> FitStatus | None:
        """How the fit ended (:class:`~ctfit.FitStatus`); None where it was not recorded (a
        texel's fit, which keeps only ``converged``; a fit JSON written before it was)."""
        value = self.stats.get("fit_status")
        return None if value is None else FitStatus(value)

    @property
    def parameters(self) -> dict:
        """The fitted values under their public names, laid out as in the fit JSON (``s``,
        ``lobes`` [{``m``, ``weight``}], ``F0``, ``n``, ``k``, ``Rd``; lobes in ascending m), the
        same keys and layout as :attr:`parameter_errors`."""
        from .._io import material_to_dict

        doc = material_to_dict(self.material)
        keys = ("s", "lobes", "F0", "n", "k") + (("Rd",) if self.material.structure.has_rd else ())  # R_d = F0/π is not fitted
        return {k: doc[k] for k in keys if k in doc}

    @property
    def parameter_errors(self) -> dict | None:
        """Standard errors of :attr:`parameters`, same keys and layout (NaN where a value has none,
        e.g. on a bound); None when JᵀJ could not be inverted."""
        from .results import stderr_block

        return stderr_block(self)


def fit_core(problem: Problem, u0: dict, grid: Any, starts: int, solver_name: str, max_steps: int, keep_start: bool = False) -> dict:
    """Seeds, solve, pick the best, and everything the report needs, in one compiled program.
    ``keep_start``: the start ``u0`` is a seed too (a start the caller chose)."""
    seeds = seed_points(problem, u0, starts, grid, keep_start)
    zero_cost = sum_over_chunks(problem, zero_model_cost)  # the solver's stopping scale and the report's
    values, ok, steps, costs, normal = solve_seeds(problem, seeds, solver_name, max_steps, zero_cost)
    costs = jnp.where(jnp.isfinite(costs), costs, jnp.inf)
    best = jnp.argmin(costs)
    u = jax.tree.map(lambda a: a[best], values)
    if normal is None:
        # optimistix's own solvers (BFGS, Gauss–Newton, dogleg) know no bounds: a coordinate can
        # leave its box, where the model clips it and its gradient is 0, so a point stuck there
        # looked stationary (BFGS "converged" at 700× the minimum's cost). Judged where the model
        # takes it, on the bound: there the gradient says whether it is a minimum.
        lower, upper = bounds(problem.spec, u)
        u = jax.tree.map(jnp.clip, u, lower, upper)
        cost, jtr, jtj = normal_equations(problem, u)
    else:  # the solver's, at the seed's last accepted point (a pass of its own where it took no step or failed)
        cost, jtr, jtj = jax.lax.cond((steps[best] > 0) & jnp.isfinite(costs[best]), lambda: (costs[best], normal[0][best], normal[1][best]),
                                      lambda: normal_equations(problem, u))
    return dict(u=u, ok=ok, steps=steps, costs=costs, best=best, **report_core(problem, u, cost, jtr, jtj, zero_cost), **residual_summary(problem, u))


def _failure_hint(dtype: DTypeLike, solver: str) -> str:
    """What to try after a numerical failure: float64 where the fit ran in float32; the damped
    solver where Gauss–Newton's undamped step left the region where the model is finite (a
    conductor's n, k from one start, say); else another start or fewer lobes."""
    if jnp.dtype(dtype).name == "float32":
        return "fit in float64 (dtype=float64), from another start, or with fewer lobes"
    if solver == "gauss-newton":
        return 'Gauss–Newton takes undamped steps: fit with the damped solver (solver="lm", the default) or from more starts (starts=3)'
    return "fit from another start, or with fewer lobes"


@dataclasses.dataclass
class PreparedFit:
    """One measurement made ready for ``fit_core`` (checked, started, laid out): what :func:`fit`
    and :func:`~ctfit._fitting.batch.fit_batch` share."""

    data: Measurement
    structure: Structure
    loss: str
    dtype: DTypeLike
    start: Params
    fixed: tuple[str, ...]
    problem: Problem
    u0: dict
    grid: np.ndarray | None
    k: int
    given_start: bool
    chunked: bool = False

    def options(self, solver: str, max_steps: int) -> tuple:
        """The arguments of ``fit_core`` after (problem, u0, grid)."""
        return (self.k, solver, max_steps, self.given_start)

    def padded(self, pad_to: tuple[int, int]) -> PreparedFit:
        """The same fit with its problem padded to ``pad_to`` (direction pairs, samples)."""
        problem = make_problem(self.structure, self.data, fixed_params=self.start, fixed=self.fixed, loss=self.loss, dtype=self.dtype, pad=True, pad_to=pad_to)
        return dataclasses.replace(self, problem=problem, chunked=False)


def check_fit_arguments(data: object, structure: object) -> None:
    """TypeError naming ``data`` (a :class:`~ctfit.Measurement`) or ``structure`` (a Structure or None)."""
    if not isinstance(data, Measurement):
        hint = " (read a file with ctfit.read_measurement(path))" if isinstance(data, (str, bytes)) or hasattr(data, "__fspath__") else ""
        raise TypeError(f"data must be a ctfit.Measurement, got {type(data).__name__}{hint}")
    if structure is not None and not isinstance(structure, Structure):
        raise TypeError(f"structure must be a ctfit.Structure or None, got {type(structure).__name__}")


def prepare_fit(data: Measurement, structure: Structure | None, *, start: Params | None, fixed: tuple[str, ...], loss: str, dtype: DTypeLike,
                starts: int,
             pad_to: tuple[int, int] | None = None, chunk: int | None = None) -> PreparedFit:
    """The checks, start, problem (padded to its size bucket, or to ``pad_to`` (direction pairs,
    samples), or with ``chunk`` to a multiple of the chunks' rows), free start ``u0`` and m grid of a fit."""
    check_fit_arguments(data, structure)
    check_dtype(dtype)
    if dtype == jnp.float64 and not x64_enabled():
        raise RuntimeError("float64 fitting needs jax_enable_x64 (jax.config.update('jax_enable_x64', True)); or pass dtype=jnp.float32")
    structure = structure or Structure()
    if loss == "auto":
        loss = default_loss(data)
    if loss not in LOSSES:
        raise ValueError(f"loss must be 'auto' or one of {LOSSES}, got {loss!r}")
    start, fixed = checked_start(structure, data.n_bands, start), fixed_names(structure, fixed)
    default = default_start(structure, data)
    given_start = start is not None
    if start is None:
        start = default
    else:  # anything the structure needs but ``start`` lacks comes from the defaults
        start = Params(**{k: (getattr(start, k) if getattr(start, k) is not None else getattr(default, k)) for k in ("s", "m", "w", "f0", "n", "k", "rd")})
    check_fittable(data, structure, fixed=fixed, loss=loss, dtype=dtype)
    problem = make_problem(structure, data, fixed_params=start, fixed=fixed, loss=loss, dtype=dtype, pad=True, pad_to=pad_to, chunk=chunk)
    u0 = {k: jax.device_put(np.asarray(v, dtype=dtype)) for k, v in from_params(problem.spec, start).items()}  # (jnp.asarray compiles a conversion)
    k = starts if "m" in u0 else 1
    grid = jax.device_put(np.log(m_points(structure.lobes, structure.diffuse is not None)).astype(dtype)) if ("m" in u0 and k >= 1) else None
    return PreparedFit(data, structure, loss, dtype, start, tuple(fixed), problem, u0, grid, k, given_start, chunk is not None)


def fit(
    data: Measurement,
    structure: Structure | None = None,
    *,
    start: Params | None = None,
    fixed: tuple[str, ...] = (),
    loss: str = "auto",
    solver: str = "lm",
    dtype: DTypeLike = jnp.float64,
    starts: int = 3,
    max_steps: int = 256,
) -> FitResult:
    """Fit ``structure`` to ``data``; without one, the data chooses it (:func:`~ctfit.choose_structure`:
    metal or plastic, its diffuse part and 1–3 lobes, by BIC or on large data by the error on
    held-out direction pairs; the candidates are in
    ``stats["structure_choice"]``).

    ``start`` gives starting values (and the values of the ``fixed`` parameters); ``loss`` is
    one of ``LOSSES`` or "auto" (sigma-weighted when the data has sigma, else "robust-relative":
    the relative error (f − y)/max(y, floor), the floor from the typical sample, with large ones
    damped as in SciPy's ``soft_l1``; docs/fitting.md).
    Per-band parameters of ``start`` must already be on the data's bands.

    >>> import numpy as np, ctfit
    >>> gold = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None),
    ...                       ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.4, 0.9])),
    ...                       wavelength_nm=np.array([450.0, 650.0]))
    >>> res = ctfit.fit(ctfit.simulate(gold, n_pairs=300, seed=1), gold.structure)
    >>> res.converged, np.round(res.material.params.m, 4), np.round(res.material.params.f0, 4)
    (True, array([0.2]), array([0.4, 0.9]))
    """
    check_fit_arguments(data, structure)
    check_solve_options(starts, max_steps)
    if structure is None:
        from .structure_selection import choose_structure

        if start is not None or fixed:
            raise ValueError("structure=None lets the data choose the structure; give a structure with start or fixed")
        return choose_structure(data, loss=loss, solver=solver, dtype=dtype, starts=starts, max_steps=max_steps)[0]
    return fit_to_tolerance(data, structure, start=start, fixed=fixed, loss=loss, solver=solver, dtype=dtype, starts=starts, max_steps=max_steps)


def fit_to_tolerance(data: Measurement, structure: Structure, *, tolerance: float | None = None, start: Params | None = None, fixed: tuple[str, ...] = (),
                     loss: str = "auto", solver: str = "lm", dtype: DTypeLike = jnp.float64, starts: int = 3, max_steps: int = 256,
                     report: bool = True) -> FitResult:
    """:func:`fit` of ``structure``, its Levenberg–Marquardt ("lm") stopping where one more
    Gauss–Newton step promises less than ``tolerance`` relative decrease of the cost, and judged
    converged there (None: :data:`~ctfit._fitting.seeded_solve.STATIONARY_TOLERANCE`). The
    data-chosen default screens its candidates so (:data:`~ctfit._fitting.structure_selection.SCREEN_TOLERANCE`).
    ``report=False`` ("lm"): only what comparing fits needs (:func:`finish_light`), which spares
    the residual summary, the standard errors and the warnings (made on the host; the programs
    are the same either way)."""
    t0 = time.perf_counter()
    prep = prepare_fit(data, structure, start=start, fixed=fixed, loss=loss, dtype=dtype, starts=starts, chunk=ROWS if solver == "lm" else None)
    light = not report and solver == "lm"
    out = solve_prepared(prep, solver, max_steps, tolerance, report=not light)
    return (finish_light if light else finish_fit)(prep, out, solver, t0, tolerance if solver == "lm" else None, max_steps)


RELEASE_SAMPLES = 1 << 20
"""A fit on chunks of at least this many samples hands the memory its chunks held back to the
system once they are freed, before its report is made (:func:`~ctfit._runtime.memory.release_free_pages`,
in the ``ctfit`` command): a MERL table's warm fit then peaks at the report's own needs."""


def prefetch_fit(data: Measurement, structure: Structure, *, given_start: bool = False, fixed: tuple[str, ...] = (), loss: str = "auto",
                 solver: str = "lm", dtype: DTypeLike = jnp.float64, starts: int = 3, **_: Any) -> None:
    """Make (load or compile) the programs a :func:`fit_to_tolerance` of ``structure`` to ``data``
    will call (with a start given or not; with the report or not, the same programs), without fitting: for a
    background thread, while other fits run. Nothing for solvers other than "lm", for a fit
    that cannot be prepared (its own fit says why), or where this made them for data of the same
    bands, sigma column and size and they are still in memory (:data:`_prefetched`)."""
    if solver != "lm":
        return
    key = (structure, given_start, tuple(fixed), loss, jnp.dtype(dtype).name, starts, data.n_bands, data.sigma is not None, len(data))
    if all(ref() is not None for ref in _prefetched.get(key, [lambda: None])):
        return  # made for a file like this one, and still in memory: a database's later files skip laying out the data again
    try:
        prep = prepare_fit(data, structure, start=None, fixed=fixed, loss=loss, dtype=dtype, starts=starts, chunk=ROWS)
    except (ValueError, TypeError):
        return
    made = prefetch(prep.problem, prep.u0, prep.grid, prep.k, given_start)
    with _prefetched_guard:  # (background threads of several fits)
        _prefetched[key] = [_held(run) for run in made]
        while len(_prefetched) > PREFETCHED_KEPT:
            del _prefetched[next(iter(_prefetched))]


def _held(run: Callable) -> Callable[[], Any]:
    """A compiled program held weakly (the store's memory owns it); another (one the store could
    not key, which ``chunked_fit`` holds) as it is."""
    return weakref.ref(run) if isinstance(run, jax.stages.Compiled) else (lambda: run)


PREFETCHED_KEPT = 64
"""The most kinds of file :func:`prefetch_fit` remembers; past it (files of ever new sizes) the
oldest is forgotten, and prefetched again if met again."""
_prefetched_guard = threading.Lock()
_prefetched: dict[tuple, list[Callable[[], Any]]] = {}
""":func:`prefetch_fit`'s programs by the options and the data's bands, sigma and size (held
weakly: a program the store dropped from memory (``MEMORY_PROGRAMS``) is made again). Another
layout of that size (a grid, say) is prefetched no more; its fit makes its programs itself."""


def solve_prepared(prep: PreparedFit, solver: str, max_steps: int, tolerance: float | None = None, report: bool = True) -> dict:
    """``fit_core``'s output (host arrays) for one prepared fit: on chunks for "lm" (a problem
    laid out with ``chunk``: :func:`~ctfit._fitting.chunked_fit.chunked_core`, which stops at
    ``tolerance``, and leaves out the report with ``report=False``), else the one compiled
    program of its size bucket."""
    if solver == "lm" and prep.chunked:
        parts = chunk_problems(prep.problem)
        # A large file scores the m grid (``prep.grid``: one start or more) and races several seeds on a sample of its rows.
        sample = race_rows(prep.problem) if prep.grid is not None or prep.k + prep.given_start > 1 else None
        race_parts = None if sample is None else chunk_problems(prep.problem, rows_of=sample)
        prep.problem = dataclasses.replace(prep.problem, geom=None)  # the chunks hold the geometry now: one copy in memory
        out = chunked_core(prep.problem, prep.u0, prep.grid, prep.k, max_steps, prep.given_start, parts=parts, tolerance=tolerance, report=report,
                           race_parts=race_parts)
        del parts, race_parts
        if len(prep.data) >= RELEASE_SAMPLES:
            release_free_pages()  # the chunks' many small blocks, freed in the arenas of the threads that made them
        return out
    return jax.device_get(cached_call("fit", fit_core, prep.problem, prep.u0, prep.grid, *prep.options(solver, max_steps)))


def seed_params(
    data: Measurement, structure: Structure | None = None, *, starts: int = 3, loss: str = "auto", dtype: DTypeLike = jnp.float64
) -> list[Params]:
    """The starting points :func:`fit` solves from, best first: the ``starts`` best distinct
    points of its grid over the rms slopes, each with its best per-band F0 (or n, k) scale.

    For another optimiser started where ctfit starts (the SciPy peer of ``scripts/``), or to see
    why a fit found the basin it did. Same arguments as :func:`fit`.

    >>> import numpy as np, ctfit
    >>> metal = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None),
    ...                        ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.9])),
    ...                        wavelength_nm=np.array([550.0]))
    >>> data = ctfit.simulate(metal, n_pairs=200, seed=0)
    >>> seeds = ctfit.seed_params(data, metal.structure, starts=2)
    >>> len(seeds), [f"{float(s.m[0]):.3f}" for s in seeds]
    (2, ['0.171', '0.243'])
    """
    prep = prepare_fit(data, structure, start=None, fixed=(), loss=loss, dtype=dtype, starts=starts)
    import equinox as eqx  # (here: a fit whose programs are stored does not import Equinox)

    seeds = jax.device_get(eqx.filter_jit(seed_points)(prep.problem, prep.u0, prep.k, prep.grid))
    count = len(jax.tree.leaves(seeds)[0])
    out = []
    for i in range(count):
        p = to_params(prep.problem.spec, jax.tree.map(lambda a: a[i], seeds), prep.problem.fixed)
        out.append(Params(**{k: None if getattr(p, k) is None else np.asarray(getattr(p, k)) for k in PARAM_FIELDS}))
    return out


def _bic(cost: float, zero_cost: float, n: int, p: int, loss: str, dtype: DTypeLike) -> float:
    """BIC = N ln(RSS/N) + P ln N (χ² + P ln N with the sigma loss), RSS = 2·cost. Round-off is no
    evidence: a cost below 100 ε² of the zero model's is an exact fit, and exact fits of several
    structures tie on it, so the BIC keeps the one with the fewest parameters."""
    exact = 2 * zero_cost * (100 * float(jnp.finfo(dtype).eps)) ** 2
    return (2 * cost if loss == "sigma" else n * math.log(max(2 * cost, exact, 1e-300) / n)) + p * math.log(n)


def finish_light(prep: PreparedFit, out: dict, solver: str, t0: float, tolerance: float | None = None, max_steps: int | None = None) -> FitResult:
    """The :class:`FitResult` of a fit solved without the report (``chunked_core(report=False)``):
    its material, and the stats that compare fits (converged, steps, cost, n_samples, n_params,
    bic, gauss_newton_decrease, …; ``report`` False). No standard errors (``stderr`` None), no
    residual summary, quality or warnings: :func:`fit_to_tolerance` from its parameters gives them."""
    dtype, problem = prep.dtype, prep.problem
    costs, ok, best = out["costs"], out["ok"], int(out["best"])
    params, _ = sorted_lobes(Params(**{k: None if v is None else np.asarray(v) for k, v in out["params"].items()}))
    n, p = int(np.asarray(problem.mask).sum()), int(sum(np.size(v) for v in out["u"].values()))
    cost, zero_cost, gn_decrease = float(costs[best]), float(out["zero_cost"]), float(out["gn_decrease"])
    steps = int(np.asarray(out["steps"])[best])
    status = fit_status(np.asarray(ok)[best], math.isfinite(cost), gn_decrease, cost, zero_cost, dtype, tolerance, steps, max_steps)
    stats: FitStats = {"converged": status.converged, "fit_status": status.value, "steps": steps, "cost": cost, "time_s": time.perf_counter() - t0,
                       "n_samples": n,
             "n_params": p, "bic": _bic(cost, zero_cost, n, p, prep.loss, dtype), "loss": prep.loss, "solver": solver, "dtype": jnp.dtype(dtype).name,
             "starts": int(np.asarray(costs).size), "relative_floor": float(problem.floor), "gauss_newton_decrease": gn_decrease,
             "on_bound": labelled(out["u"], np.asarray(out["on_bound"], bool)), "report": False}
    if "race_samples" in out:
        stats["race_samples"] = int(out["race_samples"])
    return FitResult(material=_fitted_material(prep, params), stats=stats, stderr=None, warnings=[], loss=prep.loss, solver=solver)


def _held_without_error(stderr: dict | None, fixed: tuple[str, ...]) -> dict | None:
    """``stderr`` with the parameters held at their given values (``fixed``; F0's effective index
    with F0) NaN: they have no standard error (they printed "± 0" as if measured exactly)."""
    if stderr is None or not fixed:
        return stderr
    held = {parameter(k).public for k in fixed} | ({"n"} if "f0" in fixed else set())
    return {k: np.full(np.shape(v), np.nan) if k in held else v for k, v in stderr.items()}


def _no_stderr(stderr: dict | None, jt: dict | None, p: int) -> list[str]:
    """Every reported entry ("F0[2]") without a standard error: those that are NaN, or all of
    them (the quantities of ``jt``, P = ``p`` coordinates) where none were computed."""
    if stderr is None:
        return [f"{k}[{i}]" for k, v in (jt or {}).items() for i in range(np.asarray(v).reshape(-1, max(p, 1)).shape[0])]
    return [f"{k}[{i}]" for k, v in stderr.items() for i in np.flatnonzero(~np.isfinite(np.asarray(v, dtype=float)))]


def _fitted_material(prep: PreparedFit, params: Params) -> Material:
    """The :class:`~ctfit.Material` of a fit of ``prep`` with the fitted ``params``."""
    data = prep.data
    return Material(structure=prep.structure, params=Params(**{k: getattr(params, k) for k in PARAM_FIELDS}), wavelength_nm=data.wavelength_nm,
                    channels=data.channels, name=f"fit of {data.source}", band_unknown=data.band_unknown)


def _structure_notes(problem: Problem, data: Measurement, rel: np.ndarray, mask: np.ndarray, floor: float, measured: int) -> list[FitWarning]:
    """The systematic-residual warnings of a fit from its relative residuals ``rel`` (the problem's
    layout), on the grid's measured cells or the samples (:func:`~ctfit._fitting.diagnostics.residual_notes`)."""
    pairs, index = data.directions()
    if problem.spec.grid:
        cells = mask[: len(pairs)]
        return residual_notes(pairs, rel[: len(pairs)], cells & (np.asarray(problem.y)[: len(pairs)] == 0), floor, measured, mask=cells)
    return residual_notes(pairs, rel[: len(data)], np.asarray(data.brdf) == 0, floor, measured, index=index)


def finish_fit(prep: PreparedFit, out: dict, solver: str, t0: float, tolerance: float | None = None, max_steps: int | None = None) -> FitResult:
    """The :class:`FitResult` of a prepared fit from ``fit_core``'s output (host arrays); ``t0``:
    when it began; ``tolerance``: the stationarity it was solved to (:func:`fit_to_tolerance`);
    ``max_steps``: its step limit (tells :data:`FitStatus.MAX_STEPS` from a stall)."""
    data, structure, loss, dtype, problem = prep.data, prep.structure, prep.loss, prep.dtype, prep.problem
    costs, ok, steps, best = out["costs"], out["ok"], out["steps"], int(out["best"])
    u = out["u"]
    params = Params(**{k: None if v is None else np.asarray(v) for k, v in out["params"].items()})
    mask = np.asarray(problem.mask)
    floor = float(problem.floor)
    n, p = int(mask.sum()), int(sum(np.size(v) for v in u.values()))
    cost = float(costs[best])
    scale2 = 1.0 if loss == "sigma" else 2 * cost / max(n - p, 1)
    params, order = sorted_lobes(params)
    on_bound = np.asarray(out["on_bound"], bool)
    loose = undetermined(out["jtj"]) & ~on_bound  # coordinates the data does not determine
    no_noise = loss != "sigma" and n <= p  # no residual left to estimate the noise from: the errors would be rounding
    stderr = None if no_noise else _held_without_error(standard_errors(out["jtj"], out["jt"], scale2, order, ~on_bound & ~loose), prep.fixed)
    pairs, index = data.directions()
    rel = np.reshape(out["rel"], problem.y.shape)
    structure_notes = _structure_notes(problem, data, rel, mask, floor, n)
    per_sample = rel[index, data.band] if problem.spec.grid else rel[: len(data)]
    quality = quality_from_residuals(data, per_sample, floor, structure, params)
    gn_decrease = float(out["gn_decrease"])
    tolerance = STATIONARY_TOLERANCE[jnp.dtype(dtype).name] if tolerance is None else tolerance
    stationary = gn_decrease <= tolerance
    rmse = float(out["rmse"])
    not_finite = nonfinite_reason(cost, rmse, int(out["bad"]), n, dtype)  # a result that is not finite has not converged
    zero_cost = float(out["zero_cost"])
    explains_nothing = bool(explains_none(cost, zero_cost))
    status = fit_status(np.asarray(ok)[best], not_finite is None, gn_decrease, cost, zero_cost, dtype, tolerance, int(np.asarray(steps)[best]), max_steps)
    bic = _bic(cost, zero_cost, n, p, loss, dtype)
    stats: FitStats = {
        "converged": status.converged,
        "fit_status": status.value,
        "steps": int(np.asarray(steps)[best]),
        "cost": cost,
        "rmse": rmse,
        "rel_rmse": float(out["rel_rmse"]),
        "time_s": time.perf_counter() - t0,
        "n_samples": n,
        "n_params": p,
        "bic": bic,
        "loss": loss,
        "solver": solver,
        "dtype": jnp.dtype(dtype).name,
        "starts": int(np.asarray(costs).size),
        "relative_floor": floor,
        "gauss_newton_decrease": gn_decrease,
        "on_bound": labelled(u, on_bound),
        "no_stderr": _no_stderr(stderr, out["jt"], p),
        "quality": quality,
    }
    if "race_samples" in out:
        stats["race_samples"] = int(out["race_samples"])
    material = _fitted_material(prep, params)
    names = coordinate_names(u)
    not_determined = [names[i] for i in np.flatnonzero(loose)]
    why = f"{n} samples for {p} free parameters leave no residual to estimate the noise from (a sigma column gives them)" if no_noise else NO_STDERR_SINGULAR
    notes = ([FitWarning(not_finite, "non_finite")] if not_finite else []) + fit_warnings(params, stderr, not_determined, why)
    zeros_said = any(w.region == ZERO_SAMPLES for w in structure_notes)  # the share of zeros, said once
    worst = quality_warning(quality, None if zeros_said else data.brdf)
    if status.converged and worst:  # "at the best fit its seeds found": only a fit that got there says so
        notes.append(worst)
    if not stationary:
        hint = " (float32 rounding: fit in float64)" if jnp.dtype(dtype).name == "float32" else " (more max_steps=, or another start)"
        notes.append(FitWarning(f"not a minimum: the solver stopped where a Gauss–Newton step still promises a {gn_decrease:.2%} lower "
                                f"cost{hint}", "not_a_minimum"))
    if explains_nothing:
        notes.append(FitWarning(f"no fit: the model explains almost none of the data (its cost is {cost / zero_cost:.1%} of a model that is 0 everywhere); "
                                "the solver stalled where the lobe misses the data — try other lobes (structure=), starting values (start=) or another "
                                f"loss={'' if zeros_said else zeros_hint(data.brdf)}", "explains_nothing"))
    if not bool(np.asarray(ok)[best]):
        why = "the solver stopped on a numerical failure (a singular or non-finite step)"
        notes.append(FitWarning(f"{why}; {_failure_hint(dtype, solver)}", "numerical_failure"))
    return FitResult(material=material, stats=stats, stderr=stderr, warnings=notes + structure_notes, loss=loss, solver=solver)


