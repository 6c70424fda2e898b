"""Freed heap memory goes back to the operating system (glibc's malloc_trim), as the model build relies on."""

from __future__ import annotations

import ctypes.util
import platform

import numpy as np
import psutil
import pytest

from advsim_ros.core.memory import release_freed_memory


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="malloc_trim is glibc's; elsewhere nothing to check")
def test_holes_left_between_kept_arrays_are_returned() -> None:
    assert ctypes.util.find_library("c")
    process = psutil.Process()
    np.ones(16 << 17)  # a freed 16 MB block raises glibc's mmap threshold: later 1 MB arrays come from the heap
    arrays = [np.ones(1 << 17) for _ in range(400)]  # 400 x 1 MB, interleaved
    del arrays[::2]  # 200 MB of holes between the arrays that are kept
    before = process.memory_info().rss
    release_freed_memory()
    returned = before - process.memory_info().rss
    assert returned > 100 << 20, f"only {returned >> 20} MB returned"
    assert all(float(array[-1]) == 1.0 for array in arrays)  # what is kept is untouched
