"""KITTI tracking import: frames through the calibration, real sequence 0000, and bad input."""

from __future__ import annotations

import logging
import tarfile
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from advsim_ros.core.types import ActorClass, Scenario
from advsim_ros.io.kitti import (
    KITTI_FRAME_PERIOD_NS,
    KittiError,
    kitti_velodyne_dir,
    load_kitti_tracking,
    read_kitti_calibration,
)

Box = tuple[np.ndarray, float, np.ndarray]  # centre (3,) [m], yaw [rad], (length, width, height) [m]

# A calibration with the textbook axes: camera x right = -Velodyne y, camera y down = -Velodyne z,
# camera z forward = Velodyne x; rectification is the identity.
MINI_CALIB = """P0: 700 0 600 0 0 700 180 0 0 0 1 0
R0_rect: 1 0 0 0 1 0 0 0 1
Tr_velo_to_cam: 0 -1 0 0 0 0 -1 0 1 0 0 0
Tr_imu_to_velo: 1 0 0 0 0 1 0 0 0 0 1 0
"""
# One car 10 m ahead, 2 m to the left, heading along Velodyne +x; bottom 1.5 m below the sensor.
MINI_LABELS = """0 -1 DontCare -1 -1 -10 0 0 1 1 -1000 -1000 -1000 -1000 -1000 -1000 -10
0 7 Car 0 0 0 100 100 200 200 1.5 1.8 4.0 -2.0 1.5 10.0 -1.5707963267948966
1 7 Car 0 0 0 100 100 200 200 1.5 1.8 4.0 -2.0 1.5 11.0 -1.5707963267948966
2 7 Car 0 0 0 100 100 200 200 1.5 1.8 4.0 -2.0 1.5 12.0 -1.5707963267948966
"""


def _pose_row(x: float) -> str:
    return f"1 0 0 {x} 0 1 0 0 0 0 1 0\n"


def _mini_kitti(root: Path, sweeps: int = 3, poses: str | None = None, labels: str = MINI_LABELS) -> Path:
    (root / "calib").mkdir(parents=True)
    (root / "calib" / "0000.txt").write_text(MINI_CALIB)
    (root / "label_02").mkdir()
    (root / "label_02" / "0000.txt").write_text(labels)
    (root / "poses").mkdir()
    (root / "poses" / "0000_test_velo.txt").write_text(poses or "".join(_pose_row(i) for i in range(sweeps)))
    folder = root / "velodyne" / "0000"
    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for index in range(sweeps):
        rng.uniform(-5, 5, (10 + index, 4)).astype(np.float32).tofile(folder / f"{index:06d}.bin")
    return root


def test_a_box_moves_from_the_camera_frame_to_the_velodyne_and_world_frames(tmp_path: Path) -> None:
    scenario = load_kitti_tracking(_mini_kitti(tmp_path), "0000")
    (car,) = scenario.actors
    assert car.actor_id == "7"
    assert car.actor_class is ActorClass.VEHICLE
    np.testing.assert_allclose(car.size, [4.0, 1.8, 1.5])
    # World = first sweep's Velodyne frame; the sensor moves +1 m in x per frame, the car +1 m in depth.
    np.testing.assert_allclose(car.centers, [[10.0, 2.0, -0.75], [12.0, 2.0, -0.75], [14.0, 2.0, -0.75]], atol=1e-12)
    np.testing.assert_allclose(car.yaws, 0.0, atol=1e-12)
    np.testing.assert_array_equal(car.stamps_ns, scenario.frame_stamps_ns)
    assert np.all(np.diff(scenario.frame_stamps_ns) == KITTI_FRAME_PERIOD_NS)


def test_the_ego_frame_is_the_velodyne_frame_moved_down_to_the_ground(tmp_path: Path) -> None:
    scenario = load_kitti_tracking(_mini_kitti(tmp_path), "0000")
    np.testing.assert_allclose(scenario.ego_T_sensor[:3, 3], [0.0, 0.0, 1.73])
    for index, sweep in enumerate(scenario.sweeps):
        np.testing.assert_allclose(scenario.ego.poses[index] @ scenario.ego_T_sensor, sweep.sensor_pose, atol=1e-12)
    np.testing.assert_allclose(scenario.ego.xy[:, 0], [0.0, 1.0, 2.0])
    assert [sweep.num_points for sweep in scenario.sweeps] == [10, 11, 12]
    assert scenario.sweeps[0].points.dtype.names == ("x", "y", "z", "intensity")


