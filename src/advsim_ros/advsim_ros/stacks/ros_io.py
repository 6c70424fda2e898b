"""The reference stacks' side of the topic contract: ROS messages <-> the stacks' inputs and outputs.

The stacks talk to the attack graph only through topics, as a user's stack would, with the
ordinary rclpy message classes. Inputs: PointCloud2 (any field layout, via
io.pointcloud), Odometry and TF poses, the RoadMap. Outputs: the plan as nav_msgs/Path
(header stamped with the sweep's stamp, every pose stamped at its future time) and the
detections and predictions as advsim_msgs/ActorTrackArray.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from advsim_ros.core.types import FloatArray, RoadMap, ScenarioError
from advsim_ros.io.bag import pose_matrix
from advsim_ros.stacks.interface import (
    NS_PER_S,
    EgoMotion,
    ObjectTrajectories,
    StackOutput,
    ego_motion_from_poses,
)


def stamp_ns(stamp: Any) -> int:
    """builtin_interfaces/Time as integer nanoseconds."""
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def time_msg(value_ns: int) -> Any:
    from builtin_interfaces.msg import Time

    sec, nanosec = divmod(int(value_ns), NS_PER_S)
    return Time(sec=sec, nanosec=nanosec)


def mount_matrix(xyz_rpy: tuple[float, ...]) -> FloatArray:
    """(4, 4) transform from x, y, z [m] and roll, pitch, yaw [rad] (the io.sensor_mount parameter)."""
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_euler("xyz", xyz_rpy[3:6]).as_matrix()
    matrix[:3, 3] = xyz_rpy[:3]
    return matrix


def road_map_from_msg(message: Any) -> RoadMap | None:
    """An advsim_msgs/RoadMap as a core RoadMap; None when it carries nothing."""
    areas = tuple(np.column_stack([np.asarray(p.x), np.asarray(p.y)]) for p in message.drivable_areas)
    lanes = tuple(np.column_stack([np.asarray(p.x), np.asarray(p.y)]) for p in message.lane_centerlines)
    if not areas and not lanes:
        return None
    return RoadMap(drivable_areas=areas, lane_centerlines=lanes)


class PoseBuffer:
    """Recent odometry: the ego pose at a sweep's stamp and the motion up to it."""

    def __init__(self, capacity: int) -> None:
        self._entries: deque[tuple[int, FloatArray, EgoMotion]] = deque(maxlen=capacity)
        self.world_frame = ""
        self.ego_frame = ""

    def add_odometry(self, message: Any) -> None:
        stamp = stamp_ns(message.header.stamp)
        pose = pose_matrix(message.pose.pose.position, message.pose.pose.orientation, "odometry")
        twist = message.twist.twist
        motion = EgoMotion(speed=max(0.0, float(twist.linear.x)), yaw_rate=float(twist.angular.z))
        if self._entries and stamp <= self._entries[-1][0]:
            # Time went back (a new drive) or a repeat: forget what came after.
            while self._entries and self._entries[-1][0] >= stamp:
                self._entries.pop()
        self._entries.append((stamp, pose, motion))
        self.world_frame = str(message.header.frame_id)
        self.ego_frame = str(message.child_frame_id)

    @property
    def newest_ns(self) -> int | None:
        return self._entries[-1][0] if self._entries else None

    def lookup(self, at_ns: int, tolerance_ns: int) -> tuple[FloatArray, EgoMotion] | None:
        """Pose and motion at at_ns from the odometry nearest in time (within tolerance), else None."""
        if not self._entries:
            return None
        stamps = np.array([entry[0] for entry in self._entries], dtype=np.int64)
        nearest = int(np.argmin(np.abs(stamps - at_ns)))
        if abs(int(stamps[nearest]) - at_ns) > tolerance_ns:
            return None
        poses = np.stack([entry[1] for entry in self._entries])
        upto = stamps <= stamps[nearest]
        motion = ego_motion_from_poses(
            stamps[upto], poses[upto], int(stamps[nearest]), fallback=self._entries[nearest][2]
        )
        return self._entries[nearest][1], motion


def path_msg(output: StackOutput, header_stamp_ns: int, frame_id: str) -> Any:
    """The plan as nav_msgs/Path: header at the sweep's stamp, each pose at its own future time."""
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.msg import Path

    message = Path()
    message.header.stamp = time_msg(header_stamp_ns)
    message.header.frame_id = frame_id
    plan = output.plan
    for stamp, (x, y), yaw in zip(plan.stamps_ns.tolist(), plan.xy.tolist(), plan.yaws.tolist(), strict=True):
        pose = PoseStamped()
        pose.header.stamp = time_msg(stamp)
        pose.header.frame_id = frame_id
        pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = x, y, output.plan_z
        pose.pose.orientation.z, pose.pose.orientation.w = math.sin(0.5 * yaw), math.cos(0.5 * yaw)
        message.poses.append(pose)
    return message


def track_array_msg(objects: ObjectTrajectories, header_stamp_ns: int, frame_id: str) -> Any:
    """Objects as advsim_msgs/ActorTrackArray (query 0: the stack does not know queries)."""
    from advsim_msgs.msg import ActorState, ActorTrack, ActorTrackArray

    message = ActorTrackArray()
    message.header.stamp = time_msg(header_stamp_ns)
    message.header.frame_id = frame_id
    stamps = [time_msg(stamp) for stamp in objects.stamps_ns.tolist()]
    for index in range(objects.count):
        track = ActorTrack(
            actor_id=objects.actor_ids[index],
            actor_class=objects.actor_classes[index].value,
            length=float(objects.sizes[index, 0]),
            width=float(objects.sizes[index, 1]),
            height=float(objects.sizes[index, 2]),
            confidence=float(np.clip(objects.confidences[index], 0.0, 1.0)),
        )
        z = float(objects.z[index])
        for step, stamp in enumerate(stamps):
            x, y = objects.xy[index, step]
            track.states.append(
                ActorState(
                    stamp=stamp,
                    x=float(x),
                    y=float(y),
                    z=z,
                    yaw=float(objects.yaws[index, step]),
                    velocity=float(objects.velocities[index, step]),
                )
            )
        message.tracks.append(track)
    return message


def static_transforms(message: Any) -> dict[tuple[str, str], FloatArray]:
    """(parent, child) -> (4, 4) transform of every transform in a tf2_msgs/TFMessage."""
    transforms: dict[tuple[str, str], FloatArray] = {}
    for stamped in message.transforms:
        try:
            matrix = pose_matrix(stamped.transform.translation, stamped.transform.rotation, "tf_static")
        except ScenarioError:
            continue  # a broken transform of someone else's frames is not ours to fail on
        transforms[(str(stamped.header.frame_id), str(stamped.child_frame_id))] = matrix
    return transforms
