"""Actor boxes: poses from tracks, regions, ray tests and angular windows."""

from __future__ import annotations

import numpy as np
import pytest

from advsim_ros.core.lidar.boxes import (
    AngularWindow,
    actor_region,
    inside,
    invert_rigid,
    rays_hit_region,
    removal_region,
    to_box_frame,
    track_pose_at,
    yaw_pose,
)
from advsim_ros.core.lidar.sensor import unit_directions
from advsim_ros.core.types import ActorClass, ActorTrack, SensorModel


def test_a_track_has_a_pose_only_at_its_own_stamps() -> None:
    track = ActorTrack(
        "7", ActorClass.VEHICLE, np.array([4.0, 2.0, 1.5]), np.array([10, 20]), np.zeros((2, 3)), np.array([0.0, 1.0])
    )
    pose = track_pose_at(track, 20)
    assert pose is not None
    assert np.arctan2(pose[1, 0], pose[0, 0]) == pytest.approx(1.0)
    assert track_pose_at(track, 15) is None
    assert track_pose_at(track, 30) is None


def test_points_are_inside_a_grown_box_in_its_own_frame() -> None:
    pose = yaw_pose([10.0, 5.0, 0.75], np.pi / 2)
    region = removal_region(np.array([4.0, 2.0, 1.5]), margin=0.2)
    points = np.array([[10.0, 7.1, 0.75], [10.0, 7.3, 0.75], [11.1, 5.0, 0.0]])
    assert inside(to_box_frame(points, pose), region).tolist() == [True, False, True]
    raised = actor_region(np.array([4.0, 2.0, 1.5]), margin=0.2, ground_clearance=0.1)
    assert inside(to_box_frame(points, pose), raised).tolist() == [True, False, False]  # the last one is ground
    assert np.allclose(invert_rigid(pose) @ pose, np.eye(4))


def test_rays_crossing_a_box_are_told_from_rays_passing_it() -> None:
    pose = yaw_pose([10.0, 0.0, 0.0], 0.3)
    region = removal_region(np.array([4.0, 2.0, 1.5]), margin=0.0)
    directions = unit_directions(np.zeros(3), np.array([0.0, 0.2, 0.5]))
    assert rays_hit_region(np.zeros(3), directions, pose, region).tolist() == [True, False, False]
    behind = rays_hit_region(np.zeros(3), -directions[:1], pose, region)
    assert behind.tolist() == [False]  # the box lies behind the ray's origin


def test_the_angular_window_holds_every_ray_that_can_meet_the_box() -> None:
    sensor = SensorModel(np.deg2rad(np.linspace(2.0, -24.0, 32)), np.deg2rad(0.2), 1.0, 100.0)
    region = removal_region(np.array([4.5, 1.9, 1.6]), margin=0.2)
    for center in ([-8.0, 0.5, -0.9], [6.0, -3.0, -0.9], [-7.0, -0.2, -0.9]):  # the last straddles +-pi
        pose = yaw_pose(center, 0.4)
        window = AngularWindow.of_region(pose, region, margin=0.0)
        rows = window.rows(sensor)
        columns = window.columns(sensor)
        all_rows, all_columns = np.meshgrid(np.arange(sensor.num_beams), np.arange(sensor.num_azimuths), indexing="ij")
        directions = unit_directions(
            sensor.beam_elevations[all_rows.ravel()], (all_columns.ravel() + 0.5) * sensor.azimuth_resolution
        )
        crossing = rays_hit_region(np.zeros(3), directions, pose, region)
        assert np.all(np.isin(all_rows.ravel()[crossing], rows))
        assert np.all(np.isin(all_columns.ravel()[crossing], columns))
        assert not window.full_turn
    around = AngularWindow.of_region(yaw_pose([0.5, 0.0, 0.0], 0.0), region, margin=0.0)
    assert around.full_turn  # the sensor stands inside the box's footprint
