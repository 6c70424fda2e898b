"""Messages of users' stacks that are not the contract's: parsers of their plans, builders of their inputs.

Parsers take rclpy or rosbags message objects (same field names) and give ``adapters.plans.Poses``;
builders give typestore objects, published as CDR. Type names per profile key are in ``PLAN_MSGTYPES``
and ``POSE_MSGTYPES``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from advsim_ros.adapters.plans import Poses, geodetic_of, yaw_of_quaternion
from advsim_ros.adapters.profile import Datum
from advsim_ros.contract import names
from advsim_ros.contract.codec import NS_PER_S, header_msg, message, stamp_ns
from advsim_ros.contract.spatial import odometry_pose

POSE_ARRAY = "geometry_msgs/msg/PoseArray"
POSE_WITH_COVARIANCE_STAMPED = "geometry_msgs/msg/PoseWithCovarianceStamped"
NAV_SAT_FIX = "sensor_msgs/msg/NavSatFix"
NAV_SAT_STATUS = "sensor_msgs/msg/NavSatStatus"
AUTOWARE_TRAJECTORY = "autoware_planning_msgs/msg/Trajectory"

PLAN_MSGTYPES = {
    "path": names.PATH,
    "spatial_path": names.PATH,
    "autoware_trajectory": AUTOWARE_TRAJECTORY,
    "pose_array": POSE_ARRAY,
}
POSE_MSGTYPES = {
    "odometry": names.ODOMETRY,
    "pose_stamped": names.POSE_STAMPED,
    "pose_with_covariance_stamped": POSE_WITH_COVARIANCE_STAMPED,
    "navsatfix": NAV_SAT_FIX,
}


def _poses(items: list[Any]) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) positions and (N,) headings of geometry_msgs/Pose objects."""
    values = np.array(
        [[p.position.x, p.position.y, *(getattr(p.orientation, axis) for axis in "xyzw")] for p in items],
        dtype=np.float64,
    ).reshape(-1, 6)
    return values[:, :2], yaw_of_quaternion(values[:, 2], values[:, 3], values[:, 4], values[:, 5])


def plan_poses(kind: str, msg: Any) -> Poses:
    """The poses of a stack's answer of profile type ``kind`` (timed when the message carries times)."""
    if kind in ("path", "spatial_path"):
        xy, yaws = _poses([stamped.pose for stamped in msg.poses])
        stamps = np.array([stamp_ns(stamped.header.stamp) for stamped in msg.poses], dtype=np.int64)
        timed = kind == "path" and stamps.size > 0 and bool(np.all(stamps > 0))
        return Poses(xy, yaws, stamps_ns=stamps if timed else None)
    if kind == "pose_array":
        xy, yaws = _poses(list(msg.poses))
        return Poses(xy, yaws)
    if kind == "autoware_trajectory":
        points = list(msg.points)
        xy, yaws = _poses([point.pose for point in points])
        offsets = np.array(
            [int(p.time_from_start.sec) * NS_PER_S + int(p.time_from_start.nanosec) for p in points], dtype=np.int64
        )
        if offsets.size > 1 and bool(np.all(np.diff(offsets) > 0)):
            return Poses(xy, yaws, stamps_ns=stamp_ns(msg.header.stamp) + offsets)
        speeds = np.array([p.longitudinal_velocity_mps for p in points], dtype=np.float64)
        return Poses(xy, yaws, speeds=speeds)
    raise ValueError(f"unknown plan type {kind!r}")


def pose_input(kind: str, odometry: Any, frame_id: str, datum: Datum | None) -> Any:
    """What a stack of pose type ``kind`` reads, made from the contract's nav_msgs/Odometry (world frame)."""
    stamp = stamp_ns(odometry.header.stamp)
    frame = frame_id or odometry.header.frame_id
    if kind == "odometry":
        return message(
            names.ODOMETRY,
            header=header_msg(stamp, frame),
            child_frame_id=odometry.child_frame_id,
            pose=odometry.pose,
            twist=odometry.twist,
        )
    if kind == "pose_stamped":
        return message(names.POSE_STAMPED, header=header_msg(stamp, frame), pose=odometry.pose.pose)
    if kind == "pose_with_covariance_stamped":
        return message(POSE_WITH_COVARIANCE_STAMPED, header=header_msg(stamp, frame), pose=odometry.pose)
    if kind == "navsatfix":
        assert datum is not None  # checked by PoseInput
        position = odometry.pose.pose.position
        latitude, longitude, altitude = geodetic_of(datum, position.x, position.y, position.z)
        status_type = message(NAV_SAT_STATUS, status=0, service=1)  # STATUS_FIX, SERVICE_GPS
        return message(
            NAV_SAT_FIX,
            header=header_msg(stamp, frame_id or "gnss"),
            status=status_type,
            latitude=latitude,
            longitude=longitude,
            altitude=altitude,
            position_covariance=np.zeros(9, dtype=np.float64),
            position_covariance_type=0,  # COVARIANCE_TYPE_UNKNOWN
        )
    raise ValueError(f"unknown pose type {kind!r}")


def odometry_speed(odometry: Any) -> float:
    """The ego's speed in a nav_msgs/Odometry [m/s] (its twist is in the child frame)."""
    linear = odometry.twist.twist.linear
    return float(np.hypot(linear.x, linear.y))


def odometry_xy(odometry: Any) -> np.ndarray:
    """The ego's position in the odometry's frame [m]."""
    matrix = odometry_pose(odometry, "odometry")
    return np.array(matrix[:2, 3], dtype=np.float64)
