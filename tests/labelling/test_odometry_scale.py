"""KISS-ICP's scale on real KITTI 0000 sweeps, checked against the log's own poses and its labelled parked cars.

The labels (boxes fitted to metric LiDAR returns) say where each parked car is in the sensor frame at
every frame; an odometry with the right scale keeps every parked car in one place in the world
(``labelling.evaluation.static_track_scale``). On frames 84-153 (seven parked cars labelled at >= 20
frames), KISS-ICP (no deskewing, as ``advsim label`` runs it) keeps them in place within 2 % and its
path is as long as the log's poses; the independent ORB-SLAM3 stereo path, ~3 % longer than KISS-ICP's
over the whole log, is the one whose scale the labels reject (bench/bench_labelling.py, docs/data.md).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from advsim_ros.core.types import Scenario
from advsim_ros.io.bag import write_scenario_bag
from advsim_ros.io.kitti import read_kitti_calibration, read_kitti_poses
from advsim_ros.labelling.command import label_bag
from advsim_ros.labelling.evaluation import static_track_scale
from advsim_ros.labelling.odometry import lidar_odometry, trajectory_errors

START, COUNT = 84, 70  # the frames of kitti_few (conftest.FEW_FRAMES)


def test_kiss_icp_keeps_the_labelled_parked_cars_in_place_and_the_logged_path_length(
    kitti_few: Scenario, kitti_root: Path
) -> None:
    assert kitti_few.num_frames == COUNT
    estimate = lidar_odometry(sweep.xyz for sweep in kitti_few.sweeps)  # T_world_sensor, sweep 0 = identity
    logged = np.stack([sweep.sensor_pose for sweep in kitti_few.sweeps])
    errors = trajectory_errors(estimate, logged)
    assert errors["path_length_m"] > 25.0
    assert errors["path_length_ratio"] == pytest.approx(1.0, abs=0.02)
    scale, parked = static_track_scale(estimate, logged, kitti_few.frame_stamps_ns, kitti_few.actors)
    assert parked >= 5
    assert scale == pytest.approx(1.0, abs=0.02)
    calibration = read_kitti_calibration(kitti_root / "calib" / "0000.txt")
    orbslam = read_kitti_poses(kitti_root / "poses" / "0000_orbslam3_stereo_cam0.txt", "cam0", calibration)
    orbslam = orbslam[START : START + COUNT]
    orbslam_scale, _ = static_track_scale(orbslam, logged, kitti_few.frame_stamps_ns, kitti_few.actors)
    assert orbslam_scale < 0.98  # the check tells a path a few per cent too long


def test_label_checks_kiss_icp_against_the_bags_own_poses_when_asked(
    kitti_scenario: Scenario, crop_frames: Callable[..., Scenario], tmp_path: Path
) -> None:
    bag = write_scenario_bag(crop_frames(kitti_scenario, 20), tmp_path / "posed")
    report = label_bag(bag, tmp_path / "labelled", check_odometry=True)
    assert report.poses == "bag"
    check = report.summary["odometry_check"]
    assert check["path_length_ratio"] == pytest.approx(1.0, abs=0.02)
    assert check["scale_within_tolerance"] is True
    assert "odometry_check" not in label_bag(bag, tmp_path / "plain").summary
