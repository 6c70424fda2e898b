"""`advsim attack` checks the LiDAR clouds before anything starts: a PointCloud2 without z, a sweep of the
window with no valid point or no sweep at a history frame is one line naming the bag, topic and stamp."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from advsim_ros.attack.checks import preflight
from advsim_ros.attack.options import AttackOptions, StackSpec
from advsim_ros.attack.run import _base_overrides
from advsim_ros.core.types import ScenarioError

LIDAR = "/sensor/lidar/points"
FRAMES = 70  # the window (60 frames) from frame 0 or 5


def _bag(cloud_bags: Any, path: Path, changed: dict[int, bytes | None]) -> Path:
    """A bag with a 50-point sweep at every frame, except those ``changed`` (None: no sweep there)."""
    clouds = {frame: cloud_bags.cloud_cdr(cloud_bags.points(50, frame), frame) for frame in range(FRAMES)}
    clouds.update(changed)
    return cloud_bags.write(path, {frame: cdr for frame, cdr in clouds.items() if cdr is not None}, FRAMES)


def _preflight(bag: Path, out: Path, start: int) -> Any:
    options = AttackOptions(bag=bag, out_dir=out, stack=StackSpec.parse("reference"), window_start_frame=start)
    return preflight(options, _base_overrides(options, out / "journal.jsonl"))


def test_advsim_attack_refuses_a_pointcloud2_without_z_before_it_starts_anything(
    tmp_path: Path, cloud_bags: Any
) -> None:
    no_z = cloud_bags.points(50)[["x", "y", "intensity"]]
    bag = _bag(cloud_bags, tmp_path / "bag", {30: cloud_bags.cloud_cdr(no_z, 30)})
    out = tmp_path / "out"
    result = subprocess.run(
        [sys.executable, "-m", "advsim_ros.cli", "attack", str(bag), "--stack", "reference", "--window-start", "0",
         "-o", str(out)],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert result.returncode == 1
    assert result.stderr.splitlines() == [
        f"advsim attack: error: bag {bag}: LiDAR topic {LIDAR} at 4000000000 ns: PointCloud2 without z field(s): "
        "has fields ['x', 'y', 'intensity']"
    ]
    assert not out.exists()  # no run folder, no journal, no process


@pytest.mark.parametrize("case", ["no points", "all NaN or inf"])
def test_a_sweep_of_the_window_with_no_valid_point_is_refused(tmp_path: Path, cloud_bags: Any, case: str) -> None:
    points = cloud_bags.points(0 if case == "no points" else 40)
    points["x"][::2], points["y"][1::2] = np.nan, np.inf
    bag = _bag(cloud_bags, tmp_path / "bag", {12: cloud_bags.cloud_cdr(points, 12)})
    message = rf"bag .*: LiDAR topic {LIDAR} at 2200000000 ns: the sweep has no valid point \({len(points)} points"
    with pytest.raises(ScenarioError, match=message):
        _preflight(bag, tmp_path / "out", start=5)
    assert not (tmp_path / "out").exists()


def test_a_sweep_with_no_valid_point_outside_the_window_and_non_finite_points_in_it_pass(
    tmp_path: Path, cloud_bags: Any
) -> None:
    empty = cloud_bags.cloud_cdr(cloud_bags.points(0), 2)
    some_nan = cloud_bags.points(50, 20)
    some_nan["z"][:30] = np.nan
    bag = _bag(cloud_bags, tmp_path / "bag", {2: empty, 20: cloud_bags.cloud_cdr(some_nan, 20)})
    checked = _preflight(bag, tmp_path / "out", start=5)  # frames 5..64
    assert checked.window.window_start_frame == 5


def test_a_history_frame_without_a_sweep_is_refused(tmp_path: Path, cloud_bags: Any) -> None:
    bag = _bag(cloud_bags, tmp_path / "bag", {8: None, 40: None})
    with pytest.raises(ScenarioError, match=rf"no LiDAR sweep on {LIDAR} at the window's history frames \[8\]$"):
        _preflight(bag, tmp_path / "out", start=5)  # history 5..14; frame 40 lies in the future part
    _preflight(bag, tmp_path / "out", start=9)
