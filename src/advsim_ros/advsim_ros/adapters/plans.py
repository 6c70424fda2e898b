"""A stack's answer, whatever its shape, as the contract's plan (pure: numpy and pymap3d only).

The contract's plan is ``num_steps`` poses ``step`` apart after the sweep it answers, in the
world frame. Stacks answer otherwise; each shape is brought to that one by a stated rule:

- timed poses (nav_msgs/Path with per-pose stamps, Autoware trajectories with time_from_start)
  keep their times;
- untimed poses (a spatial nav_msgs/Path, a PoseArray, an Autoware trajectory with only
  speeds) are driven along from the start of the path: with the stack's own speeds where the
  message has them (time by trapezoidal integration of distance over speed), else from the
  ego's speed at the plan's time, changing by the profile's constant ``acceleration`` and held
  in [0, ``max_speed``];
- past the end of a path the ego stands at its last pose (a path that ends is one that stops);
  before the first pose (a plan made after the grid's first time) it stands at the first.

Positions are interpolated linearly in time, headings along the shortest turn. Frames: a plan in
another frame is moved into the world by a planar transform (a static pose, the east-north-up
frame of a geodetic datum, the one at the stack's first GNSS fix, or the latest transforms the
stack and the graph publish on /tf and /tf_static, chained); the world frame's own datum makes it
east-north-up at that point.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pymap3d

from advsim_ros.adapters.profile import Datum, PlanOutput
from advsim_ros.core.futures import NS_PER_S, interpolate_trajectory
from advsim_ros.core.types import FloatArray, IntArray, Plan, ScenarioError


@dataclass(frozen=True)
class Poses:
    """What a stack answered, reduced to poses: positions, headings and what timing it carries."""

    xy: FloatArray  # (N, 2) [m] in the stack's plan frame
    yaws: FloatArray  # (N,) [rad]
    stamps_ns: IntArray | None = None  # (N,) absolute times of the poses, when the message has them
    speeds: FloatArray | None = None  # (N,) the stack's own speeds at the poses [m/s], when it has them

    def __post_init__(self) -> None:
        count = self.xy.shape[0]
        if count == 0:
            raise ScenarioError("the plan has no poses")
        if not (np.all(np.isfinite(self.xy)) and np.all(np.isfinite(self.yaws))):
            raise ScenarioError("the plan has NaN or infinite poses")
        if self.stamps_ns is not None and np.any(np.diff(self.stamps_ns) <= 0):
            raise ScenarioError("the plan's times are not strictly increasing")
        if self.speeds is not None and not np.all(np.isfinite(self.speeds)):
            raise ScenarioError("the plan has NaN or infinite speeds")


def yaw_of_quaternion(x: FloatArray, y: FloatArray, z: FloatArray, w: FloatArray) -> FloatArray:
    """Heading (rotation about z) of quaternions [rad]."""
    yaws: FloatArray = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return yaws


@dataclass(frozen=True)
class PlanarTransform:
    """world_T_frame in the plane: a point p of the frame is R(yaw) p + (x, y) in the world."""

    x: float = 0.0  # [m]
    y: float = 0.0  # [m]
    yaw: float = 0.0  # [rad]

    def apply(self, xy: FloatArray, yaws: FloatArray) -> tuple[FloatArray, FloatArray]:
        cos, sin = np.cos(self.yaw), np.sin(self.yaw)
        rotated = np.column_stack([cos * xy[:, 0] - sin * xy[:, 1], sin * xy[:, 0] + cos * xy[:, 1]])
        return rotated + np.array([self.x, self.y]), yaws + self.yaw


def enu_of(datum: Datum, latitude: float, longitude: float, altitude: float) -> FloatArray:
    """(east, north, up) [m] of a geodetic point in the frame of the datum."""
    origin = (datum.latitude, datum.longitude, datum.altitude)
    east, north, up = pymap3d.geodetic2enu(latitude, longitude, altitude, *origin)
    return np.array([float(east), float(north), float(up)])


def geodetic_of(datum: Datum, east: float, north: float, up: float) -> tuple[float, float, float]:
    """(latitude [deg], longitude [deg], altitude [m]) of a point east/north/up of the datum."""
    latitude, longitude, altitude = pymap3d.enu2geodetic(
        east, north, up, datum.latitude, datum.longitude, datum.altitude
    )
    return float(latitude), float(longitude), float(altitude)


def chained(edges: Mapping[tuple[str, str], FloatArray], source: str, target: str) -> FloatArray | None:
    """source_T_target (4, 4) through the known parent -> child transforms, either way round; None if unlinked."""
    links: dict[str, list[tuple[str, FloatArray]]] = {}
    for (parent, child), matrix in edges.items():
        links.setdefault(parent, []).append((child, matrix))
        inverse: FloatArray = np.linalg.inv(matrix).astype(np.float64)
        links.setdefault(child, []).append((parent, inverse))
    reached: dict[str, FloatArray] = {source: np.eye(4)}
    frontier = [source]
    while frontier and target not in reached:
        frame = frontier.pop(0)
        for neighbour, matrix in links.get(frame, []):
            if neighbour not in reached:
                reached[neighbour] = reached[frame] @ matrix
                frontier.append(neighbour)
    return reached.get(target)


def planar(matrix: FloatArray) -> PlanarTransform:
    """The planar part (x, y, yaw) of a 4x4 transform."""
    return PlanarTransform(float(matrix[0, 3]), float(matrix[1, 3]), float(np.arctan2(matrix[1, 0], matrix[0, 0])))


def frame_transform(
    output: PlanOutput,
    world_datum: Datum | None,
    first_fix_xy: FloatArray | None,
    tf: tuple[str, Mapping[tuple[str, str], FloatArray]] | None = None,
) -> PlanarTransform:
    """world_T_plan-frame for the profile's frame_origin (first_fix: the world position of the first fix sent;
    tf: the world frame's name and the latest transforms seen on /tf and /tf_static)."""
    if output.frame_origin == "world":
        return PlanarTransform()
    if output.frame_origin == "static":
        x, y, yaw = output.origin_pose
        return PlanarTransform(x, y, yaw)
    if output.frame_origin == "first_fix":
        if first_fix_xy is None:
            raise ScenarioError("the plan is in the frame of the first GNSS fix, and no fix was sent yet")
        return PlanarTransform(float(first_fix_xy[0]), float(first_fix_xy[1]), 0.0)
    if output.frame_origin == "tf":
        world, edges = tf if tf is not None else ("", {})
        found = chained(edges, world, output.frame_id) if world else None
        if found is None:
            raise ScenarioError(f"no transform between {world or 'the world frame'} and {output.frame_id} on /tf yet")
        return planar(found)
    assert output.origin_datum is not None  # checked by PlanOutput
    if world_datum is None:
        raise ScenarioError("frame_origin datum needs the world frame's datum (inputs.pose.datum)")
    datum = output.origin_datum
    east, north, _ = enu_of(world_datum, datum.latitude, datum.longitude, datum.altitude)
    # east-north-up at another point is rotated by the meridian convergence; over a few km it is below 0.1 deg
    return PlanarTransform(float(east), float(north), 0.0)


