"""Per-texel fits of a spatially varying BRDF: one goniometer geometry, many texels' values.

``fit_texels(measurement, values, structure, ...)`` fits every row of ``values`` (texels ×
samples, the samples in the order of ``measurement``'s rows) as its own measurement of
``measurement``'s geometry and bands. The problem is laid out once (no size-bucket padding:
every texel has the same size); texels are fitted ``chunk`` at a time by the single-fit
program (``fit_core``) mapped over them (:func:`~ctfit._fitting.batch.mapped`: ``width`` side by
side, in sequence on a CPU by default) with the geometry shared, only the values and the
relative loss's floor per texel — one compiled program for all chunks (the last one is filled
up with inactive copies of its last texel), stored on disk like a single fit's. ``values`` is read a chunk at a
time, so a memory-mapped or HDF5-backed array never needs to fit in memory.

The result, :class:`TexelFits`, holds arrays with a leading texel axis — the parameters and
cheap per-texel statistics (converged, steps, cost, rmse, rel_rmse, the Gauss–Newton
decrease), not the standard errors, warnings and residual diagnostics of a full
:class:`~ctfit.FitResult`: :meth:`TexelFits.fit_result` fits one texel again with
:func:`~ctfit.fit` to get those.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import DTypeLike
from jaxtyping import Array, ArrayLike, Float

from .._model import Material, Measurement, Params, Structure, value_rules
from .._runtime import cached_call
from .batch import default_width, mapped
from .least_squares import FitResult, fit, fit_core, prepare_fit
from .losses import row_floors
from .options import takes_fit_options
from .problem import Problem
from .status import judge_converged
from .validate import representable_range

__all__ = ["fit_texels", "texel_status", "TexelFits", "ValueLayout", "with_values", "CHUNK", "TEXEL_STATUS"]

CHUNK = 1024
"""Texels per compiled call, by default."""
TEXEL_STATUS = ("fitted", "non_finite_values", "negative_values", "all_zero", "out_of_range")
"""What each texel's ``status`` code (its index here) means: 0 the texel was fitted (whether it
converged is ``converged``); otherwise it was not, its parameters and statistics are NaN, and
the code says why: a value not finite, a value < 0, every value 0, or its largest value
outside the range a fit in its dtype takes (:func:`~ctfit._fitting.validate.representable_range`)."""
_FIELDS = ("s", "m", "w", "f0", "n", "k", "rd")


@dataclasses.dataclass
class TexelFits:
    """Per-texel fits of one geometry (:func:`fit_texels`).

    ``params``: a :class:`~ctfit.Params` whose fields have a leading texel axis — s (T,), m and
    w (T, lobes) in ascending m per texel, F0, n, k, R_d (T, bands) (n: the effective index with
    the "f0" Fresnel form). ``stats``: arrays (T,) — converged, steps, cost, rmse, rel_rmse,
    gauss_newton_decrease, status (:data:`TEXEL_STATUS`; NaN parameters where it is not 0) — and the scalars loss, solver, dtype, starts, max_steps, time_s and
    texels_per_s. ``converged`` means what it means for :func:`~ctfit.fit`.

    >>> import dataclasses, numpy as np, ctfit
    >>> smooth = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([0.2]), w=np.ones(1),
    ...                         f0=np.array([0.8])), wavelength_nm=np.array([550.0]))
    >>> rough = dataclasses.replace(smooth, params=dataclasses.replace(smooth.params, m=np.array([0.4])))
    >>> geometry = ctfit.simulate(smooth, n_pairs=200, wavelength_nm=[550.0], seed=3)
    >>> fits = ctfit.fit_texels(geometry, np.stack([ctfit.evaluate(smooth, geometry), ctfit.evaluate(rough, geometry)]), smooth.structure)
    >>> len(fits), np.asarray(fits.params.m).round(4).tolist()
    (2, [[0.2], [0.4]])
    >>> fits.material(1).name, round(float(fits.fit_result(1).material.params.m[0]), 4)
    ('texel 1 of <simulated>', 0.4)
    """

    measurement: Measurement
    structure: Structure
    params: Params
    stats: dict
    values: np.ndarray = dataclasses.field(repr=False)
    options: dict = dataclasses.field(repr=False, default_factory=dict)

    def __len__(self) -> int:
        return len(self.stats["cost"])

    @property
    def converged(self) -> np.ndarray:
        return self.stats["converged"]

    def material(self, i: int) -> Material:
        """Texel ``i``'s fitted material."""
        d = self.measurement
        params = Params(**{k: None if getattr(self.params, k) is None else np.asarray(getattr(self.params, k)[i]) for k in _FIELDS})
        return Material(self.structure, params, wavelength_nm=d.wavelength_nm, channels=d.channels, name=f"texel {i} of {d.source}",
                        band_unknown=d.band_unknown)

    def fit_result(self, i: int) -> FitResult:
        """Texel ``i`` fitted again on its own by :func:`~ctfit.fit`: the full report (standard
        errors, warnings, residual structure); its parameters agree with this fit's to the
        solver's tolerance."""
        data = self.measurement.replace(brdf=np.asarray(self.values[i], dtype=float), sigma=None, source=f"texel {i} of {self.measurement.source}")
        return fit(data, self.structure, **self.options)


