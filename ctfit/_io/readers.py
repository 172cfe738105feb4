"""One entry point for every measurement format: :func:`read_measurement` picks the reader.

``.csv`` → measurement CSV (:func:`~ctfit.read_csv`), ``.binary`` → MERL (:func:`~ctfit.read_merl`),
``.alta`` → ALTA text (:func:`~ctfit.read_alta`), ``.bsdf`` → RGL material database
(:func:`~ctfit.read_rgl`). ``.dat`` files and files with another extension are recognised by
their content (a ``#DIM`` line: ALTA; a header naming ``theta_i``: CSV; a MERL-sized file with
MERL dimensions: MERL; the ``tensor_file`` header: RGL); an unrecognised ``.dat`` is read as
ALTA, whose reader then says what is missing.
"""

from __future__ import annotations

import os
import pathlib
from collections.abc import Callable
from typing import Any

from .._model import Measurement
from .alta import read_alta
from .csv_files import read_csv
from .errors import DataError
from .merl import MERL_FILE_BYTES, MERL_SHAPE, read_merl
from .rgl import TENSOR_MAGIC, read_rgl
from .untrusted import check_input_file

__all__ = ["READERS", "read_measurement", "reader_for"]

READERS = {".csv": read_csv, ".binary": read_merl, ".alta": read_alta, ".bsdf": read_rgl}
_SNIFF_BYTES = 64 * 1024


def read_measurement(path: str | os.PathLike[str], **options: Any) -> Measurement:
    r"""Read BRDF samples from a measurement CSV, a MERL ``.binary``, an ALTA text or an RGL ``.bsdf`` file.

    ``options`` go to the reader (e.g. ``param_out=`` for an ALTA file without ``#PARAM_OUT``,
    ``anisotropic=True`` for an anisotropic RGL file).
    A file in no supported format raises :class:`~ctfit.DataError` listing the formats.

    Examples
    --------
    A ``.dat`` file with a ``#DIM`` line is read as ALTA text; a ``.txt`` file of another kind is refused:

    >>> import ctfit
    >>> with open("sample.dat", "w") as f:
    ...     _ = f.write("#DIM 1 1\n#PARAM_IN COS_TH\n#PARAM_OUT INV_STERADIAN\n1.0 3.0\n0.5 0.2\n")
    >>> m = ctfit.read_measurement("sample.dat")
    >>> m.theta_i.tolist(), m.brdf.tolist(), m.meta["alta_param_out"]
    ([0.0, 60.0], [3.0, 0.2], 'INV_STERADIAN')
    >>> with open("notes.txt", "w") as f:
    ...     _ = f.write("not a measurement\n")
    >>> ctfit.read_measurement("notes.txt")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    ctfit._io.errors.DataError: notes.txt: unknown measurement format '.txt': supported are .csv (measurement CSV), ...
    """
    return reader_for(path)(path, **options)


def reader_for(path: str | os.PathLike[str]) -> Callable[..., Measurement]:
    """The reader of ``path``: by its suffix, else by its content (``.dat``: ALTA text)."""
    suffix = pathlib.Path(path).suffix.lower()
    reader = READERS.get(suffix) or _sniff(path) or (read_alta if suffix == ".dat" else None)
    if reader is None:
        raise DataError(
            f"unknown measurement format{f' {suffix!r}' if suffix else ''}: supported are .csv (measurement CSV), "
            ".binary (MERL BRDF database), .alta or .dat (ALTA text) and .bsdf (RGL material database); see docs/measurement-formats.md",
            path=path,
        )
    return reader


def _sniff(path: str | os.PathLike[str]) -> Callable[..., Measurement] | None:
    """The reader for a file recognised by its content, or None."""
    check_input_file(path, text=False)
    with open(path, "rb") as f:
        head = f.read(_SNIFF_BYTES)
    if head.startswith(TENSOR_MAGIC):
        return read_rgl
    if os.path.getsize(path) == MERL_FILE_BYTES and head[:12] == b"".join(d.to_bytes(4, "little") for d in MERL_SHAPE):
        return read_merl
    for line in head.decode("utf-8", errors="replace").splitlines():
        line = line.strip()
        if line.startswith(("#DIM", "#PARAM_IN", "#PARAM_OUT")):
            return read_alta
        if line and not line.startswith("#"):
            return read_csv if "theta_i" in line and "," in line else None
    return None
