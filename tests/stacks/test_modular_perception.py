"""Ground removal and the clustering detector on hand-built scenes with known answers, and on real KITTI sweeps."""

from __future__ import annotations

import numpy as np
import pytest

from advsim_ros.core.geometry import bev_iou
from advsim_ros.core.types import ActorClass, Scenario
from advsim_ros.stacks.interface import points_xyz, transform_points
from advsim_ros.stacks.modular.config import DetectorConfig, GroundConfig
from advsim_ros.stacks.modular.detector import CLASS_ORDER, detect
from advsim_ros.stacks.modular.ground import split_ground

GROUND = GroundConfig()
DETECTOR = DetectorConfig()


def _ground_grid(rng: np.random.Generator, slope: float = 0.0) -> np.ndarray:
    """Ground returns every ~0.3 m over 60 m x 40 m, on a plane rising `slope` m per m along x.

    None under the ego itself (a spinning LiDAR on the roof does not see the road there).
    """
    x, y = np.meshgrid(np.arange(-20.0, 40.0, 0.3), np.arange(-20.0, 20.0, 0.3))
    z = slope * x + rng.normal(0.0, 0.01, x.shape)
    points = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    under_ego = (np.abs(points[:, 0] - 0.9) < 3.0) & (np.abs(points[:, 1]) < 2.0)
    return points[~under_ego]


def _box_faces(center: tuple[float, float], yaw: float, length: float, width: float, height: float, base: float,
               sensor: np.ndarray, spacing: float = 0.08) -> np.ndarray:  # fmt: skip
    """Points on the vertical faces of a box that face the sensor (what a LiDAR sees), from `base` up."""
    points = []
    cos, sin = np.cos(yaw), np.sin(yaw)
    axes = np.array([[cos, sin], [-sin, cos]])
    half = np.array([length, width]) / 2.0
    heights = np.arange(base + 0.2, base + height, spacing)
    for axis in range(2):
        for side in (-1.0, 1.0):
            normal = side * axes[axis]
            face_center = np.asarray(center) + side * half[axis] * axes[axis]
            if normal @ (sensor - face_center) <= 0:
                continue  # faces away from the sensor
            along = np.arange(-half[1 - axis], half[1 - axis], spacing)
            grid_a, grid_h = np.meshgrid(along, heights)
            xy = face_center + grid_a.ravel()[:, None] * axes[1 - axis]
            points.append(np.column_stack([xy, grid_h.ravel()]))
    return np.concatenate(points)


def test_ground_is_split_from_objects_on_a_sloped_road_and_own_vehicle_returns_are_dropped() -> None:
    rng = np.random.default_rng(0)
    ground = _ground_grid(rng, slope=0.05)  # 5 % grade: 2 m higher at x = 40 m than at the ego
    post = np.column_stack([np.full(20, 30.0), np.full(20, 5.0), 1.5 + np.linspace(0.3, 1.5, 20)])  # 0.3..1.5 m up
    own = np.array([[0.5, 0.3, 1.0], [-1.0, 1.2, 0.8]])  # on the ego's body
    split = split_ground(np.vstack([ground, post, own]), GROUND)
    assert split.xyz.shape[0] == ground.shape[0] + post.shape[0]  # own returns gone, nothing else
    is_post = np.isin(split.xyz[:, 0], [30.0]) & np.isclose(split.xyz[:, 1], 5.0)
    assert np.all(split.is_object[is_post])
    assert not np.any(split.is_object[~is_post])  # a single plane would cut the far road into "objects"
    np.testing.assert_allclose(split.height[is_post], post[:, 2] - 1.5, atol=0.12)


@pytest.mark.parametrize("yaw", [0.0, 0.3, 1.2, -0.7])
def test_a_partly_seen_car_is_one_vehicle_box_with_its_heading_and_completed_size(yaw: float) -> None:
    rng = np.random.default_rng(1)
    sensor = np.array([0.0, 0.0])
    center, length, width = (15.0, -4.0), 4.5, 1.8
    car = _box_faces(center, yaw, length, width, 1.5, 0.0, sensor)
    split = split_ground(np.vstack([_ground_grid(rng), car]), GROUND)
    detections = detect(split, GROUND, DETECTOR, sensor)
    vehicles = detections.select(detections.classes == CLASS_ORDER.index(ActorClass.VEHICLE))
    assert vehicles.count == 1
    truth = np.array([*center, yaw, length, width])
    assert bev_iou(vehicles.boxes[0], truth) > 0.75
    heading_error = np.angle(np.exp(2j * (vehicles.boxes[0, 2] - yaw))) / 2  # boxes are symmetric under a half turn
    assert abs(heading_error) < np.deg2rad(4.0)
    assert 0.0 < vehicles.confidences[0] <= 1.0


def test_walls_bushes_and_poles_are_not_vehicles() -> None:
    rng = np.random.default_rng(2)
    sensor = np.array([0.0, 0.0])
    wall = _box_faces((10.0, 8.0), 0.0, 20.0, 0.3, 2.5, 0.0, sensor)  # 20 m long: a structure
    pole = _box_faces((8.0, -3.0), 0.0, 0.2, 0.2, 3.0, 0.0, sensor)
    bike = _box_faces((12.0, -2.0), 0.0, 1.8, 0.6, 1.7, 0.0, sensor)  # narrow: a cyclist, not a car seen end-on
    split = split_ground(np.vstack([_ground_grid(rng), wall, pole, bike]), GROUND)
    detections = detect(split, GROUND, DETECTOR, sensor)
    classes = detections.actor_classes()
    assert ActorClass.VEHICLE not in classes
    near_bike = np.linalg.norm(detections.boxes[:, :2] - [12.0, -2.0], axis=1) < 1.0
    assert [classes[i] for i in np.flatnonzero(near_bike)] == [ActorClass.CYCLIST]


def test_on_real_kitti_sweeps_the_labelled_van_ahead_is_detected_where_the_labels_put_it(
    kitti_scenario: Scenario,
) -> None:
    van = kitti_scenario.actor("0")  # KITTI track 0: the van driving ahead of the ego
    for frame in (0, 20, 40):
        sweep = kitti_scenario.sweeps[frame]
        xyz = transform_points(points_xyz(sweep.points), kitti_scenario.ego_T_sensor)
        split = split_ground(xyz, GROUND)
        detections = detect(split, GROUND, DETECTOR, kitti_scenario.ego_T_sensor[:2, 3])
        pose = kitti_scenario.ego.poses[frame]
        index = int(np.flatnonzero(van.stamps_ns == sweep.stamp_ns)[0])
        local = np.linalg.inv(pose) @ np.r_[van.centers[index], 1.0]
        truth = np.array(
            [local[0], local[1], van.yaws[index] - np.arctan2(pose[1, 0], pose[0, 0]), van.length, van.width]
        )
        vehicles = detections.select(detections.classes == CLASS_ORDER.index(ActorClass.VEHICLE))
        assert vehicles.count > 0
        assert np.max(bev_iou(vehicles.boxes, truth[None])) > 0.5, f"frame {frame}"
