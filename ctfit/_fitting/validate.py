"""Is this data fit-able? Checks made before a fit (refusals) and after it (a result that is not finite).

Before the fit (:func:`check_fittable`, a ``ValueError`` naming the file): at least as many
samples as free parameters; every BRDF value finite; the data's scale, max(brdf), inside the
range the fit's dtype can square and sum (:func:`representable_range`) — the residuals are
(model − data), or that over the relative loss's floor (at least 10⁻⁶ max(data)), squared and summed over the samples,
so data at 1e300 sr⁻¹ overflows and data at 1e-300 sr⁻¹ everywhere makes every relative
residual overflow. With the sigma loss, max(brdf)/min(sigma) must be in range too. A value
refused is named as a reader names one (:func:`sample_error`): data read from a measurement CSV
by its line and column (a :class:`~ctfit.DataError`, ``data.csv:17: column 'brdf' (6): ...``),
data made in memory by its row (``row 17 of the data``).

After the fit (:func:`nonfinite_reason`): a cost, rmse or model value that is not finite means
the fit did not converge, whatever the solver said; the reason becomes one of its warnings.
"""

from __future__ import annotations

import math

import numpy as np
from jax.typing import DTypeLike

from .._io import DataError
from .._model import PUBLIC_NAMES, Measurement, Params, Structure, format_value, value_domain, wrong_size
from .coordinates import free_names

__all__ = ["check_data_scale", "check_dtype", "check_fittable", "check_solve_options", "checked_start", "fixed_names", "n_free_parameters",
           "nonfinite_reason", "representable_range", "sample_error"]

_HEADROOM = 1e4
"""Squares of values up to max/1e4 summed over 1e8 samples stay finite."""
_START_SCALE = 1e9
"""The largest relative residual of a starting model (a model value of ~1e3 sr⁻¹ over the
relative loss's floor, at least 10⁻⁶ of the data's scale: ``problem.FLOOR_OF_PEAK``) times the data's scale."""


def representable_range(dtype) -> tuple[float, float]:
    """(lowest, highest) data scale max(brdf) in sr⁻¹ that a fit in ``dtype`` can take:
    about [7.5e-142, 1.3e150] for float64, [5.4e-7, 1.8e15] for float32."""
    root = math.sqrt(float(np.finfo(np.dtype(dtype)).max))
    return _START_SCALE * _HEADROOM / root, root / _HEADROOM


def n_free_parameters(structure: Structure, n_bands: int, fixed: tuple[str, ...] = ()) -> int:
    """The number of values a fit of ``structure`` on ``n_bands`` bands adjusts."""
    size = {"s": 1, "m": structure.lobes, "w": structure.lobes - 1, "f0": n_bands, "n": 1 if structure.shared_index else n_bands, "k": n_bands}
    size["rd"] = 1 if structure.diffuse == "constant" else n_bands
    return sum(size[name] for name in free_names(structure, fixed))


def fixed_names(structure: Structure, fixed) -> tuple[str, ...]:
    """``fixed`` as :class:`~ctfit.Params` field names (the files' names accepted too: ``F0``,
    ``weight``, ``Rd``); a ``ValueError`` listing the structure's parameters for a name it does
    not have (it was ignored: the parameter was fitted), a ``TypeError`` for a bare string.

    >>> fixed_names(Structure(lobes=2), ("F0", "m"))
    ('f0', 'm')
    """
    if isinstance(fixed, str):
        raise TypeError(f"fixed must be a sequence of parameter names, e.g. ({fixed!r},), not the string {fixed!r}")
    internal = {public: name for name, public in PUBLIC_NAMES.items()}
    names = tuple(internal.get(f, f) for f in fixed)
    allowed = free_names(structure)
    bad = [f for f, name in zip(fixed, names) if name not in allowed]
    if bad:
        raise ValueError(f"fixed names {bad}: this structure's parameters are {[PUBLIC_NAMES[n] for n in allowed]}")
    return names


def check_solve_options(starts, max_steps) -> None:
    """A ``ValueError`` naming ``starts`` (a whole number ≥ 0; 0: from the start alone) or
    ``max_steps`` (a whole number ≥ 1) otherwise: ``max_steps=0`` reported an infinite cost,
    ``starts=-1`` and 1.5 steps were taken as they came."""
    whole = lambda v: isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))
    if not whole(starts) or starts < 0:
        raise ValueError(f"starts must be a whole number ≥ 0 (0: from the start alone), got {starts!r}")
    if not whole(max_steps) or max_steps < 1:
        raise ValueError(f"max_steps must be a whole number ≥ 1, got {max_steps!r}")


