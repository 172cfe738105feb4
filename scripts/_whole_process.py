"""Time a command as a whole process: wall time, CPU time and peak memory from the kernel's own
accounting of the finished child (``os.wait4``), for the benchmarks that compare programs as users
run them (``bench_fit.py``).

The command is started by a small launcher process (a Python interpreter without ``site``) that
forks, execs the command and reaps it. Started straight from a large parent, the child's peak
resident memory would start at the parent's (Linux keeps the high-water mark of the forked copy
of the parent's memory across ``exec``): a process of 20 MB would read as the size of the
benchmark that started it.
"""

from __future__ import annotations

import dataclasses
import json
import os
import statistics
import subprocess
import sys
import tempfile

__all__ = ["Run", "byte_compile", "run", "median"]

LAUNCHER = r"""
import json, os, signal, sys, time
out, limit, cmd = sys.argv[1], float(sys.argv[2]), sys.argv[3:]
t = time.perf_counter()
pid = os.fork()
if pid == 0:
    try:
        os.execvp(cmd[0], cmd)
    finally:
        os._exit(127)
signal.signal(signal.SIGALRM, lambda *_: os.kill(pid, signal.SIGKILL))
signal.setitimer(signal.ITIMER_REAL, limit)
while True:
    try:
        _, status, ru = os.wait4(pid, 0)
        break
    except InterruptedError:
        pass
wall = time.perf_counter() - t
with open(out, "w") as f:
    json.dump(dict(wall_s=wall, cpu_s=ru.ru_utime + ru.ru_stime, peak_mb=ru.ru_maxrss * 1024 / 1e6, returncode=os.waitstatus_to_exitcode(status),
                   timed_out=wall >= limit), f)
"""


@dataclasses.dataclass
class Run:
    """One finished process: ``wall_s`` (fork to reaped), ``cpu_s`` (user + system, the process
    and its waited-for children), ``peak_mb`` (largest resident set, MB = 10⁶ bytes), exit code, output;
    ``timed_out``: killed at the time limit."""

    wall_s: float
    cpu_s: float
    peak_mb: float
    returncode: int
    stdout: str
    stderr: str
    timed_out: bool = False

    def check(self, what: str) -> Run:
        """``self``, or a RuntimeError naming ``what`` and the end of its output if it failed."""
        if self.timed_out:
            raise RuntimeError(f"{what} did not finish in {self.wall_s:.0f} s (killed)")
        if self.returncode != 0:
            raise RuntimeError(f"{what} exited with {self.returncode}:\n{self.stderr[-3000:]}\n{self.stdout[-1000:]}")
        return self


def run(cmd: list[str], *, env: dict | None = None, cwd=None, timeout: float = 900.0) -> Run:
    """Run ``cmd`` (an argument list, no shell) to its end through the launcher, killed after
    ``timeout`` seconds; its output goes to temporary files, so that reading pipes never slows it
    down. Its standard input is empty."""
    with tempfile.TemporaryDirectory(prefix="whole-process-") as tmp:
        result = os.path.join(tmp, "result.json")
        with open(os.path.join(tmp, "out"), "w+") as out, open(os.path.join(tmp, "err"), "w+") as err:
            subprocess.run([sys.executable, "-I", "-S", "-c", LAUNCHER, result, str(timeout), *cmd], stdin=subprocess.DEVNULL, stdout=out, stderr=err, env=env,
                           cwd=cwd, check=True)
            out.seek(0)
            err.seek(0)
            with open(result) as f:
                r = json.load(f)
            return Run(r["wall_s"], r["cpu_s"], r["peak_mb"], r["returncode"], out.read(), err.read(), r["timed_out"])


def byte_compile() -> None:
    """Byte-compile ctfit's modules where their ``.pyc`` is missing or older than the source, as an
    installed ctfit has them (``pip install`` and ``make install`` compile them). Where the
    environment sets ``PYTHONDONTWRITEBYTECODE``, an editable tree changed since its install
    would otherwise compile its changed modules from source in every timed process (all of them:
    +0.06 s of a 0.62 s fit, 2026-12-08), a cost no user's installed ctfit pays."""
    package = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "ctfit")
    subprocess.run([sys.executable, "-m", "compileall", "-q", package], check=True)


def median(values) -> float:
    """The median of ``values`` (the figure quoted for repeated runs)."""
    return float(statistics.median(values))
