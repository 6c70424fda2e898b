"""What every reference stack consumes and produces, independent of ROS.

A stack is stateful (trackers, LiDAR history) and sees one sweep at a time, as it would
over the topic contract: the points in the sensor frame, the ego pose at the sweep's
stamp, the ego -> sensor mount and the road map when there is one. It answers with a
Plan (world frame, stamped at its future times) and, optionally, the objects it
detected and predicted. The ROS nodes (``stacks/*/node.py``) and the offline replay
(``stacks/replay.py``) both drive stacks through this interface, so a bag replayed
offline and the same sweeps arriving over topics give the same plans.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from advsim_ros.core.types import ActorClass, FloatArray, IntArray, Plan, RoadMap, ScenarioError

NS_PER_S = 1_000_000_000


class StackError(ScenarioError):
    """Input a stack cannot plan from (bad pose, bad points, bad parameters); the message names it."""


@dataclass(frozen=True)
class TopicIoConfig:
    """How a stack's node reads its inputs (section ``io`` of params/stack_*.yaml; unused offline)."""

    mount_source: str = "tf_static"  # where the ego -> LiDAR mount comes from: "tf_static" (waited for) or "parameter"
    sensor_mount: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # x, y, z [m], roll, pitch, yaw [rad] of
    # the LiDAR on the ego, with mount_source "parameter"
    pose_tolerance_s: float = 0.05  # a sweep takes the odometry pose this close to its stamp [s]
    max_pending: int = 10  # sweeps waiting for their odometry; older ones are dropped with a warning
    odometry_buffer: int = 100  # odometry messages kept for pose lookup and motion estimates
    mount_wait_s: float = 2.0  # warn when a sweep has waited this long (wall clock) for /tf_static [s]

    def __post_init__(self) -> None:
        if len(self.sensor_mount) != 6 or not np.all(np.isfinite(self.sensor_mount)):
            raise StackError(f"io sensor_mount: expected 6 finite numbers, got {list(self.sensor_mount)}")
        if not (self.pose_tolerance_s >= 0 and self.mount_wait_s >= 0):
            raise StackError("io pose_tolerance_s, mount_wait_s: must be >= 0")
        if self.mount_source not in ("tf_static", "parameter"):
            raise StackError(f"io mount_source: 'tf_static' or 'parameter', got {self.mount_source!r}")
        if self.max_pending < 1 or self.odometry_buffer < 2:
            raise StackError("io max_pending must be >= 1 and odometry_buffer >= 2")


@dataclass(frozen=True, eq=False)
class EgoMotion:
    """The ego's motion at the sweep stamp, estimated from its recent poses (see ego_motion_from_poses)."""

    speed: float  # forward speed [m/s], >= 0
    yaw_rate: float  # heading rate, counter-clockwise positive [rad/s]
    acceleration: float = 0.0  # longitudinal acceleration [m/s^2]


@dataclass(frozen=True, eq=False)
class StackFrame:
    """One sweep as a stack receives it."""

    stamp_ns: int  # sweep stamp [ns]
    xyz: np.ndarray  # (N, 3) points in the sensor frame [m], float32 as they come off the wire, or float64
    world_T_ego: FloatArray  # (4, 4) ego pose at stamp_ns
    ego_T_sensor: FloatArray  # (4, 4) sensor mount on the ego
    motion: EgoMotion

    def __post_init__(self) -> None:
        xyz = np.asarray(self.xyz)
        if xyz.ndim != 2 or xyz.shape[1] != 3:
            raise StackError(f"sweep at {self.stamp_ns} ns: points must have shape (N, 3), got {xyz.shape}")
        for name in ("world_T_ego", "ego_T_sensor"):
            matrix = np.asarray(getattr(self, name), dtype=np.float64)
            if matrix.shape != (4, 4) or not np.all(np.isfinite(matrix)):
                raise StackError(f"sweep at {self.stamp_ns} ns: {name} must be a finite 4x4 transform")
            object.__setattr__(self, name, matrix)
        object.__setattr__(self, "xyz", xyz)


