"""A large measurement CSV parsed in a helper process while the command that needs it starts JAX.

A ``ctfit fit FILE`` process spends its first 0.6 s or so importing JAX, and parsing a large CSV
(0.24 s for 200,000 rows here; 0.65 s before its numbers were decoded as JSON, 2026-12-06) holds
Python's lock as the import does: in one process, threads or not, the two run one after the
other. So the command starts a helper process (``python -m ctfit._io.read_ahead FILE``) that
parses the file with :func:`~ctfit._io.csv_table.read_table` (NumPy and msgspec, no JAX) on
another core while it imports JAX — and makes the Measurement's columns and its direction pairs, which the fit needs next —
and takes the parsed table from the helper's output when it needs the data; the values are then
checked and made a :class:`~ctfit.Measurement` as ever (:func:`~ctfit._io.csv_files.measurement_from_table`).

What is read does not change: the helper runs the reader's own code, and a helper that fails in
any way (a bad line, a file changed meanwhile, a killed process) only means the file is read in
the command's own process after all, with the usual error. Files smaller than
:data:`READ_AHEAD_BYTES`, other formats, a machine with one core, or ``CTFIT_READ_AHEAD=0`` in
the environment: no helper. A helper whose table is never taken is stopped (:meth:`ReadAhead.cancel`);
one left behind by a command that was killed ends when it writes to the closed pipe.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .._model import Measurement
    from .csv_table import CsvTable

__all__ = ["READ_AHEAD_BYTES", "ReadAhead", "start_read_ahead", "usable_cores"]

READ_AHEAD_BYTES = 8 << 20
"""CSV files of at least this many bytes (about 100,000 rows) are parsed by a helper process. Below
it the helper gains nothing measurable (whole processes, paired, on two cores: 50,000 rows the
same within noise, 100,000 rows 3 % faster, 200,000 rows 12 %; with the faster parse of 2026-12-06,
200,000 rows still 13 %): the helper's own start (a Python process importing NumPy) and the
unpickling take about what the parse would."""

ENVIRONMENT = "CTFIT_READ_AHEAD"
"""``CTFIT_READ_AHEAD=0`` in the environment: no helper process, every file read in-process."""


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity where the system has one)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def _identity(path: str | os.PathLike[str]) -> tuple[int, int, int, int]:
    st = os.stat(path)
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns


class ReadAhead:
    """A helper process parsing one CSV; :meth:`measurement` waits for it and returns the file's
    measurement (:meth:`table`: the parsed table, or None)."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = os.fspath(path)
        self._identity = _identity(path)
        self._process: subprocess.Popen | None = subprocess.Popen(
            [sys.executable, "-m", __name__, self.path], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL
        )

    def table(self) -> CsvTable | None:
        """The helper's table once it has finished; None when it failed, was cancelled or the file
        changed since it started (size, modification time, inode). Once only."""
        process, self._process = self._process, None
        if process is None:
            return None
        assert process.stdout is not None  # stdout=PIPE
        try:
            with process.stdout:
                payload = process.stdout.read()
            if process.wait() != 0 or _identity(self.path) != self._identity:
                return None
            table = pickle.loads(payload)  # our own helper's output, through a pipe
        except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError):
            _stop(process)
            return None
        except BaseException:  # Ctrl-C while waiting: the helper stopped too
            _stop(process)
            raise
        from .csv_table import CsvTable  # (NumPy: imported here, not before the helper starts)

        return table if isinstance(table, CsvTable) else None

    def measurement(self) -> Measurement:
        """The checked :class:`~ctfit.Measurement` of the file: from the helper's table
        (:func:`~ctfit._io.csv_files.measurement_from_table`: the reader's checks and errors), or
        read here (:func:`~ctfit.read_csv`) where the helper has none. Imports JAX (the Measurement)."""
        from .csv_files import measurement_from_table, read_csv

        table = self.table()
        return read_csv(self.path) if table is None else measurement_from_table(table, self.path)

    def cancel(self) -> None:
        """Stop the helper (its table is not wanted)."""
        process, self._process = self._process, None
        if process is not None:
            _stop(process)


def _stop(process: subprocess.Popen) -> None:
    if process.poll() is None:
        process.kill()
    process.wait()
    if process.stdout is not None:
        process.stdout.close()


def start_read_ahead(path: str | os.PathLike[str]) -> ReadAhead | None:
    """A :class:`ReadAhead` of ``path`` where one pays: a regular ``.csv`` file of at least
    :data:`READ_AHEAD_BYTES`, two cores or more, not turned off (:data:`ENVIRONMENT`); else None."""
    if os.environ.get(ENVIRONMENT, "1") == "0" or Path(path).suffix.lower() != ".csv" or usable_cores() < 2:
        return None
    try:
        if not Path(path).is_file() or os.path.getsize(path) < READ_AHEAD_BYTES:
            return None
        return ReadAhead(path)
    except OSError:  # the reader in the command's process says what is wrong
        return None


def _main(argv: list[str]) -> int:
    """The helper: parse ``argv[1]`` and write its pickled :class:`CsvTable` to standard output."""
    from .csv_table import read_table

    table = read_table(argv[1], prepared=True)
    out = sys.stdout.buffer
    pickle.dump(table, out, protocol=pickle.HIGHEST_PROTOCOL)
    out.flush()
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv))
