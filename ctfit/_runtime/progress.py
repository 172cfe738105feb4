"""Progress bars for long command-line work (tqdm, on stderr).

A bar shows only when stderr is a terminal and ``--quiet`` was not given; the environment
variable ``CTFIT_PROGRESS`` overrides the terminal test (``1``: on, ``0``: off). Text written
to stdout or stderr while a bar is shown goes through :func:`echo`, which clears the bar
first, so a line of output never runs into a bar.
"""

from __future__ import annotations

import os
import sys

__all__ = ["progress_enabled", "bar", "echo"]


def progress_enabled(quiet: bool = False) -> bool:
    """Whether to draw progress bars: never with ``quiet``; else ``CTFIT_PROGRESS`` or a terminal."""
    if quiet:
        return False
    forced = os.environ.get("CTFIT_PROGRESS", "").strip()
    if forced in ("0", "1"):
        return forced == "1"
    return sys.stderr.isatty()


def bar(iterable, *, desc: str, enabled: bool, total: int | None = None, leave: bool = False):
    """``iterable`` wrapped in a tqdm bar on stderr when ``enabled``, else returned as it is."""
    if not enabled:
        return iterable
    from tqdm import tqdm

    return tqdm(iterable, desc=desc, total=total, leave=leave, file=sys.stderr, dynamic_ncols=True)


def echo(text: str, *, err: bool = False) -> None:
    """Print one line (to stderr with ``err``) without breaking a progress bar that is shown."""
    stream = sys.stderr if err else sys.stdout
    if "tqdm" in sys.modules:
        from tqdm import tqdm

        with tqdm.external_write_mode(file=stream):
            _write(text, stream)
    else:
        _write(text, stream)


def _write(text: str, stream) -> None:
    sys.stdout.flush()  # stdout first: a line on stderr never lands inside buffered table text
    stream.write(text + "\n")
    stream.flush()