@dataclass(frozen=True, eq=False)
class ObjectTrajectories:
    """Objects a stack detected (one state each) or predicted (future states), in the world frame."""

    actor_ids: tuple[str, ...]  # (N,) track ids
    actor_classes: tuple[ActorClass, ...]  # (N,)
    sizes: FloatArray  # (N, 3) box length, width, height [m]
    confidences: FloatArray  # (N,) detection scores in [0, 1]
    stamps_ns: IntArray  # (T,) state times [ns], strictly increasing
    xy: FloatArray  # (N, T, 2) box centres [m]
    z: FloatArray  # (N,) box centre height [m]
    yaws: FloatArray  # (N, T) headings [rad]
    velocities: FloatArray  # (N, T) speeds along the heading [m/s]

    def __post_init__(self) -> None:
        count = len(self.actor_ids)
        steps = int(np.asarray(self.stamps_ns).shape[0])
        expected = {
            "sizes": (count, 3),
            "confidences": (count,),
            "xy": (count, steps, 2),
            "z": (count,),
            "yaws": (count, steps),
            "velocities": (count, steps),
        }
        if len(self.actor_classes) != count:
            raise StackError(f"ObjectTrajectories: {count} ids but {len(self.actor_classes)} classes")
        for name, shape in expected.items():
            array = np.asarray(getattr(self, name), dtype=np.float64)
            if array.shape != shape:
                raise StackError(f"ObjectTrajectories {name}: expected shape {shape}, got {array.shape}")
            if not np.all(np.isfinite(array)):
                raise StackError(f"ObjectTrajectories {name}: contains NaN or infinite values")
            object.__setattr__(self, name, array)
        stamps = np.asarray(self.stamps_ns, dtype=np.int64)
        if stamps.ndim != 1 or steps < 1 or np.any(np.diff(stamps) <= 0):
            raise StackError("ObjectTrajectories stamps_ns: need >= 1 strictly increasing stamps")
        object.__setattr__(self, "stamps_ns", stamps)

    @property
    def count(self) -> int:
        return len(self.actor_ids)

    def boxes(self) -> FloatArray:
        """(N, T, 5) BEV boxes [x, y, yaw, length, width] (core.geometry convention)."""
        lengths = np.broadcast_to(self.sizes[:, None, 0], self.yaws.shape)
        widths = np.broadcast_to(self.sizes[:, None, 1], self.yaws.shape)
        return np.stack([self.xy[..., 0], self.xy[..., 1], self.yaws, lengths, widths], axis=-1)


@dataclass(frozen=True, eq=False)
class StackOutput:
    """What a stack answers for one sweep."""

    plan: Plan  # world frame, stamped at its future times
    plan_z: float  # height of the plan's poses: the ego's ground height at the sweep [m]
    detections: ObjectTrajectories | None = None  # one state per object at the sweep stamp
    predictions: ObjectTrajectories | None = None  # future states per object, at the plan's stamps
    timings_s: Mapping[str, float] = field(default_factory=dict)  # wall time per stage [s]


class AutonomyStack(Protocol):
    """A stack under test, driven one sweep at a time."""

    name: str
    # whether step() gives detections and predictions: only then does its node offer those topics, since
    # the player waits at the decision frame for every output a stack offers
    perceives: bool

    def reset(self) -> None:
        """Forget every past sweep (a new drive or a jump in time)."""

    def set_road_map(self, road_map: RoadMap | None) -> None:
        """The scenario's map (drivable areas, lanes) when one is published; None when there is none."""

    def step(self, frame: StackFrame) -> StackOutput:
        """Plan from one more sweep."""
        ...


def plan_stamps(stamp_ns: int, horizon_s: float, step_s: float) -> IntArray:
    """(H,) future stamps stamp + step, ..., stamp + horizon [ns] (5 s at 0.1 s: 50 stamps)."""
    count = round(horizon_s / step_s)
    if count < 1:
        raise StackError(f"plan horizon {horizon_s} s is shorter than one step of {step_s} s")
    step_ns = round(step_s * NS_PER_S)
    result: IntArray = stamp_ns + step_ns * np.arange(1, count + 1, dtype=np.int64)
    return result


def yaw_of(matrix: FloatArray) -> float:
    """Heading about z of a (4, 4) or (3, 3) rotation [rad]."""
    return float(np.arctan2(matrix[1, 0], matrix[0, 0]))


