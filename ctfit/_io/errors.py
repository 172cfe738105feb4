"""Errors and warnings about data and material files.

Every reader reports a bad input as a :class:`DataError` whose message names the file and,
where they apply, the 1-based line number (counting comment lines) and the column (its name
and 1-based index): ``data.csv:17: column 'theta_i' (1): 95.0 is outside [0, 90] degrees``.
"""

from __future__ import annotations

import os

__all__ = ["DataError", "DataWarning", "MaterialError"]


class DataError(ValueError):
    """A data file that breaks its format; the message says where (file, line, column).

    The parts are also attributes: ``path``, ``line``, ``column`` (name), ``index`` (1-based
    column index) and ``reason`` (the message without the location).

    Examples
    --------
    >>> import ctfit
    >>> err = ctfit.DataError("95.0 is outside [0, 90] degrees", path="data.csv", line=17, column="theta_i", index=1)
    >>> print(err)
    data.csv:17: column 'theta_i' (1): 95.0 is outside [0, 90] degrees
    >>> err.line, err.reason, isinstance(err, ValueError)
    (17, '95.0 is outside [0, 90] degrees', True)
    """

    def __init__(
        self, reason: str, *, path: str | os.PathLike[str] | None = None, line: int | None = None, column: str | None = None, index: int | None = None
    ) -> None:
        where = ""
        if path is not None:
            where = os.fspath(path) + (f":{line}" if line is not None else "") + ": "
        if column is not None:
            from .untrusted import quote  # a column's name is the file's: quoted in part

            where += f"column {quote(column)}" + (f" ({index})" if index is not None else "") + ": "
        super().__init__(where + reason)
        self.path, self.line, self.column, self.index, self.reason = path, line, column, index, reason


class DataWarning(UserWarning):
    r"""Something in a data file was dropped or assumed; the message says what and why.

    Examples
    --------
    An ALTA file of cosine-weighted values with a viewer on the horizon (θ_v = π/2), where the
    value cannot be divided by cos θ_v = 0:

    >>> import warnings, ctfit
    >>> with open("grazing.alta", "w") as f:
    ...     _ = f.write("#DIM 3 1\n#PARAM_IN ISOTROPIC_TL_TV_PROJ_DPHI\n#PARAM_OUT INV_STERADIAN_COSINE_FACTOR\n"
    ...                 "0 0.5 0 0.2\n0 1.5707963267948966 0 0.1\n")
    >>> with warnings.catch_warnings(record=True) as caught:
    ...     warnings.simplefilter("always")
    ...     samples = ctfit.read_alta("grazing.alta")
    >>> print(len(samples), caught[0].category.__name__, caught[0].message)
    1 DataWarning grazing.alta: 1 samples with theta_o ≥ 90° dropped (a cosine-weighted value cannot be divided by cos θ_o = 0)
    """


class MaterialError(ValueError):
    """A material or optical-constants file that cannot be read; the message names the place.

    >>> from ctfit import load_material
    >>> try:
    ...     load_material("no-such-material.toml")
    ... except MaterialError as err:
    ...     print(err)
    no-such-material.toml: no such file
    """