def _check_every_band_sampled(measurement: Measurement) -> None:
    """``ValueError`` naming the bands of ``measurement`` that no sample has: their parameters
    (F0, n, k, R_d of that band) are not determined, and every texel reported a converged value
    there, the start's (F0 = 0.005)."""
    missing = np.setdiff1d(np.arange(len(measurement.band_labels)), np.asarray(measurement.band))
    if missing.size:
        names = ", ".join(measurement.band_labels[int(b)] for b in missing[:5]) + (", …" if missing.size > 5 else "")
        raise ValueError(f"{measurement.source}: no sample has band {names}: its parameters cannot be fitted; give the geometry "
                         "only the bands it measures")


@takes_fit_options(fit)
def fit_texels(
    measurement: Measurement,
    values: Float[np.ndarray, "texels samples"],
    structure: Structure | None = None,
    *,
    chunk: int = CHUNK,
    width: int | None = None,
    **options: Any,
) -> TexelFits:
    """Fit ``structure`` to every texel: ``values[t]`` is texel t's BRDF at ``measurement``'s rows.

    ``values``: (texels, samples), any array NumPy can slice (a memmap, an h5py dataset);
    ``measurement``: the geometry and bands (its own brdf and sigma are not used; "auto" loss is
    the relative one). A texel that cannot be fitted (a value not finite or negative, every value
    0, values outside the dtype's range: :func:`texel_status`) is not fitted: its parameters and
    statistics are NaN, ``converged`` False and ``stats["status"]`` says why (:data:`TEXEL_STATUS`),
    while the others are fitted. Other
    arguments as for :func:`~ctfit.fit`; ``chunk`` texels are fitted per compiled call, ``width``
    of them side by side (vmapped; None: :func:`~ctfit._fitting.batch.default_width`).

    >>> import numpy as np, ctfit
    >>> def gold(m):
    ...     return ctfit.Material(ctfit.Structure(lobes=1, diffuse=None),
    ...                           ctfit.Params(m=np.array([m]), w=np.ones(1), f0=np.array([0.4, 0.9])),
    ...                           wavelength_nm=np.array([450.0, 650.0]))
    >>> geometry = ctfit.simulate(gold(0.2), n_pairs=300, seed=1)
    >>> values = np.stack([ctfit.evaluate(gold(m), geometry) for m in (0.1, 0.2, 0.3)])  # three texels
    >>> fits = ctfit.fit_texels(geometry, values, gold(0.2).structure)
    >>> np.round(fits.params.m[:, 0], 4), bool(fits.stats["converged"].all())
    (array([0.1, 0.2, 0.3]), True)
    """
    t0 = time.perf_counter()
    loss, solver, dtype, max_steps = options["loss"], options["solver"], options["dtype"], options["max_steps"]
    if not hasattr(values, "shape"):  # a list of rows: an array (a memmap or an h5py dataset is sliced as it is)
        values = np.asarray(values)
    kind = np.dtype(getattr(values, "dtype", np.float64)).kind
    if kind not in "fiu":  # complex values lost their imaginary part, strings were parsed as numbers
        raise ValueError(f"values must be real numbers, got an array of {np.dtype(values.dtype).name}")
    shape = getattr(values, "shape", None)
    if shape is None or len(shape) != 2 or shape[1] != len(measurement):
        raise ValueError(f"values must have shape (texels, {len(measurement)}) (one row per texel, one column per sample of "
                         f"{measurement.source}), got {shape}")
    if shape[0] < 1:
        raise ValueError("values has no texels (shape (0, samples))")
    if chunk < 1:
        raise ValueError(f"chunk must be ≥ 1, got {chunk}")
    width = default_width() if width is None else width
    if width < 1:
        raise ValueError(f"width must be ≥ 1, got {width}")
    if loss == "sigma":
        raise ValueError("loss 'sigma' needs per-sample uncertainties, which per-texel values do not have; choose another loss")
    _check_every_band_sampled(measurement)
    n_texels = shape[0]
    chunk = min(chunk, n_texels)
    width = min(width, chunk)
    status = texel_status(values, chunk, dtype)
    good = np.flatnonzero(status == 0)
    first = np.asarray(values[good[0]], dtype=float) if good.size else np.ones(len(measurement))
    template = measurement.replace(brdf=first, sigma=None)
    loss = "robust-relative" if loss == "auto" else loss
    # One size for every texel: laid out at its own size, no bucket padding.
    prep = prepare_fit(template, structure, start=options["start"], fixed=options["fixed"], loss=loss, dtype=dtype, starts=options["starts"],
                       pad_to=(len(template.directions()[0]), len(template)))
    problem, layout = prep.problem, ValueLayout(prep.problem, template)
    core_options = prep.options(solver, max_steps)
    pending, outs = None, []  # one chunk dispatched while the previous one's results are fetched
    for a in range(0, n_texels, chunk):
        block = np.array(values[a: a + chunk], dtype=float)  # a copy: the caller's array (a memory map of their file) is never written
        block[status[a: a + chunk] != 0] = first  # a texel that cannot be fitted: fitted as a copy of a good one, then blanked
        active = np.arange(chunk) < len(block)
        block = np.concatenate([block, np.broadcast_to(block[-1:], (chunk - len(block), block.shape[1]))])
        ys, floors = layout(block, dtype)
        run = cached_call("fit_texels", _texel_core, problem, ys, floors, active, prep.u0, prep.grid, width, *core_options)  # dispatched, not awaited
        if pending is not None:
            outs.append(jax.device_get(pending))
        pending = run
    outs.append(jax.device_get(pending))
    out = jax.tree.map(lambda *xs: np.concatenate(xs)[:n_texels], *outs)
    return _result(measurement, prep.structure, out, values, n_texels, t0, dict(options, loss=loss), status)


