"""Messages of users' stacks that are not the contract's: parsers of their plans, builders of their inputs.

Parsers take rclpy or rosbags message objects (same field names) and give ``adapters.plans.Poses``;
builders give typestore objects, published as CDR. Type names per profile key are in ``PLAN_MSGTYPES``
and ``POSE_MSGTYPES``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from advsim_ros.adapters.plans import PlanarTransform, Poses, geodetic_of, yaw_of_quaternion
from advsim_ros.adapters.profile import Datum
from advsim_ros.contract import names
from advsim_ros.contract.codec import NS_PER_S, Msg, header_msg, message, stamp_ns
from advsim_ros.contract.plan import without_orientation
from advsim_ros.contract.spatial import odometry_pose
from advsim_ros.contract.tracks import TrackRecord, track_array_from_msg
from advsim_ros.core.futures import interpolate_trajectory
from advsim_ros.core.types import ActorClass, IntArray

POSE_ARRAY = "geometry_msgs/msg/PoseArray"
POSE_WITH_COVARIANCE_STAMPED = "geometry_msgs/msg/PoseWithCovarianceStamped"
NAV_SAT_FIX = "sensor_msgs/msg/NavSatFix"
NAV_SAT_STATUS = "sensor_msgs/msg/NavSatStatus"

PLAN_MSGTYPES = {
    "path": names.PATH,
    "spatial_path": names.PATH,
    "autoware_trajectory": names.AUTOWARE_TRAJECTORY,
    "pose_array": POSE_ARRAY,
}
DETECTION_MSGTYPES = {
    "actor_tracks": names.ACTOR_TRACK_ARRAY,
    "autoware_detected_objects": names.AUTOWARE_DETECTED_OBJECTS,
    "autoware_tracked_objects": names.AUTOWARE_TRACKED_OBJECTS,
    "marker_array": names.MARKER_ARRAY,
}
PREDICTION_MSGTYPES = {
    "actor_tracks": names.ACTOR_TRACK_ARRAY,
    "autoware_predicted_objects": names.AUTOWARE_PREDICTED_OBJECTS,
}
# Autoware's ObjectClassification labels -> the project's classes (unknown, animal, hazard, ... -> other)
AUTOWARE_CLASSES = {1: ActorClass.VEHICLE, 2: ActorClass.VEHICLE, 3: ActorClass.VEHICLE, 4: ActorClass.VEHICLE,
                    5: ActorClass.CYCLIST, 6: ActorClass.CYCLIST, 7: ActorClass.PEDESTRIAN}  # fmt: skip
MARKER_CUBE, MARKER_ADD = 1, 0  # visualization_msgs/Marker type CUBE, action ADD
POSE_MSGTYPES = {
    "odometry": names.ODOMETRY,
    "pose_stamped": names.POSE_STAMPED,
    "pose_with_covariance_stamped": POSE_WITH_COVARIANCE_STAMPED,
    "navsatfix": NAV_SAT_FIX,
}


def _poses(items: list[Msg]) -> tuple[np.ndarray, np.ndarray, bool]:
    """(N, 2) positions and (N,) headings of geometry_msgs/Pose objects, and whether they carry orientations."""
    values = np.array(
        [[p.position.x, p.position.y, *(getattr(p.orientation, axis) for axis in "xyzw")] for p in items],
        dtype=np.float64,
    ).reshape(-1, 6)
    yaws = yaw_of_quaternion(values[:, 2], values[:, 3], values[:, 4], values[:, 5])
    return values[:, :2], yaws, not without_orientation(values[:, 2:])


def plan_poses(kind: str, msg: Msg) -> Poses:
    """The poses of a stack's answer of profile type ``kind`` (timed when the message carries times)."""
    if kind in ("path", "spatial_path"):
        xy, yaws, oriented = _poses([stamped.pose for stamped in msg.poses])
        stamps = np.array([stamp_ns(stamped.header.stamp) for stamped in msg.poses], dtype=np.int64)
        timed = kind == "path" and stamps.size > 0 and bool(np.all(stamps > 0))
        return Poses(xy, yaws, stamps_ns=stamps if timed else None, oriented=oriented)
    if kind == "pose_array":
        xy, yaws, oriented = _poses(list(msg.poses))
        return Poses(xy, yaws, oriented=oriented)
    if kind == "autoware_trajectory":
        points = list(msg.points)
        xy, yaws, oriented = _poses([point.pose for point in points])
        offsets = np.array(
            [int(p.time_from_start.sec) * NS_PER_S + int(p.time_from_start.nanosec) for p in points], dtype=np.int64
        )
        if offsets.size > 1 and bool(np.all(np.diff(offsets) > 0)):
            return Poses(xy, yaws, stamps_ns=stamp_ns(msg.header.stamp) + offsets, oriented=oriented)
        speeds = np.array([p.longitudinal_velocity_mps for p in points], dtype=np.float64)
        return Poses(xy, yaws, speeds=speeds, oriented=oriented)
    raise ValueError(f"unknown plan type {kind!r}")


def pose_input(kind: str, odometry: Msg, frame_id: str, datum: Datum | None) -> Msg:
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


def odometry_speed(odometry: Msg) -> float:
    """The ego's speed in a nav_msgs/Odometry [m/s] (its twist is in the child frame)."""
    linear = odometry.twist.twist.linear
    return float(np.hypot(linear.x, linear.y))


def odometry_xy(odometry: Msg) -> np.ndarray:
    """The ego's position in the odometry's frame [m]."""
    matrix = odometry_pose(odometry, "odometry")
    return np.array(matrix[:2, 3], dtype=np.float64)