def headings_along(xy: FloatArray, start_xy: FloatArray, start_yaw: float, min_step: float = 0.05) -> FloatArray:
    """(H,) heading of a path of positions (H, 2) [rad], starting from start_xy with start_yaw.

    A step shorter than min_step [m] (standing still) keeps the previous heading.
    """
    previous = np.vstack([start_xy[None, :], xy[:-1]])
    delta = xy - previous
    moving = np.hypot(delta[:, 0], delta[:, 1]) >= min_step
    raw = np.arctan2(delta[:, 1], delta[:, 0])
    yaws = np.empty(xy.shape[0])
    current = start_yaw
    for index in range(xy.shape[0]):  # H = 50: a loop is clearer than a masked cumulative fill
        if moving[index]:
            current = float(raw[index])
        yaws[index] = current
    return np.unwrap(yaws)


def ego_motion_from_poses(
    stamps_ns: IntArray,
    poses: FloatArray,
    at_ns: int,
    lookback_s: float = 0.2,
    fallback: EgoMotion | None = None,
    max_age_s: float = 0.5,
) -> EgoMotion:
    """Speed, yaw rate and acceleration at at_ns from poses (T, 4, 4) stamped at or before at_ns.

    Backward differences over about lookback_s (the stack only knows the past). Poses more
    than max_age_s older than at_ns are ignored (a jump in time, e.g. the next query); with
    fewer than two poses left, `fallback` (e.g. the odometry's twist) or standing still.
    """
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    keep = (stamps <= at_ns) & (stamps >= at_ns - int(max_age_s * NS_PER_S))
    stamps, poses = stamps[keep], poses[keep]
    if stamps.shape[0] < 2:
        return fallback if fallback is not None else EgoMotion(speed=0.0, yaw_rate=0.0)
    lookback_ns = int(lookback_s * NS_PER_S)
    earlier = int(np.searchsorted(stamps, stamps[-1] - lookback_ns, side="left"))
    earlier = min(earlier, stamps.shape[0] - 2)
    dt = (stamps[-1] - stamps[earlier]) / NS_PER_S
    displacement = poses[-1, :2, 3] - poses[earlier, :2, 3]
    heading = yaw_of(poses[-1])
    forward = float(displacement @ np.array([np.cos(heading), np.sin(heading)]))
    speed = max(0.0, forward / dt)
    dyaw = float(np.angle(np.exp(1j * (heading - yaw_of(poses[earlier])))))
    acceleration = 0.0
    if earlier >= 1:
        previous = max(0, int(np.searchsorted(stamps, stamps[earlier] - lookback_ns, side="left")))
        previous = min(previous, earlier - 1)
        dt_previous = (stamps[earlier] - stamps[previous]) / NS_PER_S
        earlier_heading = yaw_of(poses[earlier])
        earlier_forward = float(
            (poses[earlier, :2, 3] - poses[previous, :2, 3])
            @ np.array([np.cos(earlier_heading), np.sin(earlier_heading)])
        )
        earlier_speed = max(0.0, earlier_forward / dt_previous)
        acceleration = (speed - earlier_speed) / (0.5 * (dt + dt_previous))
    return EgoMotion(speed=speed, yaw_rate=dyaw / dt, acceleration=acceleration)


def transform_points(xyz: np.ndarray, transform: FloatArray) -> np.ndarray:
    """(N, 3) points moved by a (4, 4) rigid transform, in the points' dtype.

    Written out per coordinate: a BLAS matmul of a tall (N, 3) array gains nothing and, with
    the BLAS thread pool competing with other processes, can take tens of milliseconds.
    """
    matrix = np.asarray(transform, dtype=xyz.dtype)
    x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    result = np.empty_like(xyz)
    for row in range(3):
        result[:, row] = matrix[row, 0] * x + matrix[row, 1] * y + matrix[row, 2] * z + matrix[row, 3]
    return result


def points_xyz(points: np.ndarray) -> np.ndarray:
    """(N, 3) float32 x, y, z from a structured point array (any field layout) or an (N, 3) array."""
    if points.dtype.names is None:
        array = np.asarray(points, dtype=np.float32)
        if array.ndim != 2 or array.shape[1] != 3:
            raise StackError(f"points: expected a structured array or (N, 3), got shape {array.shape}")
        return array
    missing = [name for name in ("x", "y", "z") if name not in points.dtype.names]
    if missing:
        raise StackError(f"points: fields {missing} missing (has {list(points.dtype.names)})")
    xyz = np.empty((points.shape[0], 3), dtype=np.float32)
    for column, name in enumerate(("x", "y", "z")):
        xyz[:, column] = points[name]
    return xyz
