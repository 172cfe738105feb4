"""Errors and warnings about data files.

Every reader reports a bad input as a :class:`DataError` whose message names the file and,
where they apply, the 1-based line number (counting comment lines) and the column (its name
and 1-based index): ``data.csv:17: column 'theta_i' (1): 95.0 is outside [0, 90] degrees``.
"""

from __future__ import annotations

import os

__all__ = ["DataError", "DataWarning"]


class DataError(ValueError):
    """A data file that breaks its format; the message says where (file, line, column).

    The parts are also attributes: ``path``, ``line``, ``column`` (name), ``index`` (1-based
    column index) and ``reason`` (the message without the location).
    """

    def __init__(self, reason: str, *, path=None, line: int | None = None, column: str | None = None, index: int | None = None):
        where = ""
        if path is not None:
            where = os.fspath(path) + (f":{line}" if line is not None else "") + ": "
        if column is not None:
            where += f"column {column!r}" + (f" ({index})" if index is not None else "") + ": "
        super().__init__(where + reason)
        self.path, self.line, self.column, self.index, self.reason = path, line, column, index, reason


class DataWarning(UserWarning):
    """Something in a data file was dropped or assumed; the message says what and why."""