def check_dtype(dtype: DTypeLike) -> None:
    """A ``ValueError`` unless ``dtype`` is float32 or float64, the two a fit is made in: float16 was
    refused with data "in [3.9e+10, 0.026] sr⁻¹" (an empty range), an integer type with NumPy's
    "data type not inexact"."""
    try:
        name = np.dtype(dtype).name
    except TypeError:
        name = repr(dtype)
    if name not in ("float32", "float64"):
        raise ValueError(f"dtype must be float32 or float64, got {name}")


def checked_start(structure: Structure, n_bands: int, start) -> Params | None:
    """``start`` (a :class:`~ctfit.Params` or None) when each value it gives has the structure's
    shape on ``n_bands`` bands — one per lobe, one per band (or one for all) — else a
    ``ValueError`` naming it (a start of two lobes for a one-lobe structure gave a result of two
    lobes reported as converged); a ``TypeError`` for anything but Params."""
    if start is None:
        return None
    if not isinstance(start, Params):
        raise TypeError(f"start must be a ctfit.Params (a material's: material.params), got {type(start).__name__}")
    bad = wrong_size(structure, start, n_bands)  # (a plastic's one index may come listed per band)
    if bad is None:
        return _in_domain(structure, start)
    name, got = bad
    what, size = {"m": ("one per lobe", structure.lobes), "w": ("one per lobe", structure.lobes), "s": ("one", 1)}.get(
        name, (f"one per band ({n_bands}) or one for all", n_bands))
    raise ValueError(f"start.{name} has {got} values; this fit takes {what}: {size} ({_describe(structure) or 'its structure'})")


def _in_domain(structure: Structure, start: Params) -> Params:
    """``start`` when each value it gives is a finite number in the parameter's domain (that of a
    material file, :func:`~ctfit._model.parameters.value_domain`), else a
    ``ValueError`` naming it: a fixed F0 = 2 was reported as a converged fit (n = 1.8e16), a fixed
    m = −0.2 too, and a NaN start failed in NumPy's eigenvalue routine."""
    for name in ("s", "m", "w", "f0", "n", "k", "rd"):
        value = getattr(start, name)
        if value is None:
            continue
        lo, hi, lo_open = value_domain(name, structure.fresnel)
        v = np.atleast_1d(np.asarray(value, dtype=float))
        out = ~np.isfinite(v) | (v < lo) | (v > hi) | ((v == lo) & lo_open)
        if out.any():
            i = int(np.flatnonzero(out)[0])
            where = f"{'(' if lo_open else '['}{lo:g}, {hi:g}{']' if hi < math.inf else ')'}"
            why = f"is outside {where}" if np.isfinite(v[i]) else "is not a finite number"
            raise ValueError(f"start.{PUBLIC_NAMES[name]}[{i}] = {float(v[i])!r} {why}: a start (and a fixed value) must be in the parameter's domain")
    return start


def _describe(structure: Structure) -> str:
    parts = ["plastic"] if structure.family == "plastic" else []
    parts += [f"{structure.lobes} lobe{'s' if structure.lobes != 1 else ''}"] if structure.lobes else []
    if structure.fresnel == "conductor" and structure.needs_fresnel_params:
        parts.append("conductor")
    if structure.has_diffuse:
        parts.append("diffuse" if structure.diffuse == "F0/pi" else f"diffuse {structure.diffuse}")
    return ", ".join(parts)


def check_fittable(data: Measurement, structure: Structure, *, fixed: tuple[str, ...] = (), loss: str = "relative", dtype=np.float64) -> None:
    """Raise ``ValueError`` (naming ``data.source``) when ``data`` cannot be fitted with ``structure``:
    too few samples for its free parameters, or the data's scale (:func:`check_data_scale`)."""
    if data.brdf is None:
        raise ValueError(f"{data.source}: the data has no 'brdf' column to fit")
    n, p = len(data), n_free_parameters(structure, data.n_bands, fixed)
    if p == 0:
        raise ValueError(f"{data.source}: nothing to fit: every parameter of the structure is fixed (fixed = {list(fixed)}); "
                         "ctfit eval evaluates the material as it is")
    if n < p:
        raise ValueError(
            f"{data.source}: {n} sample{'s' if n != 1 else ''}, {p} free parameters ({_describe(structure)}): "
            "measure more or fit fewer (structure=: fewer lobes, no diffuse part)"
        )
    check_data_scale(data, loss=loss, dtype=dtype)


