"""Fixtures for the reference stacks' tests: real KITTI data beside the repository, a synthetic log."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from advsim_ros.core.types import Scenario
from advsim_ros.io.kitti import load_kitti_tracking
from advsim_ros.io.synthetic import SyntheticConfig, SyntheticLog, generate_synthetic_log

SHARED_DATA = Path(__file__).resolve().parents[2] / "../shared/data"


@pytest.fixture(scope="session")
def kitti_root() -> Path:
    root = SHARED_DATA / "kitti_tracking_0000"
    if not root.is_dir():
        pytest.skip(f"KITTI tracking 0000 not found at {root.resolve()} (the shared data beside the repository)")
    return root.resolve()


@pytest.fixture(scope="session")
def kitti_scenario(kitti_root: Path) -> Scenario:
    return load_kitti_tracking(kitti_root, "0000")


@pytest.fixture(scope="session")
def synthetic_log() -> SyntheticLog:
    """A 7 s synthetic street (70 sweeps): two windows of 1 s history + 5 s future."""
    return generate_synthetic_log(np.random.default_rng(7), SyntheticConfig(duration=7.0), "synthetic_7")
