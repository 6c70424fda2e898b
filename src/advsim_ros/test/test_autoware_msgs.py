"""The rosidl-built Autoware messages and the typestore's speak the same CDR, in both directions."""

import array
import dataclasses
from typing import Any

import numpy as np
from autoware_perception_msgs.msg import (
    ObjectClassification,
    PredictedObject,
    PredictedObjects,
    PredictedPath,
    Shape,
)
from autoware_planning_msgs.msg import Trajectory, TrajectoryPoint
from geometry_msgs.msg import Point32, Pose
from rclpy.serialization import deserialize_message, serialize_message

from advsim_ros.contract import codec, names


def plain(value: Any) -> Any:
    """An rclpy or rosbags message as nested dicts and lists, to compare the two kinds field by field."""
    if hasattr(value, "get_fields_and_field_types"):  # rclpy
        return {name: plain(getattr(value, name)) for name in value.get_fields_and_field_types()}
    if dataclasses.is_dataclass(value):  # rosbags; constants and __msgtype__ are dataclass fields there too
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value) if f.name[0].islower()}
    if isinstance(value, np.ndarray | array.array):
        return value.tolist()
    if isinstance(value, list | tuple):
        return [plain(item) for item in value]
    return value


def _pose(x: float, y: float) -> Pose:
    pose = Pose()
    pose.position.x, pose.position.y, pose.position.z = x, y, 0.25
    pose.orientation.z, pose.orientation.w = 0.6, 0.8
    return pose


def rclpy_trajectory() -> Trajectory:
    """Two points, every field away from its default (floats exact in float32)."""
    message = Trajectory()
    message.header.stamp.sec, message.header.stamp.nanosec = 12, 250_000_000
    message.header.frame_id = "map"
    for i in range(2):
        point = TrajectoryPoint()
        point.time_from_start.sec, point.time_from_start.nanosec = i, 500_000_000
        point.pose = _pose(1.5 + i, -2.25)
        point.longitudinal_velocity_mps = 8.5 + i
        point.lateral_velocity_mps = -0.25
        point.acceleration_mps2 = 1.75
        point.heading_rate_rps = 0.0625
        point.front_wheel_angle_rad = -0.03125
        point.rear_wheel_angle_rad = 0.015625
        message.points.append(point)
    return message


def rclpy_predicted_objects() -> PredictedObjects:
    """One object with one predicted path of two poses, every field set."""
    obj = PredictedObject()
    obj.object_id.uuid = np.arange(1, 17, dtype=np.uint8)
    obj.existence_probability = 0.875
    obj.classification = [ObjectClassification(label=ObjectClassification.PEDESTRIAN, probability=0.5)]
    kinematics = obj.kinematics
    kinematics.initial_pose_with_covariance.pose = _pose(3.0, 4.0)
    kinematics.initial_pose_with_covariance.covariance = np.arange(36, dtype=np.float64) / 8
    kinematics.initial_twist_with_covariance.twist.linear.x = 2.5
    kinematics.initial_twist_with_covariance.twist.angular.z = 0.5
    kinematics.initial_twist_with_covariance.covariance = np.full(36, 0.125)
    kinematics.initial_acceleration_with_covariance.accel.linear.x = 0.5
    kinematics.initial_acceleration_with_covariance.covariance = np.full(36, -1.5)
    path = PredictedPath()
    path.path = [_pose(3.0, 4.0), _pose(5.5, 4.0)]
    path.time_step.nanosec = 100_000_000
    path.confidence = 0.75
    kinematics.predicted_paths = [path]
    obj.shape.type = Shape.POLYGON
    obj.shape.footprint.points = [Point32(x=1.0, y=-0.5, z=0.0), Point32(x=-1.0, y=0.5, z=0.0)]
    obj.shape.dimensions.x, obj.shape.dimensions.y, obj.shape.dimensions.z = 4.5, 1.75, 1.5
    message = PredictedObjects()
    message.header.stamp.sec = 3
    message.header.frame_id = "map"
    message.objects = [obj]
    return message


def test_rclpy_autoware_messages_decode_in_the_typestore_with_every_field_and_back() -> None:
    for message, type_name in (
        (rclpy_trajectory(), names.AUTOWARE_TRAJECTORY),
        (rclpy_predicted_objects(), names.AUTOWARE_PREDICTED_OBJECTS),
    ):
        raw = serialize_message(message)
        decoded = codec.decode(raw, type_name)  # rclpy -> typestore
        assert plain(decoded) == plain(message)
        # Same layout; the bytes may differ only in alignment padding, which Fast CDR leaves unset.
        assert len(codec.encode(decoded)) == len(raw)
        back = deserialize_message(codec.encode(decoded), type(message))  # typestore -> rclpy
        assert plain(back) == plain(message)


def test_the_two_definitions_agree_on_constants() -> None:
    types = codec.typestore().types
    for cls, type_name in (
        (ObjectClassification, names.AUTOWARE_OBJECT_CLASSIFICATION),
        (Shape, names.AUTOWARE_SHAPE),
    ):
        ours = {k: v for k, v in vars(types[type_name]).items() if k.isupper()}
        assert ours, type_name
        assert ours == {k: getattr(cls, k) for k in ours}
