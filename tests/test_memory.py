"""The CLI hands large freed blocks back to the system (``ctfit._memory``)."""

import ctypes
import subprocess
import sys

import pytest

from ctfit._memory import MMAP_THRESHOLD, return_large_blocks


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt is Linux-only")
def test_freed_large_arrays_leave_the_process():
    """In a fresh process: 200 arrays of 2 MiB (below glibc's dynamic threshold once a 16 MiB
    block was freed, so heap blocks by default), of which every 20th is kept: the heap cannot
    shrink past the kept ones and keeps about 360 MiB resident by default; with the threshold
    fixed, only the 20 MiB kept stay."""
    code = (
        "import numpy as np, sys\n"
        "from ctfit._memory import return_large_blocks\n"
        "if sys.argv[1] == 'fixed': assert return_large_blocks()\n"
        "def rss():\n"
        "    return int(next(l for l in open('/proc/self/status') if l.startswith('VmRSS')).split()[1]) // 1024\n"
        "np.ones(16 << 20 >> 3); base = rss()\n"  # a freed 16 MiB block raises glibc's threshold to 16 MiB
        "arrays = [np.ones(2 << 20 >> 3) for _ in range(200)]; keep = arrays[::20]; del arrays\n"
        "print(rss() - base)\n"
    )
    grown = {how: int(subprocess.run([sys.executable, "-c", code, how], capture_output=True, text=True, check=True).stdout) for how in ("default", "fixed")}
    assert grown["fixed"] < 60 and grown["default"] > 200, grown


def test_the_threshold_is_a_mebibyte():
    assert MMAP_THRESHOLD == 1 << 20
    assert return_large_blocks() is sys.platform.startswith("linux") or not hasattr(ctypes, "CDLL")
