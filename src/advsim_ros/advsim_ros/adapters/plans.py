"""A stack's answer, whatever its shape, as the contract's plan (pure: numpy and pymap3d only).

The contract's plan is ``num_steps`` poses ``step`` apart after the sweep it answers, in the
world frame. Stacks answer otherwise; each shape is brought to that one by a stated rule:

- timed poses (nav_msgs/Path with per-pose stamps, Autoware trajectories with time_from_start)
  keep their times;
- untimed poses (a spatial nav_msgs/Path, a PoseArray, an Autoware trajectory with only
  speeds) are driven along from where the ego was when the adapter last heard of it before the
  plan was made (the latest odometry, its position projected onto the path, the first segment
  going on backwards when the ego is behind the path's start), from that odometry's time: with
  the stack's own speeds where the message has them (time by trapezoidal integration of
  distance over speed), else from the ego's speed then, changing by the profile's constant
  ``acceleration`` and held in [0, ``max_speed``]. A stack plans from the pose it knows, which
  is older than the plan: anchored at the plan's own time, the ego would stand at the path's
  start for that age (the decision delay of a timer-driven stack) and the jerk of that made-up
  stop would dominate the comfort terms. Without odometry the path is driven from its start at
  the plan's time;
- past the end of a path the ego stands at its last pose (a path that ends is one that stops);
  before the first pose reached it drives on the line of the path's start at its starting speed
  (the constant velocity of the first two timed poses; the rule's speed for untimed ones),
  never standing at the first pose;
- headings come from the path's tangent (core.geometry.tangent_headings) when every pose's
  orientation is the identity (a path of positions only) or the profile's ``headings`` is
  ``tangent``; else from the orientations.

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
from advsim_ros.core.geometry import tangent_headings
from advsim_ros.core.types import FloatArray, IntArray, Plan, ScenarioError


@dataclass(frozen=True)
class Poses:
    """What a stack answered, reduced to poses: positions, headings and what timing it carries."""

    xy: FloatArray  # (N, 2) [m] in the stack's plan frame
    yaws: FloatArray  # (N,) [rad]
    stamps_ns: IntArray | None = None  # (N,) absolute times of the poses, when the message has them
    speeds: FloatArray | None = None  # (N,) the stack's own speeds at the poses [m/s], when it has them
    oriented: bool = True  # False when every pose's orientation was the identity: the yaws say nothing

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
    """Distance driven by each wanted time [s] from ego_speed at the profile's acceleration, within [0, max_speed].

    Before time 0 the ego drove at its speed then (negative distances): it did not stand and wait.
    """
    start = min(max(ego_speed, 0.0), output.max_speed)
    t = np.maximum(wanted, 0.0)
    backwards = start * np.minimum(wanted, 0.0)
    if output.acceleration == 0.0:
        distance: FloatArray = start * t + backwards
        return distance
    # piecewise: accelerate (or brake) until the speed limit (or a stop), then hold that speed
    limit = output.max_speed if output.acceleration > 0.0 else 0.0
    switch = (limit - start) / output.acceleration
    ramp = np.minimum(t, switch)
    distance = start * ramp + 0.5 * output.acceleration * ramp**2 + limit * np.maximum(t - switch, 0.0) + backwards
    return distance


def _path(xy: FloatArray, yaws: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The path without repeated poses: arc lengths [m] (strictly increasing), positions and unwrapped headings."""
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    keep = np.concatenate([[True], np.diff(arc) > 0.0])  # repeated poses would make arc length not increase
    return arc[keep], xy[keep], np.unwrap(yaws[keep])


