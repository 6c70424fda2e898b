"""LiDAR input as drivers record it: non-finite points dropped at ingestion and counted once in the log,
clouds checked without copying their points (the attack's preflight), sweeps with no valid point named."""

from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from advsim_ros.io.bag import BagConfig, BagError, check_lidar_sweeps, iter_bag_sweeps, read_scenario_bag

LIDAR = BagConfig().lidar_topic


def _poisoned(cloud_bags: Any, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """An organised 4 x 30 sweep (x, y, z, intensity, ring, time, padding) with NaN and inf in x, y or z of
    some points, and the mask of the points that stay."""
    points = cloud_bags.points(120, seed)
    rng = np.random.default_rng(seed)
    bad = rng.choice(120, size=17, replace=False)
    for index, point in enumerate(bad):
        points[["x", "y", "z"][index % 3]][point] = [np.nan, np.inf, -np.inf][index % 3]
    keep = np.ones(120, dtype=bool)
    keep[bad] = False
    return points, keep


def _records(points: np.ndarray, keep: np.ndarray) -> bytes:
    """The bytes of the kept points, padding included (indexing a structured array would zero the padding)."""
    return points.view(np.uint8).reshape(points.shape[0], -1)[keep].tobytes()


def test_non_finite_points_are_dropped_with_every_other_field_and_byte_kept_and_counted_once(
    tmp_path: Path, cloud_bags: Any, caplog: pytest.LogCaptureFixture
) -> None:
    poisoned = {frame: _poisoned(cloud_bags, frame) for frame in (2, 5)}
    clean = cloud_bags.points(120, 9)
    clouds = {frame: cloud_bags.cloud_cdr(points, frame, height=4) for frame, (points, _) in poisoned.items()}
    clouds[7] = cloud_bags.cloud_cdr(clean, 7, height=4)
    bag = cloud_bags.write(tmp_path / "bag", clouds, num_frames=10)
    with caplog.at_level(logging.WARNING):
        scenario = read_scenario_bag(bag)
    sweeps = {sweep.stamp_ns: sweep for sweep in scenario.sweeps}
    for frame, (points, keep) in poisoned.items():
        read = sweeps[cloud_bags.stamp(frame)].points
        assert read.dtype == points.dtype  # layout, offsets and padding as recorded
        assert read.tobytes() == _records(points, keep)  # the finite points, in order, byte for byte
    assert sweeps[cloud_bags.stamp(7)].points.tobytes() == clean.tobytes()
    warnings = [record.getMessage() for record in caplog.records if record.levelno == logging.WARNING]
    assert warnings == [f"bag {bag}: dropped 34 non-finite points in 2 sweeps of {LIDAR}"]


def test_streamed_sweeps_drop_non_finite_points_too(
    tmp_path: Path, cloud_bags: Any, caplog: pytest.LogCaptureFixture
) -> None:
    points, keep = _poisoned(cloud_bags, 3)
    bag = cloud_bags.write(tmp_path / "bag", {1: cloud_bags.cloud_cdr(points, 1)}, num_frames=3)
    with caplog.at_level(logging.WARNING):
        ((stamp, frame_id, read),) = list(iter_bag_sweeps(bag))
    assert (stamp, frame_id) == (cloud_bags.stamp(1), "lidar")
    assert read.tobytes() == _records(points, keep)
    assert [record.getMessage() for record in caplog.records] == [
        f"bag {bag}: dropped 17 non-finite points in 1 sweeps of {LIDAR}"
    ]


def test_a_clean_bag_logs_nothing(tmp_path: Path, cloud_bags: Any, caplog: pytest.LogCaptureFixture) -> None:
    bag = cloud_bags.write(tmp_path / "bag", {0: cloud_bags.cloud_cdr(cloud_bags.points(10), 0)}, num_frames=2)
    with caplog.at_level(logging.DEBUG):
        read_scenario_bag(bag)
    assert [record for record in caplog.records if record.name.startswith("advsim_ros")] == []


def test_the_check_returns_the_sweep_stamps_and_refuses_a_cloud_without_z_anywhere(
    tmp_path: Path, cloud_bags: Any
) -> None:
    good = {frame: cloud_bags.cloud_cdr(cloud_bags.points(20, frame), frame) for frame in range(6)}
    bag = cloud_bags.write(tmp_path / "good", good, num_frames=6)
    assert check_lidar_sweeps(bag, BagConfig(), [cloud_bags.stamp(1)]) == {cloud_bags.stamp(f) for f in range(6)}
    no_z = cloud_bags.points(20)[["x", "y", "intensity"]]
    bag = cloud_bags.write(tmp_path / "no_z", {**good, 4: cloud_bags.cloud_cdr(no_z, 4)}, num_frames=6)
    # frame 4 lies outside the stamps asked about: its layout is checked all the same (lidar_resim reads it)
    with pytest.raises(BagError, match=rf"bag .*no_z: LiDAR topic {LIDAR} at 1400000000 ns: PointCloud2 without z"):
        check_lidar_sweeps(bag, BagConfig(), [cloud_bags.stamp(1)])


@pytest.mark.parametrize("case", ["no points", "all NaN"])
def test_a_sweep_with_no_valid_point_is_named_when_asked_about(tmp_path: Path, cloud_bags: Any, case: str) -> None:
    points = cloud_bags.points(0 if case == "no points" else 12)
    points["z"] = np.nan
    clouds = {frame: cloud_bags.cloud_cdr(cloud_bags.points(20, frame), frame) for frame in range(6)}
    clouds[3] = cloud_bags.cloud_cdr(points, 3, height=1 if case == "no points" else 3)
    bag = cloud_bags.write(tmp_path / "bag", clouds, num_frames=6)
    assert len(check_lidar_sweeps(bag, BagConfig(), [cloud_bags.stamp(f) for f in (0, 1, 2)])) == 6
    count = 0 if case == "no points" else 12
    message = rf"LiDAR topic {LIDAR} at 1300000000 ns: the sweep has no valid point \({count} points, none with"
    with pytest.raises(BagError, match=message):
        check_lidar_sweeps(bag, BagConfig(), [cloud_bags.stamp(f) for f in (2, 3, 4)])


def test_a_bag_of_a_storage_plugin_rosbags_cannot_read_is_one_line_naming_it(tmp_path: Path, cloud_bags: Any) -> None:
    bag = cloud_bags.write(tmp_path / "bag", {0: cloud_bags.cloud_cdr(cloud_bags.points(20, 0), 0)}, num_frames=1)
    metadata = bag / "metadata.yaml"
    metadata.write_text(re.sub(r"storage_identifier: \w+", "storage_identifier: leveldb", metadata.read_text()))
    with pytest.raises(BagError, match=r"storage 'leveldb' is not one this reads \(sqlite3, mcap\)") as error:
        read_scenario_bag(bag)
    assert "report" not in str(error.value)
