"""Poses and transforms: 4x4 matrices <-> geometry_msgs, TF and nav_msgs/Odometry."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from advsim_ros.contract import names
from advsim_ros.contract.codec import ContractError, Msg, header_msg, message
from advsim_ros.core.types import EgoTrajectory, FloatArray


def pose_matrix(translation: Msg, rotation: Msg, what: str) -> FloatArray:
    """A 4x4 transform from a ROS translation (or position) and quaternion; ContractError for NaN, bad quaternions."""
    values = np.array(
        [translation.x, translation.y, translation.z, rotation.x, rotation.y, rotation.z, rotation.w], dtype=np.float64
    )
    if not np.all(np.isfinite(values)):
        raise ContractError(f"{what}: pose contains NaN or infinite values")
    norm = float(np.linalg.norm(values[3:]))
    if abs(norm - 1.0) > 1e-3:
        raise ContractError(f"{what}: orientation quaternion has norm {norm:.6g}, not 1")
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_quat(values[3:] / norm).as_matrix()
    matrix[:3, 3] = values[:3]
    return matrix


def quaternion_msg(rotation: FloatArray) -> Msg:
    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    return message(names.QUATERNION, x=float(x), y=float(y), z=float(z), w=float(w))


def pose_msg(matrix: FloatArray) -> Msg:
    """geometry_msgs/Pose of a 4x4 transform."""
    position = message(names.POINT, x=float(matrix[0, 3]), y=float(matrix[1, 3]), z=float(matrix[2, 3]))
    return message(names.POSE, position=position, orientation=quaternion_msg(matrix[:3, :3]))


def transform_msg(matrix: FloatArray) -> Msg:
    """geometry_msgs/Transform of a 4x4 transform."""
    translation = message(names.VECTOR3, x=float(matrix[0, 3]), y=float(matrix[1, 3]), z=float(matrix[2, 3]))
    return message(names.TRANSFORM, translation=translation, rotation=quaternion_msg(matrix[:3, :3]))


def tf_message(stamp_ns: int, parent: str, child: str, matrix: FloatArray) -> Msg:
    """tf2_msgs/TFMessage with the one transform parent -> child."""
    stamped = message(
        names.TRANSFORM_STAMPED,
        header=header_msg(stamp_ns, parent),
        child_frame_id=child,
        transform=transform_msg(matrix),
    )
    return message(names.TF_MESSAGE, transforms=[stamped])


def transforms_of(tf: Msg) -> dict[tuple[str, str], FloatArray]:
    """(parent, child) -> 4x4 transform of every valid transform in a TFMessage (broken ones are skipped)."""
    transforms: dict[tuple[str, str], FloatArray] = {}
    for stamped in tf.transforms:
        try:
            matrix = pose_matrix(stamped.transform.translation, stamped.transform.rotation, "tf")
        except ContractError:
            continue  # a broken transform of someone else's frames is not ours to fail on
        transforms[(str(stamped.header.frame_id), str(stamped.child_frame_id))] = matrix
    return transforms


def _gradient(values: FloatArray, times_s: FloatArray) -> FloatArray:
    """d values / dt along axis 0 [unit/s]; zeros when there is a single sample."""
    if values.shape[0] < 2:
        return np.zeros_like(values)
    result: FloatArray = np.gradient(values, times_s, axis=0)
    return result


def odometry_msg(
    stamp_ns: int, world_frame: str, ego_frame: str, pose: FloatArray, velocity: FloatArray, yaw_rate: float
) -> Msg:
    """nav_msgs/Odometry of one ego pose (4, 4), its velocity (3,) in the ego frame [m/s] and yaw rate [rad/s]."""
    linear = message(names.VECTOR3, x=float(velocity[0]), y=float(velocity[1]), z=float(velocity[2]))
    angular = message(names.VECTOR3, x=0.0, y=0.0, z=float(yaw_rate))
    return message(
        names.ODOMETRY,
        header=header_msg(stamp_ns, world_frame),
        child_frame_id=ego_frame,
        pose=message("geometry_msgs/msg/PoseWithCovariance", pose=pose_msg(pose), covariance=np.zeros(36)),
        twist=message(
            "geometry_msgs/msg/TwistWithCovariance",
            twist=message("geometry_msgs/msg/Twist", linear=linear, angular=angular),
            covariance=np.zeros(36),
        ),
    )


def odometry_msgs(ego: EgoTrajectory, world_frame: str, ego_frame: str) -> list[Msg]:
    """nav_msgs/Odometry of every ego pose; the twist (in the ego frame) by finite differences."""
    poses = ego.poses
    times_s = (ego.stamps_ns - ego.stamps_ns[0]) * 1e-9
    velocity_world = _gradient(poses[:, :3, 3], times_s)
    yaw_rate = _gradient(np.unwrap(ego.yaws), times_s)
    velocity_ego = np.einsum("kji,kj->ki", poses[:, :3, :3], velocity_world)  # twist is in the child (ego) frame
    return [
        odometry_msg(stamp, world_frame, ego_frame, poses[index], velocity_ego[index], float(yaw_rate[index]))
        for index, stamp in enumerate(ego.stamps_ns.tolist())
    ]


def odometry_pose(odometry: Msg, what: str) -> FloatArray:
    """The 4x4 pose an Odometry message gives (child frame in header frame)."""
    pose = odometry.pose.pose
    return pose_matrix(pose.position, pose.orientation, what)
