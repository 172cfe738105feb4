"""Time a command as a whole process: wall time, CPU time and peak memory from the kernel's own
accounting of the finished child (``os.wait4``), for the benchmarks that compare programs as users
run them (``bench_fit.py``).
"""

from __future__ import annotations

import dataclasses
import os
import statistics
import subprocess
import tempfile
import time

__all__ = ["Run", "run", "median"]


@dataclasses.dataclass
class Run:
    """One finished process: ``wall_s`` (start to reaped), ``cpu_s`` (user + system, the process
    and its waited-for children), ``peak_mb`` (largest resident set, MiB), exit code, output."""

    wall_s: float
    cpu_s: float
    peak_mb: float
    returncode: int
    stdout: str
    stderr: str

    def check(self, what: str) -> Run:
        """``self``, or a RuntimeError naming ``what`` and the end of its stderr if it failed."""
        if self.returncode != 0:
            raise RuntimeError(f"{what} exited with {self.returncode}:\n{self.stderr[-3000:]}\n{self.stdout[-1000:]}")
        return self


def run(cmd: list[str], *, env: dict | None = None, cwd=None, timeout: float | None = None) -> Run:
    """Run ``cmd`` (an argument list, no shell) to its end; output goes to temporary files, so
    that reading pipes never slows the child down."""
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err:
        t = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, env=env, cwd=cwd, text=True)
        deadline = None if timeout is None else t + timeout
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG if deadline else 0)
            if pid:
                break
            if time.perf_counter() > deadline:
                proc.kill()
                pid, status, usage = os.wait4(proc.pid, 0)
                break
            time.sleep(0.01)
        wall = time.perf_counter() - t
        proc.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        return Run(wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024, proc.returncode, out.read(), err.read())


def median(values) -> float:
    """The median of ``values`` (the figure quoted for repeated runs)."""
    return float(statistics.median(values))