def texel_status(values: np.ndarray, chunk: int, dtype: DTypeLike) -> np.ndarray:
    """Each texel's :data:`TEXEL_STATUS` code (int8): 0 where it can be fitted, else the first
    rule it breaks — the brdf rules of every reader (:func:`~ctfit._model.measurement.value_rules`:
    finite, ≥ 0), then :func:`~ctfit._fitting.validate.check_fittable`'s (not all 0, the largest
    value in the dtype's range). Read a chunk at a time.

    >>> texel_status(np.array([[1.0, 2.0], [np.nan, 1.0], [-1.0, 1.0], [0.0, 0.0], [1e300, 1.0]]), 2, np.float64).tolist()
    [0, 1, 2, 3, 4]
    """
    lo, hi = representable_range(dtype)
    out = np.zeros(values.shape[0], np.int8)
    for a in range(0, values.shape[0], chunk):
        block = np.asarray(values[a: a + chunk], dtype=float)
        with np.errstate(invalid="ignore"):
            broken = [test(block).any(axis=1) for test, _ in value_rules("brdf")]  # not finite, negative
            top = np.where(np.isfinite(block), block, 0.0).max(axis=1, initial=0.0)
            broken += [top == 0, (top < lo) | (top > hi)]
        code = np.zeros(len(block), np.int8)
        for c, hit in reversed(list(enumerate(broken, start=1))):  # the first rule broken wins
            code[hit] = c
        out[a: a + len(block)] = code
    return out


