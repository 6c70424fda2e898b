"""The reference stacks' side of the topic contract: what a stack node keeps between messages, and its outputs.

The stacks talk to the attack graph only through topics, as a user's stack would. Inputs are
read with the contract's parsers (``advsim_ros.contract``: PointCloud2 of any layout, poses,
the road map, /tf_static); outputs are built with the contract's builders and published as
CDR: the plan as nav_msgs/Path (header stamped with the sweep's stamp, every pose at its
future time), detections and predictions as advsim_msgs/ActorTrackArray.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from scipy.spatial.transform import Rotation

from advsim_ros.contract import codec
from advsim_ros.contract.codec import Msg
from advsim_ros.contract.plan import path_cdr
from advsim_ros.contract.spatial import odometry_pose
from advsim_ros.contract.tracks import track_array_cdr
from advsim_ros.core.types import ActorClass, FloatArray, IntArray
from advsim_ros.stacks.interface import EgoMotion, ObjectTrajectories, StackOutput, ego_motion_from_poses


def mount_matrix(xyz_rpy: tuple[float, ...]) -> FloatArray:
    """(4, 4) transform from x, y, z [m] and roll, pitch, yaw [rad] (the io.sensor_mount parameter)."""
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_euler("xyz", xyz_rpy[3:6]).as_matrix()
    matrix[:3, 3] = xyz_rpy[:3]
    return matrix


class PoseBuffer:
    """Recent odometry: the ego pose at a sweep's stamp and the motion up to it."""

    def __init__(self, capacity: int) -> None:
        self._entries: deque[tuple[int, FloatArray, EgoMotion]] = deque(maxlen=capacity)
        self.world_frame = ""
        self.ego_frame = ""

    def add_odometry(self, odometry: Msg) -> None:  # nav_msgs/Odometry (rclpy)
        stamp = codec.stamp_ns(odometry.header.stamp)
        pose = odometry_pose(odometry, "odometry")
        twist = odometry.twist.twist
        motion = EgoMotion(speed=max(0.0, float(twist.linear.x)), yaw_rate=float(twist.angular.z))
        if self._entries and stamp <= self._entries[-1][0]:
            # Time went back (a new drive) or a repeat: forget what came after.
            while self._entries and self._entries[-1][0] >= stamp:
                self._entries.pop()
        self._entries.append((stamp, pose, motion))
        self.world_frame = str(odometry.header.frame_id)
        self.ego_frame = str(odometry.child_frame_id)

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


def track_arrays(
    objects: ObjectTrajectories,
) -> tuple[tuple[str, ...], tuple[ActorClass, ...], FloatArray, FloatArray, IntArray, FloatArray]:
    """A stack's objects as track_array_cdr's arrays: ActorTracks with curvature and acceleration unknown (0)."""
    count, steps = objects.count, objects.stamps_ns.shape[0]
    states = np.zeros((count, steps, 7))
    states[..., :2] = objects.xy
    states[..., 2] = objects.z[:, None]
    states[..., 3] = objects.yaws
    states[..., 4] = objects.velocities
    confidences = np.clip(objects.confidences, 0.0, 1.0)
    return objects.actor_ids, objects.actor_classes, objects.sizes, confidences, objects.stamps_ns, states


def output_messages(output: StackOutput, stamp: int, frame_id: str) -> tuple[bytes, bytes | None, bytes | None]:
    """CDR of the plan, and of the detections and predictions when the stack made them."""

    def tracks(objects: ObjectTrajectories | None) -> bytes | None:
        return None if objects is None else track_array_cdr(*track_arrays(objects), stamp, frame_id)

    plan = path_cdr(output.plan, stamp, frame_id, output.plan_z)
    return plan, tracks(output.detections), tracks(output.predictions)
