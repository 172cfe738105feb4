"""Progress bars for long command-line work (tqdm, on stderr).

A bar shows only when stderr is a terminal and ``--quiet`` was not given; the environment
variable ``CTFIT_PROGRESS`` overrides the terminal test (``1``: on, ``0``: off). Text written
to stdout or stderr while a bar is shown goes through :func:`echo`, which clears the bar
first, so a line of output never runs into a bar.

A reader that goes away (``ctfit fit … | head -1``) costs no result: the first write that finds
its pipe closed sends that stream to ``os.devnull`` from then on (as the Python documentation
on SIGPIPE advises), and the command goes on fitting and writing its files, silently there.
"""

from __future__ import annotations

import errno
import os
import sys

__all__ = ["progress_enabled", "bar", "closed_pipe", "echo"]


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
    _tolerant(sys.stdout, sys.stdout.flush)  # stdout first: a line on stderr never lands inside buffered table text
    _tolerant(stream, lambda: (stream.write(text + "\n"), stream.flush()))


def _tolerant(stream, action) -> None:
    """``action()``, a write to ``stream``; a closed pipe sends ``stream`` to devnull (:func:`closed_pipe`)."""
    try:
        action()
    except OSError as e:
        if e.errno != errno.EPIPE:
            raise
        closed_pipe(stream)


def closed_pipe(stream) -> None:
    """Send ``stream`` (``sys.stdout``, ``sys.stderr``), whose reader has gone, to ``os.devnull``:
    what it still holds and all later writes go nowhere, without an error."""
    try:
        fd = stream.fileno()
    except (AttributeError, OSError, ValueError):  # not a file (a test's capture): nothing to redirect
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, fd)
    os.close(devnull)