def _box(
    actor_id: str,
    actor_class: ActorClass,
    confidence: float,
    size: Msg,
    stamps_ns: Sequence[int] | IntArray,
    poses: list[Msg],
) -> TrackRecord:
    """A track of boxes at the poses (geometry_msgs/Pose), one per stamp; speeds and curvatures unknown (0)."""
    values = np.array(
        [[p.position.x, p.position.y, p.position.z, *(getattr(p.orientation, axis) for axis in "xyzw")] for p in poses],
        dtype=np.float64,
    ).reshape(-1, 7)
    zeros = np.zeros(values.shape[0])
    return TrackRecord(
        actor_id=actor_id,
        actor_class=actor_class,
        size=np.array([size.x, size.y, size.z], dtype=np.float64),
        confidence=float(confidence),
        stamps_ns=np.asarray(stamps_ns, dtype=np.int64),
        xyz=values[:, :3],
        yaw=yaw_of_quaternion(values[:, 3], values[:, 4], values[:, 5], values[:, 6]),
        velocity=zeros,
        curvature=zeros,
        acceleration=zeros,
    )


def _autoware_class(classifications: Sequence[Msg]) -> ActorClass:
    if not len(classifications):
        return ActorClass.OTHER
    best = max(classifications, key=lambda item: float(item.probability))
    return AUTOWARE_CLASSES.get(int(best.label), ActorClass.OTHER)


def _uuid(value: Msg | None, index: int) -> str:
    digits = bytes(np.asarray(value.uuid, dtype=np.uint8)).hex() if value is not None else ""
    return digits if digits.strip("0") else f"object_{index}"


def header_of(msg: Msg) -> tuple[int, str] | None:
    """(stamp [ns], frame) of an answer: its header's, a MarkerArray's first marker's; None for an empty one."""
    if hasattr(msg, "header"):
        return stamp_ns(msg.header.stamp), str(msg.header.frame_id)
    markers = list(getattr(msg, "markers", []))
    return (stamp_ns(markers[0].header.stamp), str(markers[0].header.frame_id)) if markers else None


def detection_tracks(kind: str, msg: Msg) -> list[TrackRecord]:
    """The boxes of a stack's detections of profile type ``kind``, one state each at the message's stamp."""
    if kind == "actor_tracks":
        return list(track_array_from_msg(msg).tracks)
    if kind == "marker_array":  # CUBE markers: the namespace names the class when it is one of the project's
        classes = {c.value for c in ActorClass}
        return [
            _box(
                f"{m.ns}/{m.id}",
                ActorClass(m.ns) if m.ns in classes else ActorClass.VEHICLE,
                1.0,
                m.scale,
                [stamp_ns(m.header.stamp)],
                [m.pose],
            )
            for m in msg.markers
            if int(m.type) == MARKER_CUBE and int(m.action) == MARKER_ADD
        ]
    stamp = [stamp_ns(msg.header.stamp)]
    if kind in ("autoware_detected_objects", "autoware_tracked_objects"):
        return [
            _box(
                _uuid(getattr(item, "object_id", None), index),
                _autoware_class(item.classification),
                float(item.existence_probability),
                item.shape.dimensions,
                stamp,
                [item.kinematics.pose_with_covariance.pose],
            )
            for index, item in enumerate(msg.objects)
        ]
    raise ValueError(f"unknown detections type {kind!r}")


def prediction_tracks(kind: str, msg: Msg) -> list[TrackRecord]:
    """The predicted tracks of a stack's predictions of profile type ``kind`` (each its own stamps).

    Autoware objects carry several paths with confidences: the most confident one is the prediction.
    """
    if kind == "actor_tracks":
        return list(track_array_from_msg(msg).tracks)
    if kind != "autoware_predicted_objects":
        raise ValueError(f"unknown predictions type {kind!r}")
    start = stamp_ns(msg.header.stamp)
    tracks = []
    for index, item in enumerate(msg.objects):
        paths = [path for path in item.kinematics.predicted_paths if len(path.path)]
        if not paths:
            continue
        best = max(paths, key=lambda path: float(path.confidence))
        step = int(best.time_step.sec) * NS_PER_S + int(best.time_step.nanosec)
        if step <= 0:
            continue  # a path without times cannot be compared with the future
        stamps = start + step * np.arange(len(best.path), dtype=np.int64)
        tracks.append(
            _box(
                _uuid(item.object_id, index),
                _autoware_class(item.classification),
                float(item.existence_probability),
                item.shape.dimensions,
                stamps,
                list(best.path),
            )
        )
    return tracks


def moved(track: TrackRecord, transform: PlanarTransform) -> TrackRecord:
    """The track in the world frame (its boxes in the frame world_T_frame = transform)."""
    xy, yaw = transform.apply(track.xyz[:, :2], track.yaw)
    xyz = np.column_stack([xy, track.xyz[:, 2]])
    return TrackRecord(
        track.actor_id, track.actor_class, track.size, track.confidence, track.stamps_ns, xyz,
        np.arctan2(np.sin(yaw), np.cos(yaw)), track.velocity, track.curvature, track.acceleration,
    )  # fmt: skip


def on_grid(track: TrackRecord, stamps_ns: Sequence[int] | IntArray) -> TrackRecord:
    """The track's positions and headings at these stamps (held before its first and after its last)."""
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    xy, yaw, _ = interpolate_trajectory(track.stamps_ns, track.xyz[:, :2], track.yaw, stamps)
    z = np.interp(stamps.astype(np.float64), track.stamps_ns.astype(np.float64), track.xyz[:, 2])
    zeros = np.zeros(stamps.shape[0])
    return TrackRecord(
        track.actor_id, track.actor_class, track.size, track.confidence, stamps, np.column_stack([xy, z]),
        yaw, zeros, zeros, zeros,
    )  # fmt: skip