def _along(xy: FloatArray, yaws: FloatArray, distance: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Positions and headings at these distances along the path: held past its end, and before its start
    (negative distances) on the straight line of its first segment, heading held."""
    arc, points, headings = _path(xy, yaws)
    if arc.shape[0] < 2:
        return np.repeat(xy[:1], distance.shape[0], axis=0), np.repeat(yaws[:1], distance.shape[0])
    x = np.interp(distance, arc, points[:, 0])
    y = np.interp(distance, arc, points[:, 1])
    out = np.column_stack([x, y])
    behind = distance < 0.0
    direction = (points[1] - points[0]) / arc[1]
    out[behind] = points[0] + distance[behind, None] * direction
    return out, np.interp(distance, arc, headings)


def arc_of(point: FloatArray, xy: FloatArray) -> float:
    """Arc length [m] of the path point nearest ``point``; the first segment goes on backwards, so a point
    behind the path's start has a negative one (0 for a path that does not move)."""
    arc, points, _ = _path(xy, np.zeros(xy.shape[0]))
    if arc.shape[0] < 2:
        return 0.0
    starts, segments, lengths = points[:-1], np.diff(points, axis=0), np.diff(arc)
    fraction = np.einsum("ij,ij->i", point - starts, segments) / lengths**2
    fraction = np.clip(fraction, np.where(np.arange(fraction.shape[0]) == 0, -np.inf, 0.0), 1.0)
    distances = np.linalg.norm(starts + fraction[:, None] * segments - point, axis=1)
    index = int(np.argmin(distances))
    return float(arc[index] + fraction[index] * lengths[index])


def _untimed_distance(
    xy: FloatArray, speeds: FloatArray | None, wanted: FloatArray, start: float, ego_speed: float, output: PlanOutput
) -> FloatArray:
    """Distance along a path without times at each wanted time [s] after the ego was at arc length ``start``.

    By the profile's speed rule, or by the stack's own speeds: its timeline (from the path's start,
    trapezoidal) shifted so that it is at ``start`` at time 0, at its first speed before its start.
    """
    if speeds is None:
        return start + _rule_distance(wanted, ego_speed, output)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    times = _driven_times(arc, np.maximum(speeds, 0.0))
    reached = np.isfinite(times)
    first_speed = max(float(speeds[0]), 0.0)
    if start >= 0.0:
        at_start = float(np.interp(start, arc[reached], times[reached]))
    else:
        at_start = start / first_speed if first_speed > 1e-3 else 0.0
    clock = wanted + at_start
    distance: FloatArray = np.interp(clock, times[reached], arc[reached])
    return np.where(clock < 0.0, first_speed * clock, distance)


def _on_times(
    stamps_ns: IntArray, xy: FloatArray, yaws: FloatArray, query_ns: IntArray
) -> tuple[FloatArray, FloatArray]:
    """Timed poses at query stamps, linear in time: held after the last, and before the first continued back at
    the constant velocity of the first two (heading held), so that no standstill is made up before the plan."""
    out_xy, out_yaws, _ = interpolate_trajectory(stamps_ns, xy, yaws, query_ns)
    early = query_ns < stamps_ns[0]
    if np.any(early) and stamps_ns.shape[0] >= 2:
        velocity = (xy[1] - xy[0]) / (float(stamps_ns[1] - stamps_ns[0]) / NS_PER_S)
        ahead = (query_ns[early] - stamps_ns[0]).astype(np.float64) / NS_PER_S
        out_xy[early] = xy[0] + ahead[:, None] * velocity
    return out_xy, out_yaws


@dataclass(frozen=True)
class EgoAt:
    """Where the ego was, as the adapter last heard before a plan was made (the contract's odometry)."""

    stamp_ns: int  # the odometry's stamp [ns]
    xy: FloatArray  # (2,) position in the world frame [m]


def ego_before(odometry: Mapping[int, tuple[float, FloatArray]], made_ns: int) -> tuple[float, EgoAt | None]:
    """The ego's speed [m/s] and position from the latest odometry (stamp -> (speed, world xy)) at or before
    made_ns; (0, None) when none is known."""
    known = [stamp for stamp in odometry if stamp <= made_ns]
    if not known:
        return 0.0, None
    speed, xy = odometry[max(known)]
    return speed, EgoAt(max(known), xy)


def contract_plan(
    poses: Poses,
    plan_stamp_ns: int,
    sweep_stamp_ns: int,
    ego_speed: float,
    output: PlanOutput,
    transform: PlanarTransform,
    ego: EgoAt | None = None,
) -> Plan:
    """The contract's plan for the sweep stamped sweep_stamp_ns from what the stack answered at plan_stamp_ns.

    ``ego``: where the ego was when last heard of before the plan was made (``ego_before``); a path
    without times is driven from there, from then (module docstring). Without it, from the path's start
    at plan_stamp_ns.
    """
    step_ns = round(output.step * NS_PER_S)
    stamps = sweep_stamp_ns + step_ns * np.arange(1, output.num_steps + 1, dtype=np.int64)
    tangent = output.headings == "tangent" or not poses.oriented
    yaws = tangent_headings(poses.xy, poses.yaws) if tangent else poses.yaws
    xy, yaws = transform.apply(poses.xy, yaws)  # into the world first: the ego's position is there
    if poses.stamps_ns is not None:
        plan_xy, plan_yaws = _on_times(poses.stamps_ns, xy, yaws, stamps)
    else:
        origin_ns, start = (ego.stamp_ns, arc_of(ego.xy, xy)) if ego is not None else (plan_stamp_ns, 0.0)
        wanted = (stamps - origin_ns).astype(np.float64) / NS_PER_S
        plan_xy, plan_yaws = _along(xy, yaws, _untimed_distance(xy, poses.speeds, wanted, start, ego_speed, output))
    return Plan(stamps_ns=stamps, xy=plan_xy, yaws=np.arctan2(np.sin(plan_yaws), np.cos(plan_yaws)))
