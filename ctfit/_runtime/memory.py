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
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

__all__ = ["return_large_blocks"]

MMAP_THRESHOLD = 1 << 20
"""Blocks of at least this many bytes are mapped on their own (``M_MMAP_THRESHOLD``)."""
TRIM_THRESHOLD = 4 << 20
"""Free memory at the top of a heap is handed back to the system above this many bytes (``M_TRIM_THRESHOLD``)."""
_M_MMAP_THRESHOLD = -3  # mallopt parameter numbers (malloc.h)
_M_TRIM_THRESHOLD = -1


def return_large_blocks() -> bool:
    """Fix glibc's mmap threshold at ``MMAP_THRESHOLD`` and its trim threshold at ``TRIM_THRESHOLD``
    for this process; True where they were set."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mapped = libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)
        trimmed = libc.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)
        return bool(mapped) and bool(trimmed)
    except (OSError, AttributeError):  # not glibc
        return False
