"""How a fit ended: one verdict (:class:`FitStatus`), decided in one place.

A fit has converged when the solver met no numerical failure, its result is finite, it explains
some of the data (its cost is below ``NO_SIGNAL`` of a model that is 0 everywhere) and it is
stationary (a Gauss–Newton step promises at most ``STATIONARY_TOLERANCE`` of the cost). The first
test that fails names the status (:func:`fit_status`); :func:`judge_converged` is the same
verdict for many fits at once (texels), where only "converged or not" is kept.

>>> fit_status(ok=True, finite=True, gn_decrease=0.5, cost=1.0, zero_cost=10.0, dtype="float64", steps=256, max_steps=256)
<FitStatus.MAX_STEPS: 'max_steps'>
"""

from __future__ import annotations

import enum

import jax.numpy as jnp
import numpy as np
from jax.typing import ArrayLike, DTypeLike

from .seeded_solve import STATIONARY_TOLERANCE, explains_none

__all__ = ["FitStatus", "fit_status", "judge_converged"]


class FitStatus(enum.StrEnum):
    """How a fit ended (``FitResult.status``; ``stats["fit_status"]`` and the fit JSON's
    ``fit.fit_status``, as its value). Only ``CONVERGED`` has converged.

    >>> import numpy as np, ctfit
    >>> gold = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([0.2]), w=np.ones(1),
    ...                       f0=np.array([0.4, 0.9])), wavelength_nm=np.array([450.0, 650.0]))
    >>> data = ctfit.simulate(gold, n_pairs=300, noise=0.01, seed=1)
    >>> ctfit.fit(data, gold.structure).status
    <FitStatus.CONVERGED: 'converged'>
    >>> ctfit.fit(data, gold.structure, max_steps=1, starts=1).status  # the step limit came first
    <FitStatus.MAX_STEPS: 'max_steps'>
    """

    CONVERGED = "converged"
    """Stationary, finite, and explaining some of the data."""
    MAX_STEPS = "max_steps"
    """Stopped at the step limit (``max_steps``) where a Gauss–Newton step still promised a lower cost."""
    NOT_A_MINIMUM = "not_a_minimum"
    """Stopped before the step limit (the solver stalled) where a Gauss–Newton step still promised a lower cost."""
    EXPLAINS_NOTHING = "explains_nothing"
    """The model explains almost none of the data: its cost is near a zero model's."""
    NON_FINITE = "non_finite"
    """The cost, the rms error or some model value is not finite."""
    NUMERICAL_FAILURE = "numerical_failure"
    """The solver stopped on a singular or non-finite step."""

    @property
    def converged(self) -> bool:
        return self is FitStatus.CONVERGED


def _verdicts(
    ok: ArrayLike, finite: ArrayLike, gn_decrease: ArrayLike, cost: ArrayLike, zero_cost: ArrayLike, dtype: DTypeLike, tolerance: float | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(solver ok, finite, explains some of the data, stationary), each an array or a bool."""
    tolerance = STATIONARY_TOLERANCE[jnp.dtype(dtype).name] if tolerance is None else tolerance
    return np.asarray(ok, bool), np.asarray(finite, bool), ~explains_none(cost, zero_cost), np.asarray(gn_decrease) <= tolerance


def judge_converged(
    ok: ArrayLike, finite: ArrayLike, gn_decrease: ArrayLike, cost: ArrayLike, zero_cost: ArrayLike, dtype: DTypeLike, tolerance: float | None = None
) -> np.ndarray:
    """Whether one fit or many (arrays) converged: :func:`fit_status` is ``CONVERGED``
    (``tolerance``: the stationarity, by default ``STATIONARY_TOLERANCE``)."""
    solver_ok, is_finite, explains, stationary = _verdicts(ok, finite, gn_decrease, cost, zero_cost, dtype, tolerance)
    return solver_ok & is_finite & explains & stationary


def fit_status(
    ok: ArrayLike, finite: ArrayLike, gn_decrease: ArrayLike, cost: ArrayLike, zero_cost: ArrayLike, dtype: DTypeLike,
    tolerance: float | None = None, steps: int | None = None, max_steps: int | None = None,
) -> FitStatus:
    """The status of one fit: the first of the tests in the module docstring that fails, in the
    order of :class:`FitStatus` from the last (a numerical failure first); ``steps`` and
    ``max_steps`` tell the step limit from a stall."""
    solver_ok, is_finite, explains, stationary = (bool(v) for v in _verdicts(ok, finite, gn_decrease, cost, zero_cost, dtype, tolerance))
    if not solver_ok:
        return FitStatus.NUMERICAL_FAILURE
    if not is_finite:
        return FitStatus.NON_FINITE
    if not explains:
        return FitStatus.EXPLAINS_NOTHING
    if not stationary:
        at_limit = steps is not None and max_steps is not None and steps >= max_steps
        return FitStatus.MAX_STEPS if at_limit else FitStatus.NOT_A_MINIMUM
    return FitStatus.CONVERGED