def _driven_times(arc: FloatArray, speeds: FloatArray) -> FloatArray:
    """Time at each arc length from speeds given at those points (trapezoidal); a stop ends the drive."""
    times = np.zeros_like(arc)
    for index in range(1, arc.shape[0]):
        mean = 0.5 * (speeds[index - 1] + speeds[index])
        if mean <= 1e-3:  # the stack stops here: the rest of the path is never reached
            times[index:] = np.inf
            break
        times[index] = times[index - 1] + (arc[index] - arc[index - 1]) / mean
    return times


def _rule_distance(wanted: FloatArray, ego_speed: float, output: PlanOutput) -> FloatArray:
    """Distance driven by each wanted time [s] from ego_speed at the profile's acceleration, within [0, max_speed]."""
    speed_at = np.clip(max(ego_speed, 0.0) + output.acceleration * np.maximum(wanted, 0.0), 0.0, output.max_speed)
    if output.acceleration == 0.0:
        distance: FloatArray = speed_at * np.maximum(wanted, 0.0)
        return distance
    # piecewise: accelerate (or brake) until the speed limit (or a stop), then hold that speed
    start = min(max(ego_speed, 0.0), output.max_speed)
    limit = output.max_speed if output.acceleration > 0.0 else 0.0
    switch = (limit - start) / output.acceleration
    t = np.maximum(wanted, 0.0)
    ramp = np.minimum(t, switch)
    distance = start * ramp + 0.5 * output.acceleration * ramp**2 + limit * np.maximum(t - switch, 0.0)
    return distance


def _along(poses: Poses, distance: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Positions and headings at these distances along the path (held at its ends)."""
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poses.xy, axis=0), axis=1))])
    if arc[-1] <= 0.0:
        return np.repeat(poses.xy[:1], distance.shape[0], axis=0), np.repeat(poses.yaws[:1], distance.shape[0])
    keep = np.concatenate([[True], np.diff(arc) > 0.0])  # repeated poses would make arc length not increase
    arc, xy, yaws = arc[keep], poses.xy[keep], np.unwrap(poses.yaws[keep])
    x = np.interp(distance, arc, xy[:, 0])
    y = np.interp(distance, arc, xy[:, 1])
    return np.column_stack([x, y]), np.interp(distance, arc, yaws)


def timed(poses: Poses, plan_stamp_ns: int) -> FloatArray:
    """Times [s] after plan_stamp_ns at which the stack's timed or speed-annotated poses are reached (inf: never)."""
    if poses.stamps_ns is not None:
        return (poses.stamps_ns - plan_stamp_ns).astype(np.float64) / NS_PER_S
    assert poses.speeds is not None
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poses.xy, axis=0), axis=1))])
    return _driven_times(arc, np.maximum(poses.speeds, 0.0))


def contract_plan(
    poses: Poses,
    plan_stamp_ns: int,
    sweep_stamp_ns: int,
    ego_speed: float,
    output: PlanOutput,
    transform: PlanarTransform,
) -> Plan:
    """The contract's plan for the sweep stamped sweep_stamp_ns from what the stack answered at plan_stamp_ns."""
    step_ns = round(output.step * NS_PER_S)
    stamps = sweep_stamp_ns + step_ns * np.arange(1, output.num_steps + 1, dtype=np.int64)
    wanted = (stamps - plan_stamp_ns).astype(np.float64) / NS_PER_S
    if poses.stamps_ns is None and poses.speeds is None:  # a path and nothing more: the speed rule drives it
        xy, yaws = _along(poses, _rule_distance(wanted, ego_speed, output))
    else:  # held before the first and after the last pose reached
        times = timed(poses, plan_stamp_ns)
        reached = np.isfinite(times)
        reached_ns = plan_stamp_ns + np.round(times[reached] * NS_PER_S).astype(np.int64)
        xy, yaws, _ = interpolate_trajectory(reached_ns, poses.xy[reached], poses.yaws[reached], stamps)
    world_xy, world_yaws = transform.apply(xy, yaws)
    return Plan(stamps_ns=stamps, xy=world_xy, yaws=np.arctan2(np.sin(world_yaws), np.cos(world_yaws)))
