"""Handing freed C heap back to the operating system (glibc's malloc_trim).

glibc keeps freed blocks of its heap for reuse: megabyte blocks freed after it raised its mmap
threshold sit in the heap's middle and stay resident. A model build that allocates and frees
sweep-sized arrays between long-lived ones, or a node that drops a large part of what it loaded
(lidar_resim: the sweeps it never re-simulates, the triangles it gave to Embree), would keep
hundreds of MB of such holes until the process ends. malloc_trim(0) returns their pages; nothing
else changes (same values, same allocations). Elsewhere than on glibc this does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
from collections.abc import Callable


@functools.cache
def _malloc_trim() -> Callable[[int], int] | None:
    name = ctypes.util.find_library("c")
    try:
        trim: Callable[[int], int] = ctypes.CDLL(name).malloc_trim  # glibc only
    except (OSError, AttributeError, TypeError):
        return None
    return trim


def release_freed_memory() -> bool:
    """Return the free pages of the C heap to the system (a few ms); False where the C library cannot."""
    trim = _malloc_trim()
    if trim is None:
        return False
    trim(0)
    return True
