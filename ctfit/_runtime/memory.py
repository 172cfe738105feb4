"""Large arrays go back to the system when freed (glibc), so a command's peak memory is what it
holds at once, not what it ever held.

glibc serves allocations below its *mmap threshold* from the heap, and raises that threshold
(up to 32 MiB) each time a larger block is freed. Arrays of a few to 32 MiB — a MERL file's
columns, a fit's layout — then land in the heap, and the heap keeps the freed pages: the
process grows by every temporary it ever had. Fixing the threshold at 1 MiB (``mallopt``)
keeps large blocks mapped on their own and unmapped when freed. Elsewhere (macOS, musl) this
does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

__all__ = ["return_large_blocks"]

MMAP_THRESHOLD = 1 << 20
"""Blocks of at least this many bytes are mapped on their own (``M_MMAP_THRESHOLD``)."""
_M_MMAP_THRESHOLD = -3  # mallopt parameter number (malloc.h)


def return_large_blocks() -> bool:
    """Fix glibc's mmap threshold at ``MMAP_THRESHOLD`` for this process; True where it was set."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        return bool(libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD))
    except (OSError, AttributeError):  # not glibc
        return False