class ValueLayout:
    """Rows of values (members × samples, in the rows of ``data``) laid out as ``problem``'s
    ``y`` (grid: direction pairs × bands; pairs: the samples, padded with zeros), with each
    row's loss floor: for measurements that share ``data``'s geometry.

    >>> import numpy as np, ctfit
    >>> from ctfit._fitting.least_squares import prepare_fit
    >>> gold = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([0.2]), w=np.ones(1),
    ...                       f0=np.array([0.9])), wavelength_nm=np.array([550.0]))
    >>> data = ctfit.simulate(gold, n_pairs=50, seed=0)
    >>> prep = prepare_fit(data, gold.structure, start=None, fixed=(), loss="relative", dtype=np.float64, starts=3)
    >>> ys, floors = ValueLayout(prep.problem, data)(np.stack([data.brdf, 2 * data.brdf]), np.float64)
    >>> ys.shape[1:] == prep.problem.y.shape, bool(np.allclose(ys[0], prep.problem.y)), bool(np.isclose(floors[1], 2 * float(prep.problem.floor)))
    (True, True, True)
    """

    def __init__(self, problem: Problem, data: Measurement) -> None:
        self.grid, self.loss = problem.spec.grid, problem.spec.loss
        self.shape = problem.y.shape
        self.index, self.band = data.directions()[1], np.asarray(data.band)

    def __call__(self, block: np.ndarray, dtype: DTypeLike) -> tuple[np.ndarray, np.ndarray]:
        ys = np.zeros((len(block),) + self.shape)
        if self.grid:
            ys[:, self.index, self.band] = block
        else:
            ys[:, : block.shape[1]] = block
        floors = row_floors(block, self.loss)
        return ys.astype(dtype), floors.astype(dtype)


def with_values(problem: Problem, y: Array, floor: Array) -> Problem:
    """``problem`` with another measurement's values ``y`` (laid out by :class:`ValueLayout`) and
    loss floor: a texel, or a member of a group of one geometry. (A dataclass replace, not
    Equinox's ``tree_at``: the fits of a folder import no Equinox when their programs are stored.)"""
    return dataclasses.replace(problem, y=y, floor=floor)


def _texel_core(problem: Problem, ys: Array, floors: Array, active: Array, u0: dict, grid: Any, width: int, *options: Any) -> Any:
    """``fit_core`` mapped over the texels' values (geometry and start shared); per texel the
    parameters and the cheap statistics only (the rest of the program is dead code to XLA)."""

    def one(texel: Any) -> dict:
        y, floor = texel
        out = fit_core(with_values(problem, y, floor), u0, grid, *options)
        best = out["best"]
        return dict(params=out["params"], cost=out["costs"][best], ok=out["ok"][best], steps=out["steps"][best],
                    gauss_newton_decrease=out["gn_decrease"], zero_cost=out["zero_cost"], rmse=out["rmse"], rel_rmse=out["rel_rmse"],
                    finite=out["bad"] == 0)

    return mapped(one, (ys, floors), active, width)


def _result(
    measurement: Measurement, structure: Structure, out: dict, values: np.ndarray, n_texels: int, t0: float, options: dict, status: np.ndarray
) -> TexelFits:
    dtype = jnp.dtype(options["dtype"]).name
    bad = status != 0
    p = {k: None if out["params"][k] is None else np.where(_per_texel(bad, out["params"][k]), np.nan, out["params"][k]) for k in _FIELDS}
    if p["m"] is not None:  # lobes in ascending m, per texel
        order = np.argsort(p["m"], axis=1)
        p["m"], p["w"] = np.take_along_axis(p["m"], order, 1), np.take_along_axis(p["w"], order, 1)
    get = lambda k: np.where(bad, np.nan, np.asarray(out[k], dtype=float))  # no fit: NaN
    cost, rmse = get("cost"), get("rmse")
    decrease = get("gauss_newton_decrease")
    finite = np.isfinite(cost) & np.isfinite(rmse) & np.asarray(out["finite"]).astype(bool)
    elapsed = time.perf_counter() - t0
    stats = dict(
        converged=np.asarray(judge_converged(np.asarray(out["ok"]), finite, decrease, cost, np.asarray(out["zero_cost"]), dtype)) & ~bad,
        steps=np.where(bad, 0, np.asarray(out["steps"])).astype(int), cost=cost, rmse=rmse, rel_rmse=get("rel_rmse"), gauss_newton_decrease=decrease,
        status=status,
        loss=options["loss"], solver=options["solver"], dtype=dtype, starts=options["starts"], max_steps=options["max_steps"],
        time_s=elapsed, texels_per_s=n_texels / elapsed,
    )
    return TexelFits(measurement, structure, Params(**p), stats, values, options)


def _per_texel(bad: np.ndarray, a: ArrayLike) -> np.ndarray:
    """``bad`` (T,) broadcast against a parameter array (T, ...)."""
    return bad.reshape(bad.shape + (1,) * (np.ndim(a) - 1))
