"""What decides the last bits of this process's floating-point results: a key part for caches of built models.

On one machine a model build is bit-identical from run to run, whatever the thread counts
(tests/core/lidar/test_rebuild_determinism.py). Across machines it is not: numpy picks its
float64 sin/cos/arctan2/... loops by the CPU's instruction set (AVX-512 SVML code or the C
library: answers 1 ulp apart), OpenBLAS and Embree pick their kernels by the CPU model, and
library versions change them. A cache shared by such machines (a home folder on NFS, a cache
volume mounted into a container) would serve a model that a fresh build here does not give;
keyed by this fingerprint, each kind of machine builds its own.
"""

from __future__ import annotations

import functools
import importlib.metadata
import json
import os
import platform
from pathlib import Path

from numpy.lib.introspect import opt_func_info

_CPU_FIELDS = ("vendor_id", "cpu family", "model", "model name")  # what OpenBLAS and Embree choose kernels by
_LIBRARIES = ("numpy", "scipy", "open3d")
_OVERRIDES = ("OPENBLAS_CORETYPE",)  # environment variables that force a BLAS kernel


def _version(distribution: str) -> str:
    try:
        return importlib.metadata.version(distribution)
    except importlib.metadata.PackageNotFoundError:
        return "absent"


def _cpu_identity() -> dict[str, str]:
    """The first processor's vendor, family, model and name (Linux); the platform's processor string elsewhere."""
    try:
        text = Path("/proc/cpuinfo").read_text(encoding="utf-8", errors="replace")
    except OSError:
        return {"processor": platform.processor()}
    found: dict[str, str] = {}
    for line in text.splitlines():
        if not line.strip():
            break  # the first processor's block ends: all processors of a machine are alike for this purpose
        name, _, value = line.partition(":")
        if name.strip() in _CPU_FIELDS:
            found[name.strip()] = value.strip()
    return found


@functools.cache
def numerics_fingerprint() -> str:
    """A JSON text naming the libraries, their SIMD choices and the CPU: equal where results are bit-equal."""
    return json.dumps(
        {
            "libraries": {name: _version(name) for name in _LIBRARIES},
            "numpy_dispatch": opt_func_info(),  # the loop each ufunc runs here (NPY_DISABLE_CPU_FEATURES included)
            "cpu": _cpu_identity(),
            "machine": platform.machine(),
            "overrides": {name: os.environ.get(name, "") for name in _OVERRIDES},
        },
        sort_keys=True,
    )
