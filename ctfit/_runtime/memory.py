"""Large arrays go back to the system when freed (glibc), so a command's peak memory is what it
holds at once, not what it ever held.

glibc serves allocations below its *mmap threshold* from the heap, and raises that threshold
(up to 32 MiB) each time a larger block is freed. Arrays of a few to 32 MiB — a MERL file's
columns, a fit's layout — then land in the heap, and the heap keeps the freed pages: the
process grows by every temporary it ever had. Fixing the threshold at 1 MiB (``mallopt``)
keeps large blocks mapped on their own and unmapped when freed. Elsewhere (macOS, musl) this
does nothing.

Fixing that threshold also fixes glibc's *trim threshold* at its default, 128 KiB (glibc then
adjusts neither): every free that leaves 128 KiB at the top of a heap hands those pages back, and
the next allocations fault them in again. A fit's many small blocks (its threads' arenas
included) then cost system time: on the test-bed's rough plastic, a warm default fit's system
time fell from 0.49 to 0.35 s and its wall time from 1.78 to 1.68 s (medians of six) with
``TRIM_THRESHOLD``, its peak memory and a MERL fit's the same. So the trim threshold is set too:
up to 4 MiB free at the top of a heap is kept for the next allocations.

Freed blocks in the middle of a heap stay with it, and each thread allocates from an arena of
its own: a phase whose many small blocks other threads made (a large fit's chunks) leaves their
pages to arenas the next phase's thread does not use. :func:`release_free_pages` hands such pages
back (``malloc_trim``), where a fit of a million samples or more ends its solve.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

__all__ = ["release_free_pages", "return_large_blocks"]

MMAP_THRESHOLD = 1 << 20
"""Blocks of at least this many bytes are mapped on their own (``M_MMAP_THRESHOLD``)."""
TRIM_THRESHOLD = 4 << 20
"""Free memory at the top of a heap is handed back to the system above this many bytes (``M_TRIM_THRESHOLD``)."""
_M_MMAP_THRESHOLD = -3  # mallopt parameter numbers (malloc.h)
_M_TRIM_THRESHOLD = -1
_libc = None  # glibc, once :func:`return_large_blocks` has set this process up


def return_large_blocks() -> bool:
    """Fix glibc's mmap threshold at ``MMAP_THRESHOLD`` and its trim threshold at ``TRIM_THRESHOLD``
    for this process; True where they were set."""
    global _libc
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mapped = libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)
        trimmed = libc.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)
        _libc = libc if hasattr(libc, "malloc_trim") else None
        return bool(mapped) and bool(trimmed)
    except (OSError, AttributeError):  # not glibc
        return False


def release_free_pages() -> bool:
    """Hand the free pages of every heap back to the system (glibc's ``malloc_trim``), other
    threads' arenas included, in a process that :func:`return_large_blocks` set up (the ``ctfit``
    command); elsewhere nothing. For the end of a large phase whose many small blocks were freed
    by threads other than the next phase's: a MERL table's fit leaves about 190 MiB in the
    arenas of the threads that made its 20,000 chunk arrays, which the report, made in another
    thread, cannot reuse (about 20 ms). True where it ran."""
    if _libc is None:
        return False
    _libc.malloc_trim(0)
    return True
