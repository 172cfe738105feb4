"""The CLI hands large freed blocks back to the system, and a large fit's freed chunks before its
report (``ctfit._runtime.memory``)."""

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


# 200 MiB of 8 KiB blocks made in a thread of their own (its own arena), every tenth kept: the
# freed nine tenths lie between kept blocks, where no free of glibc's own hands them back.
RELEASE_PROBE = (
    "import threading, numpy as np\n"
    "from ctfit._runtime.memory import release_free_pages, return_large_blocks\n"
    "def rss(): return int(open('/proc/self/statm').read().split()[1]) * 4096 >> 20\n"
    "print(release_free_pages())\n"
    "assert return_large_blocks()\n"
    "kept = []\n"
    "def make():\n"
    "    blocks = [np.ones(8 << 10 >> 3) for _ in range(25_000)]\n"
    "    kept.extend(blocks[::10])\n"
    "worker = threading.Thread(target=make); worker.start(); worker.join()\n"
    "before = rss(); ran = release_free_pages(); print(ran, before - rss())\n"
)


@pytest.mark.skipif(not sys.platform.startswith("linux") or not _has_mallinfo2(), reason="needs glibc (mallopt, malloc_trim)")
def test_the_free_pages_another_thread_left_go_back_once_asked():
    """``release_free_pages`` does nothing in a process that ``return_large_blocks`` did not set up
    (a program that imports ctfit keeps its allocator as it is); in one it did, the pages freed
    between blocks that stay, in another thread's arena, leave the process: 180 MiB of them here."""
    lines = subprocess.run([sys.executable, "-c", RELEASE_PROBE], capture_output=True, text=True, check=True).stdout.split("\n")
    assert lines[0] == "False", lines
    ran, freed = lines[1].split()
    assert ran == "True" and int(freed) >= 100, lines


def test_the_threshold_is_a_mebibyte():
    assert MMAP_THRESHOLD == 1 << 20
    assert TRIM_THRESHOLD == 4 << 20
    assert return_large_blocks() is sys.platform.startswith("linux") or not hasattr(ctypes, "CDLL")


def test_a_large_fit_releases_its_chunks_memory_before_its_report(monkeypatch):
    """``fit`` asks for the free pages back once its chunks are freed, where the data has at least
    ``RELEASE_SAMPLES`` samples (a smaller fit, a file of a folder among them, does not pay for it)."""
    import numpy as np

    import ctfit
    from ctfit._fitting import least_squares

    calls = []
    monkeypatch.setattr(least_squares, "release_free_pages", lambda: calls.append(len(calls)) or True)
    gold = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.9])),
                          wavelength_nm=np.array([550.0]))
    data = ctfit.simulate(gold, n_pairs=300, seed=2)
    ctfit.fit(data, gold.structure)
    assert calls == []  # 300 samples: below RELEASE_SAMPLES
    monkeypatch.setattr(least_squares, "RELEASE_SAMPLES", len(data))
    res = ctfit.fit(data, gold.structure)
    assert calls == [0] and res.converged
