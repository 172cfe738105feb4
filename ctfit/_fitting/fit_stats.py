"""The figures a fit reports (``FitResult.stats``, the fit JSON's ``fit`` block): their names and
types, written once for type checkers and readers (``docs/formats.md`` describes them)."""

from __future__ import annotations

from typing import TypedDict

__all__ = ["FitStats"]


class FitStats(TypedDict, total=False):
    """``FitResult.stats``: a dict with these keys (a ``TypedDict``: type checkers know each key's
    type; at run time it is a plain dict, as the fit JSON's ``fit`` block is).

    Every fit has ``converged`` … ``on_bound``; a fit with the report (the default) also
    ``rmse``, ``rel_rmse``, ``no_stderr`` and ``quality``; one without (a candidate of the
    data-chosen structure, ``report`` False) ``quality`` holds the median relative error and its
    90th percentile alone, and a screened candidate also ``heldout_median_relative_error`` and
    ``heldout_p90_relative_error``; a fit whose structure the data chose, ``structure_choice`` and ``structure_screening``.

    >>> import typing, ctfit
    >>> hints = typing.get_type_hints(ctfit.FitStats)
    >>> hints["converged"], hints["cost"], hints["on_bound"]
    (<class 'bool'>, <class 'float'>, list[str])
    """

    converged: bool
    """Whether the fit ended at a minimum: ``fit_status`` is "converged"."""
    fit_status: str
    """How it ended (a :class:`~ctfit.FitStatus` value)."""
    steps: int
    """Levenberg–Marquardt steps of the best start (on all the data: see ``race_samples``)."""
    cost: float
    """½‖r‖² at the solution, r the loss's residuals."""
    time_s: float
    """Wall time of the fit."""
    n_samples: int
    n_params: int
    """Free parameters (coordinates)."""
    bic: float
    """Bayesian information criterion (the structure choice's, ``docs/fitting.md``)."""
    loss: str
    solver: str
    dtype: str
    starts: int
    """Starts raced (grid seeds and the start given)."""
    race_samples: int
    """Present where the starts were raced on a random sample of the data, of this many samples
    (data of at least 8,192 samples): the race's winners then went on over all of it (``steps``)."""
    relative_floor: float
    """The relative losses' floor (``loss_floor``)."""
    gauss_newton_decrease: float
    """The relative decrease of the cost one more Gauss–Newton step promises at the solution."""
    on_bound: list[str]
    """Coordinates on a bound ("s", "w[0]", …): results, with no standard error."""
    report: bool
    """False for a fit without the report (no standard errors, residual summary or warnings)."""
    rmse: float
    rel_rmse: float
    """rms of (f − y)/max(y, floor)."""
    no_stderr: list[str]
    """Coordinates without a standard error."""
    quality: dict
    """``{"median_relative_error", "p90_relative_error", "samples", "peak_width_deg", "regions"}`` (:func:`~ctfit.fit_quality`)."""
    heldout_median_relative_error: float
    heldout_p90_relative_error: float
    structure_choice: list[dict]
    """Every candidate of the data-chosen structure (``docs/formats.md``)."""
    structure_screening: dict
    """``{"samples", "of", "criterion", "heldout_samples"}``."""