def test_camera_poses_are_turned_into_velodyne_poses_through_the_calibration(tmp_path: Path) -> None:
    root = _mini_kitti(tmp_path)
    # The camera moves 1 m forward per frame along its own z axis = Velodyne x.
    (root / "poses" / "0000_test_cam0.txt").write_text("".join(f"1 0 0 0 0 1 0 0 0 0 1 {i}\n" for i in range(3)))
    scenario = load_kitti_tracking(root, "0000", poses=root / "poses" / "0000_test_cam0.txt")
    np.testing.assert_allclose(scenario.ego.xy, [[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]], atol=1e-12)


def test_a_nan_pose_is_rejected_naming_the_file_and_line(tmp_path: Path) -> None:
    root = _mini_kitti(tmp_path, poses=_pose_row(0) + "1 0 0 nan 0 1 0 0 0 0 1 0\n" + _pose_row(2))
    with pytest.raises(KittiError, match=r"0000_test_velo.txt line 2: pose contains NaN"):
        load_kitti_tracking(root, "0000")


def test_a_label_file_that_does_not_match_the_sweeps_is_rejected(tmp_path: Path) -> None:
    labels = MINI_LABELS + "5 7 Car 0 0 0 100 100 200 200 1.5 1.8 4.0 -2.0 1.5 12.0 0\n"
    root = _mini_kitti(tmp_path, labels=labels)
    with pytest.raises(KittiError, match="does not match the sweeps: it labels frame 5 but sequence 0000 has only 3"):
        load_kitti_tracking(root, "0000")


def test_poses_that_do_not_match_the_sweeps_are_rejected(tmp_path: Path) -> None:
    root = _mini_kitti(tmp_path, poses=_pose_row(0) + _pose_row(1))
    with pytest.raises(KittiError, match="has 2 poses but sequence 0000 has 3 sweeps"):
        load_kitti_tracking(root, "0000")


def test_a_truncated_sweep_file_is_rejected(tmp_path: Path) -> None:
    root = _mini_kitti(tmp_path)
    sweep = root / "velodyne" / "0000" / "000001.bin"
    sweep.write_bytes(sweep.read_bytes()[:-3])
    with pytest.raises(KittiError, match=r"000001.bin: 173 bytes is not a whole number of 16-byte points"):
        load_kitti_tracking(root, "0000")


