"""Fixtures for the io tests (the real data itself comes from tests/conftest.py)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from advsim_ros.core.types import Scenario
from advsim_ros.io.bag import BagConfig, write_scenario_bag


@pytest.fixture(scope="session")
def kitti_bag(kitti_scenario: Scenario, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """KITTI tracking 0000 written as an MCAP scenario bag (~300 MB in the temp folder)."""
    path = tmp_path_factory.mktemp("kitti") / "kitti_0000"
    return write_scenario_bag(kitti_scenario, path, source="kitti_tracking/0000")


def count_points_in_boxes(points_world: np.ndarray, boxes: list[tuple[np.ndarray, float, np.ndarray]]) -> list[int]:
    """LiDAR points (N, 3) inside each upright box (centre (3,), yaw, (length, width, height)) of one frame."""
    points = points_world[np.argsort(points_world[:, 0])]
    counts = []
    for center, yaw, size in boxes:
        reach = 0.5 * float(np.hypot(size[0], size[1]))  # only points this close in x can be inside
        start, stop = np.searchsorted(points[:, 0], [center[0] - reach, center[0] + reach])
        offset = points[start:stop] - center
        cos, sin = np.cos(yaw), np.sin(yaw)
        along = offset[:, 0] * cos + offset[:, 1] * sin
        across = -offset[:, 0] * sin + offset[:, 1] * cos
        upright = np.abs(offset[:, 2]) <= size[2] / 2
        inside = (np.abs(along) <= size[0] / 2) & (np.abs(across) <= size[1] / 2) & upright
        counts.append(int(inside.sum()))
    return counts


@pytest.fixture(scope="session")
def points_in_boxes() -> Callable[[np.ndarray, list[tuple[np.ndarray, float, np.ndarray]]], list[int]]:
    """An independent point-in-box counter (tests do not trust the code under test for it)."""
    return count_points_in_boxes


def assert_scenarios_equal(read: Scenario, written: Scenario, pose_atol: float = 1e-9) -> None:
    """Everything a scenario holds is the same; poses pass through quaternions, so within pose_atol."""
    assert read.scenario_id == written.scenario_id
    np.testing.assert_array_equal(read.frame_stamps_ns, written.frame_stamps_ns)
    np.testing.assert_allclose(read.ego.poses, written.ego.poses, rtol=0, atol=pose_atol)
    np.testing.assert_allclose(read.ego_T_sensor, written.ego_T_sensor, rtol=0, atol=pose_atol)
    np.testing.assert_array_equal(read.ego_geometry.size, written.ego_geometry.size)
    assert read.ego_geometry.forward_offset == written.ego_geometry.forward_offset
    assert [actor.actor_id for actor in read.actors] == [actor.actor_id for actor in written.actors]
    for mine, theirs in zip(read.actors, written.actors, strict=True):
        assert mine.actor_class is theirs.actor_class
        np.testing.assert_array_equal(mine.size, theirs.size)
        np.testing.assert_array_equal(mine.stamps_ns, theirs.stamps_ns)
        np.testing.assert_array_equal(mine.centers, theirs.centers)
        np.testing.assert_array_equal(mine.yaws, theirs.yaws)
    assert len(read.sweeps) == len(written.sweeps)
    for mine_sweep, their_sweep in zip(read.sweeps, written.sweeps, strict=True):
        assert mine_sweep.stamp_ns == their_sweep.stamp_ns
        assert mine_sweep.frame_id == their_sweep.frame_id
        assert mine_sweep.points.dtype == their_sweep.points.dtype
        assert mine_sweep.points.tobytes() == their_sweep.points.tobytes()
        np.testing.assert_allclose(mine_sweep.sensor_pose, their_sweep.sensor_pose, rtol=0, atol=pose_atol)
    assert (read.sensor is None) == (written.sensor is None)
    if read.sensor is not None and written.sensor is not None:
        np.testing.assert_array_equal(read.sensor.beam_elevations, written.sensor.beam_elevations)
        assert read.sensor.azimuth_resolution == written.sensor.azimuth_resolution
        assert (read.sensor.min_range, read.sensor.max_range) == (written.sensor.min_range, written.sensor.max_range)
    assert (read.road_map is None) == (written.road_map is None)
    if read.road_map is not None and written.road_map is not None:
        for mine_lines, their_lines in (
            (read.road_map.drivable_areas, written.road_map.drivable_areas),
            (read.road_map.lane_centerlines, written.road_map.lane_centerlines),
        ):
            assert len(mine_lines) == len(their_lines)
            for mine_line, their_line in zip(mine_lines, their_lines, strict=True):
                np.testing.assert_array_equal(mine_line, their_line)


@pytest.fixture(scope="session")
def scenarios_equal() -> Callable[[Scenario, Scenario], None]:
    """Asserts that a scenario read back equals the one written (see assert_scenarios_equal)."""
    return assert_scenarios_equal


# --------------------------------------------------------------------------- users' own bags


_JAZZY = get_typestore(Stores.ROS2_JAZZY)
_T = _JAZZY.types
UserMessage = tuple[str, str, int, Any]  # topic, type, log time [ns], message


class UserBags:
    """Bags as a user's recorder makes them: /velodyne_points with ring and time, 50 Hz /odom and /tf
    in frame "odom", and a two-step static mount base_link -> roof -> velodyne (LiDAR turned 90 degrees)."""

    sweep_stamps = tuple(10**9 + 100_000_000 * i for i in range(4))

    @staticmethod
    def ego_pose(stamp: int) -> np.ndarray:
        """The user's ego drives at 5 m/s along x while turning at 0.2 rad/s (t from 0 s)."""
        seconds = stamp * 1e-9
        yaw = 0.2 * seconds
        pose = np.eye(4)
        pose[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
        pose[:3, 3] = [5.0 * seconds, 0.0, 0.0]
        return pose

    @staticmethod
    def points(count: int) -> np.ndarray:
        """x, y, z, intensity float32, ring uint16, time float64, with padding as drivers lay them out."""
        dtype = np.dtype(
            {
                "names": ["x", "y", "z", "intensity", "ring", "time"],
                "formats": ["<f4", "<f4", "<f4", "<f4", "<u2", "<f8"],
                "offsets": [0, 4, 8, 16, 20, 24],
                "itemsize": 32,
            }
        )
        points = np.zeros(count, dtype=dtype)
        points["x"] = np.linspace(1, 30, count)
        points["ring"] = np.arange(count) % 64
        points["time"] = np.linspace(0, 0.1, count)
        return points

    @staticmethod
    def _time(stamp: int) -> Any:
        return _T["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9)

    def _tf(self, stamp: int, parent: str, child: str, matrix: np.ndarray) -> Any:
        x, y, z, w = Rotation.from_matrix(matrix[:3, :3]).as_quat()
        return _T["geometry_msgs/msg/TransformStamped"](
            header=_T["std_msgs/msg/Header"](stamp=self._time(stamp), frame_id=parent),
            child_frame_id=child,
            transform=_T["geometry_msgs/msg/Transform"](
                translation=_T["geometry_msgs/msg/Vector3"](x=matrix[0, 3], y=matrix[1, 3], z=matrix[2, 3]),
                rotation=_T["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w),
            ),
        )

    def _odometry(self, stamp: int, matrix: np.ndarray) -> Any:
        transform = self._tf(stamp, "odom", "base_link", matrix).transform
        zero = _T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
        return _T["nav_msgs/msg/Odometry"](
            header=_T["std_msgs/msg/Header"](stamp=self._time(stamp), frame_id="odom"),
            child_frame_id="base_link",
            pose=_T["geometry_msgs/msg/PoseWithCovariance"](
                pose=_T["geometry_msgs/msg/Pose"](
                    position=_T["geometry_msgs/msg/Point"](**{a: getattr(transform.translation, a) for a in "xyz"}),
                    orientation=transform.rotation,
                ),
                covariance=np.zeros(36),
            ),
            twist=_T["geometry_msgs/msg/TwistWithCovariance"](
                twist=_T["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=np.zeros(36)
            ),
        )

    def _cloud(self, stamp: int, points: np.ndarray, drop: str) -> Any:
        datatypes = {"f4": 7, "f8": 8, "u1": 2, "u2": 4}
        fields = [
            _T["sensor_msgs/msg/PointField"](
                name=name, offset=points.dtype.fields[name][1], datatype=datatypes[points.dtype[name].str[1:]], count=1
            )
            for name in points.dtype.names
            if name != drop
        ]
        return _T["sensor_msgs/msg/PointCloud2"](
            header=_T["std_msgs/msg/Header"](stamp=self._time(stamp), frame_id="velodyne"),
            height=1,
            width=len(points),
            fields=fields,
            is_bigendian=False,
            point_step=points.dtype.itemsize,
            row_step=points.dtype.itemsize * len(points),
            data=points.view(np.uint8),
            is_dense=True,
        )

    def messages(
        self, *, lidar_topic: str = "/velodyne_points", drop_field: str = "", nan_at: int | None = None
    ) -> list[UserMessage]:
        """The recording; ``drop_field`` leaves a PointField out, ``nan_at`` poisons one odometry pose."""
        mount = np.eye(4)
        mount[:3, 3] = [0.5, 0.0, 1.9]
        lidar = np.eye(4)
        lidar[:2, :2] = [[0.0, -1.0], [1.0, 0.0]]
        static = [self._tf(0, "base_link", "roof", mount), self._tf(0, "roof", "velodyne", lidar)]
        messages: list[UserMessage] = [
            ("/tf_static", "tf2_msgs/msg/TFMessage", 0, _T["tf2_msgs/msg/TFMessage"](transforms=static))
        ]
        for index in range(20):
            stamp = 10**9 - 50_000_000 + 20_000_000 * index  # 50 Hz, offset from the sweeps, covering them
            pose = self.ego_pose(stamp)
            if nan_at == index:
                pose[0, 3] = np.nan
            messages.append(("/odom", "nav_msgs/msg/Odometry", stamp, self._odometry(stamp, pose)))
            transforms = _T["tf2_msgs/msg/TFMessage"](transforms=[self._tf(stamp, "odom", "base_link", pose)])
            messages.append(("/tf", "tf2_msgs/msg/TFMessage", stamp, transforms))
        for stamp in self.sweep_stamps:
            cloud = self._cloud(stamp, self.points(25), drop_field)
            messages.append((lidar_topic, "sensor_msgs/msg/PointCloud2", stamp + 3_000_000, cloud))  # received later
        return messages

    @staticmethod
    def write(path: Path, messages: list[UserMessage], storage: StoragePlugin = StoragePlugin.MCAP) -> Path:
        with Writer(path, version=9, storage_plugin=storage) as writer:
            connections: dict[str, Any] = {}
            for topic, msgtype, stamp, message in sorted(messages, key=lambda item: item[2]):
                if topic not in connections:
                    connections[topic] = writer.add_connection(topic, msgtype, typestore=_JAZZY)
                writer.write(connections[topic], stamp, _JAZZY.serialize_cdr(message, msgtype))
        return path


USER_BAG_CONFIG = BagConfig(lidar_topic="/velodyne_points", odom_topic="/odom", world_frame="odom")


@pytest.fixture(scope="session")
def user_bags() -> UserBags:
    """Builds bags as a user's recorder makes them (see UserBags)."""
    return UserBags()


@pytest.fixture(scope="session")
def user_bag_config() -> BagConfig:
    """The bag parameters a user sets for the bags of UserBags."""
    return USER_BAG_CONFIG
