"""The CLI hands large freed blocks back to the system (``ctfit._runtime.memory``)."""

import ctypes
import subprocess
import sys

import pytest

from ctfit._runtime.memory import MMAP_THRESHOLD, TRIM_THRESHOLD, return_large_blocks

# glibc's own account of the heap (mallinfo2, glibc ≥ 2.33): ``fordblks`` is the free memory the
# heap keeps — what a process holds without using. (Resident-set figures would also move with the
# kernel's reclaim of cold pages.)
PROBE = (
    "import ctypes, sys, numpy as np\n"
    "from ctfit._runtime.memory import return_large_blocks\n"
    "class Info(ctypes.Structure):\n"
    "    _fields_ = [(f, ctypes.c_size_t) for f in ('arena', 'ordblks', 'smblks', 'hblks', 'hblkhd', 'usmblks', 'fsmblks', 'uordblks', 'fordblks', "
    "'keepcost')]\n"
    "libc = ctypes.CDLL('libc.so.6'); libc.mallinfo2.restype = Info\n"
    "if sys.argv[1] == 'fixed': assert return_large_blocks()\n"
    "np.ones(16 << 20 >> 3)\n"  # a freed 16 MiB block raises glibc's dynamic threshold to 16 MiB
    "arrays = [np.ones(2 << 20 >> 3) for _ in range(200)]; mapped = libc.mallinfo2().hblkhd >> 20\n"
    "keep = arrays[::20]; del arrays\n"
    "print(mapped, libc.mallinfo2().fordblks >> 20)\n"
)


def _has_mallinfo2() -> bool:
    try:
        return hasattr(ctypes.CDLL("libc.so.6"), "mallinfo2")
    except OSError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux") or not _has_mallinfo2(), reason="needs glibc ≥ 2.33 (mallopt, mallinfo2)")
def test_freed_large_arrays_leave_the_process():
    """In a fresh process with the threshold fixed: 200 arrays of 2 MiB — below glibc's dynamic
    threshold once a 16 MiB block was freed, so by default heap blocks, and the heap keeps the
    ~360 MiB freed between every 20th, kept one (where the heap can grow in place; that depends
    on the address-space layout, so the default is not asserted) — are each their own mapping
    while alive, and the heap holds nothing freed after they go."""
    mapped, held = (int(x) for x in subprocess.run([sys.executable, "-c", PROBE, "fixed"], capture_output=True, text=True, check=True).stdout.split())
    assert mapped >= 400 and held < 30, (mapped, held)


# Page faults of 200 rounds of allocating 2 MiB in blocks of 256 KiB (below the mmap threshold),
# touching them and freeing them: a heap that hands the freed pages back faults them in again
# every round (512 pages of 4 KiB).
FAULT_PROBE = (
    "import resource, numpy as np\n"
    "from ctfit._runtime.memory import return_large_blocks\n"
    "assert return_large_blocks()\n"
    "before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt\n"
    "for _ in range(200):\n"
    "    blocks = [np.ones(256 << 10 >> 3) for _ in range(8)]\n"
    "    del blocks\n"
    "print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)\n"
)


@pytest.mark.skipif(not sys.platform.startswith("linux") or not _has_mallinfo2(), reason="needs glibc (mallopt)")
def test_small_freed_blocks_are_kept_for_the_next_allocations():
    """Fixing the mmap threshold fixes glibc's trim threshold at 128 KiB: the heap hands back the
    pages of every few freed blocks, and the next allocations fault them in again (the system
    time of a warm fit). With ``TRIM_THRESHOLD`` (4 MiB) 2 MiB of blocks freed and allocated
    again 200 times fault their pages in about once: 96,000 faults before, about 500 after."""
    faults = int(subprocess.run([sys.executable, "-c", FAULT_PROBE], capture_output=True, text=True, check=True).stdout)
    assert faults < 20 * 512, faults  # pages faulted in again in at most 20 of the 200 rounds


def test_the_threshold_is_a_mebibyte():
    assert MMAP_THRESHOLD == 1 << 20
    assert TRIM_THRESHOLD == 4 << 20
    assert return_large_blocks() is sys.platform.startswith("linux") or not hasattr(ctypes, "CDLL")