def check_data_scale(data: Measurement, *, loss: str = "relative", dtype=np.float64) -> None:
    """Raise ``ValueError`` when a fit in ``dtype`` cannot take ``data``'s values: a brdf that is not
    finite, the largest brdf outside :func:`representable_range`, or (``loss`` "sigma") a sigma so
    small that brdf/sigma overflows. The value is named by :func:`sample_error`: its line and
    column in the CSV it was read from, else its row of the data. Data without brdf passes."""
    if data.brdf is None:
        return
    y = np.asarray(data.brdf, dtype=float)
    bad = np.flatnonzero(~np.isfinite(y))
    if bad.size:
        raise sample_error(data, int(bad[0]), "brdf", f"{format_value(y[bad[0]])} is not a finite number ({bad.size} such rows)")
    lo, hi = representable_range(dtype)
    name = np.dtype(dtype).name
    what = f"a fit in {name} takes data whose largest brdf is in [{lo:.2g}, {hi:.2g}] sr⁻¹"
    over = np.flatnonzero(y > hi)
    if over.size:
        raise sample_error(data, int(over[0]), "brdf", f"{float(y[over[0]])!r} is too large: {what} (squares of larger values overflow); is the unit sr⁻¹?")
    top = int(np.argmax(y)) if len(y) else 0
    if not len(y) or y[top] == 0:
        raise ValueError(f"{data.source}: every brdf is 0: there is nothing to fit")
    if y[top] < lo:
        hint = " (or fit in float64)" if name == "float32" else ""
        raise sample_error(data, top, "brdf", f"{float(y[top])!r}, the largest brdf, is too small: {what} (relative residuals of smaller data "
                           f"overflow); is the unit sr⁻¹?{hint}")
    if loss == "sigma" and data.sigma is not None:
        sigma = np.asarray(data.sigma, dtype=float)
        low = int(np.argmin(sigma))
        if sigma[low] > 0 and y[top] / sigma[low] > hi:
            raise sample_error(data, low, "sigma", f"{float(sigma[low])!r} is too small for brdf values up to {float(y[top])!r}: "
                               f"(brdf − model)/sigma overflows {name}")


def sample_error(data: Measurement, row: int, column: str, reason: str) -> ValueError:
    """The error refusing the value of sample ``row`` (0-based) in ``column``, ``reason`` saying why
    (it starts with the value): a :class:`~ctfit.DataError` at the value's line and column where
    ``data`` was read from a measurement CSV (:meth:`~ctfit.Measurement.file_place`), as a reader
    reports one, else a ``ValueError`` naming the row of the data (1-based).

    >>> import numpy as np, ctfit
    >>> m = ctfit.Measurement(theta_i=np.array([30.0, 45.0]), phi_i=np.zeros(2), theta_o=np.array([30.0, 45.0]),
    ...                       phi_o=np.full(2, 180.0), band=np.zeros(2, int), wavelength_nm=np.array([550.0]), brdf=np.array([0.8, 0.5]))
    >>> print(sample_error(m, 1, "brdf", "0.5 is wrong"))
    <memory>: row 2 of the data: brdf = 0.5 is wrong
    >>> print(sample_error(m.replace(source="d.csv").with_lines(3, {"brdf": 6}), 1, "brdf", "0.5 is wrong"))
    d.csv:4: column 'brdf' (6): 0.5 is wrong
    """
    place = data.file_place(row, column)
    if place is None:
        return ValueError(f"{data.source}: row {row + 1} of the data: {column} = {reason}")
    return DataError(reason, path=data.source, line=place[0], column=column, index=place[1])


def nonfinite_reason(cost: float, rmse: float, bad: int, values: int, dtype) -> str | None:
    """Why a fit's result is not finite (a warning), or None when cost, rmse and model values are;
    ``bad`` of the ``values`` model values are not finite."""
    parts = []
    if not math.isfinite(cost):
        parts.append(f"the cost is {cost}")
    if bad:
        parts.append(f"{bad} of {values} model values are not finite")
    if not math.isfinite(rmse):
        parts.append(f"the rmse is {rmse}")
    if not parts:
        return None
    lo, hi = representable_range(dtype)
    return (
        f"not converged: {', '.join(parts)} in {np.dtype(dtype).name} (the data's scale must be within "
        f"[{lo:.2g}, {hi:.2g}] sr⁻¹, and the fitted model too)"
    )
