"""Rebuilt caches are bit-identical: the re-simulation model and the drivable area of one bag, built in fresh processes.

A cached model must be the model a fresh build gives, or the same perturbation scores differently
with and without the cache. Two processes build the caches of a KITTI 0000 window at the same
time, one with many BLAS threads and one pinned to a single CPU (one BLAS, OpenMP and TBB
thread), each into its own cache folder; every stored array must have the same bytes.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from advsim_ros.core.curation import crop_frames
from advsim_ros.core.lidar.config import ResimConfig
from advsim_ros.core.lidar.model_cache import scenario_digest
from advsim_ros.core.numerics import numerics_fingerprint
from advsim_ros.core.types import Scenario
from advsim_ros.io.bag import write_scenario_bag
from advsim_ros.io.synthetic import SyntheticLog

# Builds both caches of the bag in argv[1] into the folder argv[2]; with argv[3] == "one", on one CPU only
# (set before numpy, OpenBLAS and Open3D's TBB read how many there are). Prints {file: {array: digest}}.
BUILD = """
import os, sys
if sys.argv[3] == "one":
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
import hashlib, json
from pathlib import Path
import numpy as np
from advsim_ros.core.drivable import DrivableConfig
from advsim_ros.core.lidar.resim import ResimModel
from advsim_ros.io.bag import BagConfig, read_scenario_bag
from advsim_ros.io.drivable_cache import bag_drivable_area

bag, cache = Path(sys.argv[1]), Path(sys.argv[2])
ResimModel.build(read_scenario_bag(bag, load_sweeps=True), cache / "resim")
bag_drivable_area(bag, read_scenario_bag(bag, load_sweeps=False), DrivableConfig(), BagConfig(), cache / "drivable")
digests = {}
for path in sorted(cache.glob("*/*.npz")):
    with np.load(path, allow_pickle=False) as stored:
        digests[str(path.relative_to(cache))] = {
            name: f"{stored[name].dtype.str}{stored[name].shape}:" + hashlib.blake2b(stored[name].tobytes()).hexdigest()
            for name in stored.files
        }
print(json.dumps(digests))
"""

THREADS = {"many": "8", "one": "1"}  # BLAS/OpenMP threads of each builder; "many" oversubscribes a small machine


def _environment(threads: str) -> dict[str, str]:
    return {**os.environ, "OPENBLAS_NUM_THREADS": threads, "OMP_NUM_THREADS": threads, "MKL_NUM_THREADS": threads}


def _differences(first: dict[str, dict[str, str]], second: dict[str, dict[str, str]]) -> list[str]:
    """The cache files and arrays whose digests differ (a file or array missing on one side included)."""
    found = sorted(set(first) ^ set(second))
    for name in sorted(set(first) & set(second)):
        arrays = set(first[name]) | set(second[name])
        found += [f"{name}:{array}" for array in sorted(arrays) if first[name].get(array) != second[name].get(array)]
    return found


@pytest.mark.slow
def test_caches_of_a_kitti_window_are_bit_identical_when_rebuilt_in_fresh_processes(
    kitti_scenario: Scenario, tmp_path: Path, record_property: Callable[[str, object], None]
) -> None:
    """Frames 0-59 of KITTI 0000 (1 s history + 5 s future: what an attack builds); about 1-2 min on 2 cores."""
    bag = write_scenario_bag(crop_frames(kitti_scenario, 0, 59), tmp_path / "window", source="kitti_tracking/0000")
    builders = {
        name: subprocess.Popen(
            [sys.executable, "-c", BUILD, str(bag), str(tmp_path / name), name],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=_environment(threads),
        )
        for name, threads in THREADS.items()
    }
    outputs = {name: builder.communicate(timeout=900) for name, builder in builders.items()}
    for name, builder in builders.items():
        assert builder.returncode == 0, f"builder {name!r} failed:\n{outputs[name][1][-3000:]}"
    many, one = (json.loads(outputs[name][0]) for name in THREADS)
    model = [arrays for name, arrays in many.items() if name.startswith("resim/")]
    assert len(model) == 1
    assert len(model[0]) > 30  # the sensor's, the ground's, the background's and 15 assets' arrays
    assert any(name.startswith("drivable/") for name in many)
    record_property("arrays_compared", sum(len(arrays) for arrays in many.values()))
    assert not _differences(many, one), f"rebuilt caches differ in {_differences(many, one)}"


def test_the_numerics_fingerprint_tells_numpys_simd_loops_apart() -> None:
    """numpy's float64 sin/cos/arctan2 differ by an ulp between AVX-512 and AVX2 loops (the sensor model of a
    KITTI window moved by up to 1e-7 m with AVX-512 off): a process with other loops must key caches apart."""
    from numpy.lib.introspect import opt_func_info

    chosen = {loop["current"] for loops in opt_func_info().values() for loop in loops.values()}
    above_baseline = sorted(target for target in chosen if not target.startswith("baseline"))
    if not above_baseline:
        pytest.skip("numpy runs only its baseline loops on this CPU: there is no SIMD target to switch off")
    probe = "from advsim_ros.core.numerics import numerics_fingerprint; print(numerics_fingerprint())"
    same = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True, timeout=120)
    switched_off = subprocess.run(
        [sys.executable, "-c", probe],
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
        env={**os.environ, "NPY_DISABLE_CPU_FEATURES": " ".join(above_baseline)},
    )
    assert same.stdout.strip() == numerics_fingerprint()
    assert switched_off.stdout.strip() != numerics_fingerprint()


def test_the_model_cache_key_changes_with_the_numerics(
    short_log: SyntheticLog, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A model cached on another kind of machine (or with other library versions) is not read back here."""
    from advsim_ros.core.lidar import model_cache

    here = scenario_digest(short_log.scenario, ResimConfig())
    monkeypatch.setattr(model_cache, "numerics_fingerprint", lambda: numerics_fingerprint() + " (another machine)")
    assert scenario_digest(short_log.scenario, ResimConfig()) != here
