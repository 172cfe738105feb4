"""Progress bars for long command-line work (tqdm, on stderr).

A bar shows only when stderr is a terminal and ``--quiet`` was not given; the environment
variable ``CTFIT_PROGRESS`` overrides the terminal test (``1``: on, ``0``: off). Work that runs
for minutes (posterior sampling) writes plain lines instead where stderr is not a terminal (a
log file, a pipe, a batch job): one every :data:`LINE_EVERY_S` seconds (:func:`progress_mode`,
:class:`ProgressLines`). Text written
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
import time

__all__ = ["LINE_EVERY_S", "ProgressLines", "progress_enabled", "progress_mode", "bar", "closed_pipe", "echo"]

LINE_EVERY_S = 5.0
"""Seconds between two progress lines (:class:`ProgressLines`)."""


def progress_enabled(quiet: bool = False) -> bool:
    """Whether to draw progress bars: never with ``quiet``; else ``CTFIT_PROGRESS`` or a terminal."""
    return progress_mode(quiet) == "bar"


def progress_mode(quiet: bool = False) -> str | None:
    """How long work shows its progress: None with ``quiet`` or ``CTFIT_PROGRESS=0``; "bar" with
    ``CTFIT_PROGRESS=1`` or on a terminal; else "lines" (a log file, a pipe)."""
    forced = os.environ.get("CTFIT_PROGRESS", "").strip()
    if quiet or forced == "0":
        return None
    return "bar" if forced == "1" or sys.stderr.isatty() else "lines"


class ProgressLines:
    """Progress as plain lines on stderr, at most one every ``every`` seconds (the first after
    ``every``: work shorter than that writes none): ``DESC: 400 of 2,000 steps (20 %), 31 s,
    about 1 min 48 s left``. ``done``: steps done before (a resumed run), counted in but not in
    the rate."""

    def __init__(self, total: int, *, desc: str, unit: str = "steps", done: int = 0, every: float | None = None):
        self.total, self.desc, self.unit, self.start_count = int(total), desc, unit, int(done)
        self.count, self.every = int(done), LINE_EVERY_S if every is None else float(every)
        self.t0 = self.last = time.monotonic()

    def update(self, n: int = 1) -> None:
        self.count += n
        now = time.monotonic()
        if now - self.last >= self.every:
            self.last = now
            echo(self.line(now - self.t0), err=True)

    def line(self, elapsed: float) -> str:
        """The line after ``elapsed`` seconds."""
        ran = self.count - self.start_count
        left = (self.total - self.count) * elapsed / ran if ran > 0 else float("nan")
        share = 100 * self.count / self.total if self.total else 100.0
        eta = f", about {_duration(left)} left" if left == left and self.count < self.total else ""
        return f"{self.desc}: {self.count:,} of {self.total:,} {self.unit} ({share:.0f} %), {_duration(elapsed)}{eta}"


def _duration(seconds: float) -> str:
    """``31 s``, ``1 min 48 s``, ``2 h 05 min``."""
    s = int(round(seconds))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60} s"
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


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
    _tolerant(stream, lambda: _write_text(stream, text + "\n"))


def _write_text(stream, text: str) -> None:
    """``stream.write(text)`` and a flush; a character its encoding refuses (the lone surrogates in which
    Python holds the name of a file that is not UTF-8, on a UTF-8 terminal) as a backslash
    escape, as messages quote such a name (``caf\\udce9.csv``): a fit's table printed so failed
    that file. (A text stream encodes the whole text before it writes any of it.)"""
    try:
        stream.write(text)
    except UnicodeEncodeError:
        encoding = getattr(stream, "encoding", None) or "utf-8"
        stream.write(text.encode(encoding, "backslashreplace").decode(encoding))
    stream.flush()


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
