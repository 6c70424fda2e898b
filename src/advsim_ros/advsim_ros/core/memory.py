"""Returning freed heap memory to the operating system between the stages of a long computation.

glibc keeps freed blocks of its heap for reuse. A build that allocates and frees many sweep-sized
arrays between long-lived ones (the re-simulation model's) leaves hundreds of MB of such holes that
count as resident memory until the process ends; ``malloc_trim`` hands them back. Elsewhere than on
glibc this does nothing.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
from collections.abc import Callable


@functools.cache
def _malloc_trim() -> Callable[[int], int] | None:
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        trim: Callable[[int], int] = ctypes.CDLL(name).malloc_trim
    except (OSError, AttributeError):  # not glibc
        return None
    return trim


def release_freed_memory() -> None:
    """Give the heap's free pages back to the operating system (glibc's malloc_trim; a few ms)."""
    trim = _malloc_trim()
    if trim is not None:
        trim(0)
