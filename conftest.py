"""Fixtures every test shares: the real driving data beside the repository, loaded once per session.

Tests that need the data skip with a message naming the missing folder when it is absent.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from advsim_ros.core.types import Scenario
from advsim_ros.io.kitti import load_kitti_tracking

SHARED_DATA = Path(__file__).resolve().parent / "../shared/data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real driving data not found at {SHARED_DATA.resolve()} (see README, 'Data')")
    return SHARED_DATA.resolve()


@pytest.fixture(scope="session")
def kitti_root(shared_data: Path) -> Path:
    root = shared_data / "kitti_tracking_0000"
    if not root.is_dir():
        pytest.skip(f"KITTI tracking 0000 not found at {root}")
    return root


@pytest.fixture(scope="session")
def av2_logs(shared_data: Path) -> list[Path]:
    logs = sorted(path for path in (shared_data / "av2").glob("*-*-*-*-*") if path.is_dir())
    if not logs:
        pytest.skip(f"Argoverse 2 logs not found under {shared_data / 'av2'}")
    return logs


@pytest.fixture(scope="session")
def kitti_scenario(kitti_root: Path) -> Scenario:
    """KITTI tracking 0000 (the first run unpacks the Velodyne archive into the cache, ~15 s)."""
    return load_kitti_tracking(kitti_root, "0000")
