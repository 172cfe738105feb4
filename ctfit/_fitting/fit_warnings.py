"""A fit's warnings as values: each is its text (a ``str``, as the table and the fit JSON show it)
and what it is about, for code that acts on it: its kind, the parameter and the region of the
data it concerns."""

from __future__ import annotations

__all__ = ["FitWarning", "WARNING_KINDS"]

WARNING_KINDS = ("degenerate", "on_bound", "no_standard_errors", "systematic_residuals", "not_represented", "not_a_minimum",
                 "explains_nothing", "non_finite", "numerical_failure")
"""What a warning can be about: a parameter the data does not determine (``degenerate``), one on or
near its bound (``on_bound``), standard errors not computed, residuals that stay on one side of
the data in a region, a model that does not represent the material (``not_represented``, with
the region where it fails most), and the ways a fit can end short of a minimum (the
:class:`~ctfit.FitStatus` names)."""


class FitWarning(str):
    """One warning of a fit: its text (it *is* the text, so it prints, compares and is written as
    before) with ``kind`` (one of :data:`WARNING_KINDS`), ``parameter`` (public names: "s",
    "m", "weight", "F0", "Rd", …, several joined by ", "; or None) and ``region`` (where in the
    data, e.g. "near the specular peak"; or None).

    >>> w = FitWarning("s = 1 (on its bound): the data shows no diffuse part", "on_bound", parameter="s")
    >>> w.kind, w.parameter, w.startswith("s = 1"), w.as_dict()["kind"]
    ('on_bound', 's', True, 'on_bound')
    """

    kind: str
    parameter: str | None
    region: str | None

    def __new__(cls, text: str, kind: str, parameter: str | None = None, region: str | None = None) -> FitWarning:
        if kind not in WARNING_KINDS:
            raise ValueError(f"kind must be one of {WARNING_KINDS}, got {kind!r}")
        self = super().__new__(cls, text)
        self.kind, self.parameter, self.region = kind, parameter, region
        return self

    # pickled (Dask) and copied with its fields; str has one argument, this __new__ four
    def __getnewargs__(self) -> tuple[str, str, str | None, str | None]:  # type: ignore[override]
        return (str(self), self.kind, self.parameter, self.region)

    def as_dict(self) -> dict:
        """``{"kind", "parameter", "region", "text"}``: the fit JSON's ``fit.warning_details`` entry."""
        return {"kind": self.kind, "parameter": self.parameter, "region": self.region, "text": str(self)}
