"""The stack's plan on the wire: nav_msgs/Path <-> Plan (positions, headings, stamps)."""

from __future__ import annotations

import math
import struct

import numpy as np

from advsim_ros.contract import names
from advsim_ros.contract.codec import (
    CDR_LE_HEADER,
    ContractError,
    Msg,
    cdr_align,
    cdr_header,
    header_msg,
    message,
    stamp_ns,
)
from advsim_ros.core.geometry import tangent_headings
from advsim_ros.core.types import FloatArray, Plan

PLAN_STEP_NS = 100_000_000  # poses stamped 0 (stacks that stamp only the header) are taken this far apart [ns]


def path_msg(plan: Plan, header_stamp_ns: int, frame_id: str, z: float = 0.0) -> Msg:
    """A Plan as nav_msgs/Path: header at the sweep's stamp, each pose at its own future time, at height z [m]."""
    poses = []
    for stamp, (x, y), yaw in zip(plan.stamps_ns.tolist(), plan.xy.tolist(), plan.yaws.tolist(), strict=True):
        orientation = message(names.QUATERNION, x=0.0, y=0.0, z=math.sin(yaw / 2.0), w=math.cos(yaw / 2.0))
        position = message(names.POINT, x=x, y=y, z=float(z))
        poses.append(
            message(
                names.POSE_STAMPED,
                header=header_msg(stamp, frame_id),
                pose=message(names.POSE, position=position, orientation=orientation),
            )
        )
    return message(names.PATH, header=header_msg(header_stamp_ns, frame_id), poses=poses)


def path_cdr(plan: Plan, header_stamp_ns: int, frame_id: str, z: float = 0.0) -> bytes:
    """CDR of path_msg(plan, header_stamp_ns, frame_id, z), byte for byte, written without message objects."""
    payload = bytearray()
    cdr_header(payload, header_stamp_ns, frame_id)
    cdr_align(payload, 4)
    payload.extend(struct.pack("<I", plan.stamps_ns.shape[0]))
    for stamp, (x, y), yaw in zip(plan.stamps_ns.tolist(), plan.xy.tolist(), plan.yaws.tolist(), strict=True):
        cdr_header(payload, stamp, frame_id)
        cdr_align(payload, 8)
        payload.extend(struct.pack("<7d", x, y, float(z), 0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0)))
    return CDR_LE_HEADER + bytes(payload)


def without_orientation(quaternions: FloatArray) -> bool:
    """Whether (N, 4) quaternions [x, y, z, w] say nothing about heading: every one is the identity (or all
    zeros, never filled in), as in spatial paths whose poses carry positions only."""
    return bool(np.all(quaternions[:, :3] == 0.0))


def plan_from_path(path: Msg, time_offset_ns: int = 0) -> Plan:
    """A nav_msgs/Path (rclpy or rosbags object) as a Plan, pose stamps shifted by -time_offset_ns.

    Poses stamped 0 (stacks that stamp only the header) are taken as 0.1 s apart after the header.
    A path whose every orientation is the identity carries no headings: they come from the path's
    tangent (core.geometry.tangent_headings), not a heading of 0 for every pose.
    ContractError for an empty path, non-finite poses or stamps that do not increase.
    """
    poses = path.poses
    if not poses:
        raise ContractError("the plan (nav_msgs/Path) has no poses")
    header_ns = stamp_ns(path.header.stamp)
    stamps = np.array([stamp_ns(pose.header.stamp) for pose in poses], dtype=np.int64)
    if np.all(stamps == 0):
        stamps = header_ns + PLAN_STEP_NS * np.arange(1, len(poses) + 1, dtype=np.int64)
    xy = np.array([[pose.pose.position.x, pose.pose.position.y] for pose in poses], dtype=np.float64)
    quaternions = np.array(
        [[p.pose.orientation.x, p.pose.orientation.y, p.pose.orientation.z, p.pose.orientation.w] for p in poses]
    )
    if not (np.all(np.isfinite(xy)) and np.all(np.isfinite(quaternions))):
        raise ContractError("the plan (nav_msgs/Path) has NaN or infinite poses")
    if np.any(np.diff(stamps) <= 0):
        raise ContractError("the plan's pose stamps are not strictly increasing")
    x, y, z, w = quaternions.T
    yaws = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    if without_orientation(quaternions):
        yaws = tangent_headings(xy, yaws)
    return Plan(stamps_ns=stamps - time_offset_ns, xy=xy, yaws=yaws)