def test_non_finite_points_are_dropped_at_import_and_counted_in_the_log(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    root = _mini_kitti(tmp_path)
    sweep = root / "velodyne" / "0000" / "000001.bin"
    points = np.fromfile(sweep, dtype=np.float32).reshape(-1, 4)
    points[[0, 4], 0], points[7, 2], points[9, 3] = np.nan, -np.inf, np.nan  # a NaN intensity is kept
    points.tofile(sweep)
    with caplog.at_level(logging.WARNING):
        scenario = load_kitti_tracking(root, "0000")
    np.testing.assert_array_equal(scenario.sweeps[1].xyz, np.delete(points, [0, 4, 7], axis=0)[:, :3])
    assert np.isnan(scenario.sweeps[1].points["intensity"][6])  # point 9, after the three dropped before it
    assert [sweep.num_points for sweep in scenario.sweeps] == [10, 8, 12]
    assert [record.getMessage() for record in caplog.records] == [
        f"KITTI {root / 'velodyne' / '0000'}: dropped 3 non-finite points in 1 sweeps"
    ]


def test_missing_files_are_named(tmp_path: Path) -> None:
    root = _mini_kitti(tmp_path)
    (root / "calib" / "0000.txt").unlink()
    with pytest.raises(KittiError, match="calibration file not found"):
        load_kitti_tracking(root, "0000")
    with pytest.raises(KittiError, match="sequence must be four digits"):
        load_kitti_tracking(root, "0")


def _pack_sweeps(root: Path) -> Path:
    archive = root / "velodyne.tar.xz"
    with tarfile.open(archive, "w:xz") as tar:
        tar.add(root / "velodyne", arcname="velodyne")
    for file in sorted((root / "velodyne" / "0000").iterdir()):
        file.unlink()
    (root / "velodyne" / "0000").rmdir()
    (root / "velodyne").rmdir()
    return archive


def test_sweeps_are_read_from_the_archive_through_the_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    root = _mini_kitti(tmp_path / "kitti")
    expected = load_kitti_tracking(root, "0000")
    _pack_sweeps(root)
    monkeypatch.setenv("ADVSIM_CACHE_DIR", str(tmp_path / "cache"))
    scenario = load_kitti_tracking(root, "0000")
    folder = kitti_velodyne_dir(root, "0000")
    assert folder.is_relative_to(tmp_path / "cache")
    for mine, theirs in zip(scenario.sweeps, expected.sweeps, strict=True):
        np.testing.assert_array_equal(mine.points, theirs.points)


def test_a_truncated_archive_is_rejected_and_leaves_no_partial_cache(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    root = _mini_kitti(tmp_path / "kitti")
    archive = _pack_sweeps(root)
    archive.write_bytes(archive.read_bytes()[:-200])
    cache = tmp_path / "cache"
    monkeypatch.setenv("ADVSIM_CACHE_DIR", str(cache))
    with pytest.raises(KittiError, match=r"velodyne\.tar\.xz is unreadable or truncated"):
        load_kitti_tracking(root, "0000")
    assert not [path for path in cache.rglob("*") if path.is_file()]


# --------------------------------------------------------------------------- real data: KITTI tracking 0000


def test_kitti_0000_has_154_sweeps_15_tracks_and_711_boxes_without_dontcare(kitti_scenario: Scenario) -> None:
    assert kitti_scenario.num_frames == 154
    assert len(kitti_scenario.sweeps) == 154
    assert len(kitti_scenario.actors) == 15
    assert sum(len(actor.stamps_ns) for actor in kitti_scenario.actors) == 711
    classes = {actor.actor_class for actor in kitti_scenario.actors}
    assert classes == {ActorClass.VEHICLE, ActorClass.PEDESTRIAN, ActorClass.CYCLIST}
    assert all(98_000 <= sweep.num_points <= 125_000 for sweep in kitti_scenario.sweeps)


def test_kitti_0000_boxes_contain_the_lidar_points_of_their_objects(
    kitti_scenario: Scenario, points_in_boxes: Callable[[np.ndarray, list[Box]], list[int]]
) -> None:
    boxes: dict[int, list[Box]] = defaultdict(list)
    for actor in kitti_scenario.actors:
        for stamp, center, yaw in zip(actor.stamps_ns.tolist(), actor.centers, actor.yaws, strict=True):
            boxes[stamp].append((center, float(yaw), actor.size))
    counts = []
    for sweep in kitti_scenario.sweeps:
        world = np.einsum("ij,nj->ni", sweep.sensor_pose[:3, :3], sweep.xyz) + sweep.sensor_pose[:3, 3]
        counts += points_in_boxes(world, boxes[sweep.stamp_ns])
    assert len(counts) == 711
    assert sum(count == 0 for count in counts) <= 1
    assert abs(np.mean(counts) - 683) < 10  # 683 counted in the camera frame; yaw-only world boxes differ by <1 %


def test_kitti_0000_stereo_camera_poses_agree_with_the_lidar_odometry(kitti_root: Path) -> None:
    T_rect_velo = read_kitti_calibration(kitti_root / "calib" / "0000.txt")
    assert T_rect_velo.shape == (4, 4)
    lidar = load_kitti_tracking(kitti_root, "0000")
    camera = load_kitti_tracking(kitti_root, "0000", poses=kitti_root / "poses" / "0000_orbslam3_stereo_cam0.txt")
    gap = np.linalg.norm(lidar.ego.poses[:, :3, 3] - camera.ego.poses[:, :3, 3], axis=1)
    assert gap.mean() < 1.5  # the data README: 1.1 m mean, 2.1 m max over 72 m
    assert gap.max() < 2.5
    travelled = np.linalg.norm(np.diff(lidar.ego.xy, axis=0), axis=1).sum()
    assert 60 < travelled < 80
