"""Frenet sampling planner: lateral x longitudinal rollouts along a reference path, scored, best one kept.

Reference path: the map's lane centreline the ego is driving along when the scenario has
a map (chained through the lanes that continue it), else the circular arc near the ego's
current curvature (yaw rate / speed) that runs longest through free space. Rollouts
follow M. Werling, J. Ziegler, S. Kammel, S. Thrun, "Optimal trajectory generation for
dynamic street scenarios in a Frenet frame" (ICRA 2010): quintic lateral offsets d(t) to
a set of end offsets, quartic speed profiles s(t) to a set of end speeds, every pairing
mapped to the world frame. Each rollout is scored for collision with the predicted
moving objects (separating-axis test) and with the static occupancy grid (distance
transform), earlier collisions weighing more; for proximity (a grown ego box), progress,
comfort (lateral and longitudinal acceleration, jerk), offset from the reference, and
leaving the drivable area when a map gives one. All rollouts are scored at once, as
arrays.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from advsim_ros.core.drivable import drivable_area_from_map
from advsim_ros.core.geometry import overlap_from_components
from advsim_ros.core.types import DrivableArea, FloatArray, RoadMap
from advsim_ros.stacks.modular.config import PlannerConfig
from advsim_ros.stacks.modular.occupancy import ObstacleGrid

BoolArray = npt.NDArray[np.bool_]

REFERENCE_STEP = 0.5  # spacing of reference path samples [m]
REFERENCE_LENGTH = 150.0  # reference paths reach this far ahead [m] (5 s at the 15 m/s limit is 75 m)
MAX_ARC_TURN = 0.5 * np.pi  # an arc reference turns at most this much, then runs straight [rad]


@dataclass(frozen=True, eq=False)
class ReferencePath:
    """A path sampled every REFERENCE_STEP metres; the ego is at arc length 0."""

    xy: FloatArray  # (K, 2) world positions [m]
    s: FloatArray  # (K,) arc length, 0 at the ego's projection [m]
    heading: FloatArray  # (K,) unwrapped tangent heading [rad]
    source: str  # "lane" or "arc"


@dataclass(frozen=True, eq=False)
class EgoState:
    """The ego at the planning instant, world frame."""

    xy: FloatArray  # (2,) ego frame origin [m]
    yaw: float  # heading [rad]
    speed: float  # forward speed [m/s]
    acceleration: float  # longitudinal acceleration [m/s^2]
    yaw_rate: float  # [rad/s]
    length: float  # ego box length [m]
    width: float  # ego box width [m]
    forward_offset: float  # ego box centre ahead of the ego frame origin [m]


@dataclass(frozen=True, eq=False)
class PlanChoice:
    """The chosen rollout and why."""

    xy: FloatArray  # (T, 2) ego frame origin at the plan steps, world [m]
    yaw: FloatArray  # (T,) heading [rad]
    cost: float  # total cost of the chosen rollout
    collides: bool  # the chosen rollout still overlaps a predicted object
    reference: ReferencePath
    num_rollouts: int
    terms: Mapping[str, FloatArray]  # each cost term of every rollout (C,): collision, proximity, progress, ...
    best: int  # index of the chosen rollout


def footprint_circles(length: float, width: float, count: int) -> tuple[FloatArray, float]:
    """Offsets along the heading [m] of `count` equal circles covering a length x width box, and their radius [m]."""
    offsets = np.asarray((np.arange(count) + 0.5) * (length / count) - 0.5 * length, dtype=np.float64)
    return offsets, float(np.hypot(0.5 * length / count, 0.5 * width))


def ego_curvature(ego: EgoState, max_curvature: float) -> float:
    """The ego's current path curvature, yaw rate / speed (speed floored at 2 m/s where it is noise) [1/m]."""
    return float(np.clip(ego.yaw_rate / max(ego.speed, 2.0), -max_curvature, max_curvature))


def arc_reference(ego: EgoState, curvature: float) -> ReferencePath:
    """A circular arc from the ego along its heading with the given curvature, straight after a quarter turn."""
    s = np.arange(0.0, REFERENCE_LENGTH + REFERENCE_STEP, REFERENCE_STEP)
    turn_end = MAX_ARC_TURN / abs(curvature) if abs(curvature) > 1e-6 else np.inf
    heading = ego.yaw + curvature * np.minimum(s, turn_end)
    # Integrate the tangent exactly on the arc and with the final heading beyond it.
    if abs(curvature) > 1e-6:
        on_arc = np.minimum(s, turn_end)
        x = (np.sin(ego.yaw + curvature * on_arc) - np.sin(ego.yaw)) / curvature
        y = (np.cos(ego.yaw) - np.cos(ego.yaw + curvature * on_arc)) / curvature
        beyond = np.maximum(s - turn_end, 0.0) if np.isfinite(turn_end) else np.zeros_like(s)
        x = x + beyond * np.cos(heading)
        y = y + beyond * np.sin(heading)
    else:
        x, y = s * np.cos(ego.yaw), s * np.sin(ego.yaw)
    xy = np.stack([ego.xy[0] + x, ego.xy[1] + y], axis=1)
    return ReferencePath(xy=xy, s=s, heading=heading, source="arc")


def _resample(polyline: FloatArray, step: float) -> tuple[FloatArray, FloatArray]:
    segment = np.linalg.norm(np.diff(polyline, axis=0), axis=1)
    keep = np.r_[True, segment > 1e-6]
    polyline = polyline[keep]
    along = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(polyline, axis=0), axis=1))]
    samples = np.arange(0.0, along[-1] + 1e-9, step)
    xy = np.stack([np.interp(samples, along, polyline[:, 0]), np.interp(samples, along, polyline[:, 1])], axis=1)
    return xy, samples


def _nearest_on(polyline: FloatArray, point: FloatArray) -> tuple[float, int]:
    distance = np.linalg.norm(polyline - point, axis=1)
    index = int(np.argmin(distance))
    return float(distance[index]), index


def lane_reference(ego: EgoState, road_map: RoadMap, config: PlannerConfig) -> ReferencePath | None:
    """The lane centreline under the ego heading its way, chained through lanes that continue it; None if none."""
    best: tuple[float, int, int] | None = None  # distance, lane, vertex
    lanes = [_resample(lane, REFERENCE_STEP)[0] for lane in road_map.lane_centerlines]
    lanes = [lane for lane in lanes if lane.shape[0] >= 2]
    for index, lane in enumerate(lanes):
        distance, vertex = _nearest_on(lane, ego.xy)
        if distance > config.lane_search_radius:
            continue
        following = lane[min(vertex + 1, lane.shape[0] - 1)] - lane[max(vertex - 1, 0)]
        heading = np.arctan2(following[1], following[0])
        if abs(np.angle(np.exp(1j * (heading - ego.yaw)))) > config.lane_heading_tolerance:
            continue
        if best is None or distance < best[0]:
            best = (distance, index, vertex)
    if best is None:
        return None
    _, lane_index, vertex = best
    path = [lanes[lane_index][vertex:]]
    length = REFERENCE_STEP * (path[0].shape[0] - 1)
    used = {lane_index}
    while length < REFERENCE_LENGTH:
        end = path[-1][-1]
        end_heading = np.arctan2(*(path[-1][-1] - path[-1][-2])[::-1]) if path[-1].shape[0] >= 2 else ego.yaw
        successor = None
        for index, lane in enumerate(lanes):
            if index in used or np.linalg.norm(lane[0] - end) > 1.5:
                continue
            start_heading = np.arctan2(*(lane[1] - lane[0])[::-1])
            if abs(np.angle(np.exp(1j * (start_heading - end_heading)))) < 0.6:
                successor = index
                break
        if successor is None:
            break
        used.add(successor)
        path.append(lanes[successor][1:])
        length += REFERENCE_STEP * (lanes[successor].shape[0] - 1)
    polyline = np.concatenate(path, axis=0)
    if polyline.shape[0] < 2:
        return None
    # Run straight on past the last lane so that every rollout stays on the reference.
    direction = polyline[-1] - polyline[-2]
    direction /= max(float(np.linalg.norm(direction)), 1e-9)
    extra = np.arange(1, int(REFERENCE_LENGTH / REFERENCE_STEP) + 1)[:, None] * REFERENCE_STEP * direction
    xy, s = _resample(np.concatenate([polyline, polyline[-1] + extra], axis=0), REFERENCE_STEP)
    tangent = np.gradient(xy, axis=0)
    heading = np.unwrap(np.arctan2(tangent[:, 1], tangent[:, 0]))
    # Arc length 0 where the ego projects onto the path.
    _, nearest = _nearest_on(xy, ego.xy)
    return ReferencePath(xy=xy, s=s - s[nearest], heading=heading, source="lane")


def choose_curvature(ego: EgoState, grid: ObstacleGrid | None, config: PlannerConfig) -> float:
    """Without a map: the arc ("tentacle") that runs free longest, the one nearest the ego's curvature on ties.

    Arcs around the ego's curvature are walked out over the distance the horizon covers;
    each is free up to its first point where the ego box would come within
    tentacle_clearance of an occupied cell (following the road without a map, as in
    F. von Hundelshausen et al., "Driving with tentacles", J. Field Robotics 2008).
    """
    own = ego_curvature(ego, config.max_curvature)
    if grid is None or config.tentacle_count == 1:
        return own
    candidates = np.clip(
        own + np.linspace(-config.tentacle_spread, config.tentacle_spread, config.tentacle_count),
        -config.max_curvature,
        config.max_curvature,
    )
    lookahead = max(ego.speed * config.horizon_s, config.min_lookahead)
    s = np.arange(REFERENCE_STEP, lookahead + REFERENCE_STEP, REFERENCE_STEP)
    turn = candidates[:, None] * s[None, :]
    safe = np.where(np.abs(candidates) > 1e-6, candidates, 1.0)[:, None]
    x = np.where(np.abs(candidates)[:, None] > 1e-6, np.sin(turn) / safe, s[None, :])
    y = np.where(np.abs(candidates)[:, None] > 1e-6, (1.0 - np.cos(turn)) / safe, 0.0)
    cos, sin = np.cos(ego.yaw), np.sin(ego.yaw)
    forward = x + ego.forward_offset * np.cos(turn)  # box centre ahead of the origin along the arc
    sideways = y + ego.forward_offset * np.sin(turn)
    centre = np.stack([ego.xy[0] + cos * forward - sin * sideways, ego.xy[1] + sin * forward + cos * sideways], -1)
    offsets, radius = footprint_circles(ego.length, ego.width, config.footprint_circles)
    heading = np.stack([np.cos(ego.yaw + turn), np.sin(ego.yaw + turn)], axis=-1)
    circles = centre[..., None, :] + offsets[:, None] * heading[..., None, :]  # (K, S, circles, 2)
    limit = radius + config.tentacle_clearance
    blocked = grid.clearance(circles, limit + 0.5).min(axis=-1) < limit  # (K, S)
    free = np.where(blocked.any(axis=1), s[np.argmax(blocked, axis=1)] - REFERENCE_STEP, lookahead)
    best = free.max()
    ties = np.flatnonzero(free >= best - 1e-9)
    return float(candidates[ties[np.argmin(np.abs(candidates[ties] - own))]])


def _quintic_lateral(
    d0: float, d0_rate: float, targets: FloatArray, durations: FloatArray, t: FloatArray
) -> FloatArray:
    """(L, T) offsets: quintics from (d0, d0_rate, 0) to (target, 0, 0) over each duration, then held."""
    # d(t) = d0 + d0_rate t + c3 t^3 + c4 t^4 + c5 t^5; the end conditions fix c3..c5 for each duration.
    result: FloatArray = np.empty((targets.shape[0], t.shape[0]))
    for row in range(targets.shape[0]):
        big_t = float(durations[row])
        system = np.array(
            [
                [big_t**3, big_t**4, big_t**5],
                [3 * big_t**2, 4 * big_t**3, 5 * big_t**4],
                [6 * big_t, 12 * big_t**2, 20 * big_t**3],
            ]
        )
        rhs = np.array([targets[row] - d0 - d0_rate * big_t, -d0_rate, 0.0])
        c = np.linalg.solve(system, rhs)
        local = np.minimum(t, big_t)
        result[row] = d0 + d0_rate * local + c[0] * local**3 + c[1] * local**4 + c[2] * local**5
        after = t > big_t
        result[row, after] = targets[row]
    return result


def _quartic_speed(
    v0: float, a0: float, targets: FloatArray, durations: FloatArray, t: FloatArray, dt: float
) -> tuple[FloatArray, FloatArray]:
    """(S, T) arc lengths [m] and speeds [m/s]: quartic s(t) from (0, v0, a0) to (target speed, 0 accel), then held.

    Speeds are clipped at 0 (the ego never reverses) and integrated to arc lengths.
    """
    speeds = np.empty((targets.shape[0], t.shape[0]))
    for row in range(targets.shape[0]):
        big_t = float(durations[row])
        system = np.array([[3 * big_t**2, 4 * big_t**3], [6 * big_t, 12 * big_t**2]])
        rhs = np.array([targets[row] - v0 - a0 * big_t, -a0])
        c3, c4 = np.linalg.solve(system, rhs)
        local = np.minimum(t, big_t)
        speeds[row] = v0 + a0 * local + 3 * c3 * local**2 + 4 * c4 * local**3
        speeds[row, t > big_t] = targets[row]
    speeds = np.maximum(speeds, 0.0)
    # Trapezoidal integration from the current speed at t = 0.
    previous = np.concatenate([np.full((targets.shape[0], 1), max(v0, 0.0)), speeds[:, :-1]], axis=1)
    arc = np.cumsum(0.5 * (previous + speeds) * dt, axis=1)
    return arc, speeds


def _frenet_of(reference: ReferencePath, ego: EgoState) -> tuple[float, float, float]:
    """Ego arc length s [m], lateral offset d [m] and its rate [m/s] on the reference."""
    _, index = _nearest_on(reference.xy, ego.xy)
    heading = float(reference.heading[index])
    tangent = np.array([np.cos(heading), np.sin(heading)])
    normal = np.array([-np.sin(heading), np.cos(heading)])
    along = float(reference.s[index] + (ego.xy - reference.xy[index]) @ tangent)
    offset = float((ego.xy - reference.xy[index]) @ normal)
    rate = ego.speed * float(np.sin(ego.yaw - heading))
    return along, offset, rate


def _to_world(reference: ReferencePath, arc: FloatArray, offset: FloatArray) -> FloatArray:
    """(L, S, T, 2) positions for lateral profiles (L, T) and arc lengths (S, T)."""
    x = np.interp(arc, reference.s, reference.xy[:, 0])
    y = np.interp(arc, reference.s, reference.xy[:, 1])
    heading = np.interp(arc, reference.s, reference.heading)
    normal_x, normal_y = -np.sin(heading), np.cos(heading)
    world_x = x[None] + offset[:, None, :] * normal_x[None]
    world_y = y[None] + offset[:, None, :] * normal_y[None]
    return np.stack([world_x, world_y], axis=-1)


def _headings(xy: FloatArray, start_xy: FloatArray, start_yaw: float) -> FloatArray:
    """(..., T) heading of each step's motion; standing still keeps the previous heading."""
    previous = np.concatenate([np.broadcast_to(start_xy, xy[..., :1, :].shape), xy[..., :-1, :]], axis=-2)
    delta = xy - previous
    moving = np.hypot(delta[..., 0], delta[..., 1]) > 0.02
    raw = np.arctan2(delta[..., 1], delta[..., 0])
    # Carry the last moving heading forward: index of the last moving step so far.
    steps = np.arange(xy.shape[-2])
    last = np.maximum.accumulate(np.where(moving, steps, -1), axis=-1)
    carried = np.take_along_axis(raw, np.maximum(last, 0), axis=-1)
    result: FloatArray = np.where(last >= 0, carried, start_yaw)
    # Keep headings continuous with the start (unwrap relative to it).
    continuous: FloatArray = start_yaw + np.angle(np.exp(1j * (result - start_yaw)))
    return continuous


def _kinematics(xy: FloatArray, start_xy: FloatArray, start_speed: float, start_yaw: float, dt: float) -> FloatArray:
    """(..., T) per-step comfort cost terms stacked on axis 0: lateral accel^2, longitudinal accel^2, jerk^2."""
    start = np.broadcast_to(start_xy, xy[..., :1, :].shape)
    path = np.concatenate([start, xy], axis=-2)  # (..., T + 1, 2)
    velocity = np.diff(path, axis=-2) / dt  # (..., T, 2): velocity over each step
    start_velocity = np.broadcast_to(start_speed * np.array([np.cos(start_yaw), np.sin(start_yaw)]), start.shape)
    velocity = np.concatenate([start_velocity, velocity], axis=-2)  # (..., T + 1, 2)
    acceleration = np.diff(velocity, axis=-2) / dt  # (..., T, 2)
    jerk = np.diff(acceleration, axis=-2, prepend=acceleration[..., :1, :]) / dt
    mid_velocity = 0.5 * (velocity[..., 1:, :] + velocity[..., :-1, :])
    speed = np.maximum(np.hypot(mid_velocity[..., 0], mid_velocity[..., 1]), 0.5)
    unit = mid_velocity / speed[..., None]
    longitudinal = np.sum(acceleration * unit, axis=-1)
    lateral = unit[..., 0] * acceleration[..., 1] - unit[..., 1] * acceleration[..., 0]
    return np.stack([lateral**2, longitudinal**2, np.sum(jerk**2, axis=-1)])


def _box_overlaps(
    ego_xy: FloatArray, ego_yaw: FloatArray, half_length: float, half_width: float, margin: float, obstacles: FloatArray
) -> tuple[BoolArray, BoolArray]:
    """(C, T) overlap of the ego box with any obstacle box, and of the ego box grown by margin [m].

    ego_xy (C, T, 2) are box centres, ego_yaw (C, T) headings, obstacles (N, T, 5) boxes at the
    same steps. Cheap tests first: an obstacle step outside the rollouts' bounding box at
    that step is skipped, then pairs whose circumscribed circles do not touch; the
    separating-axis test runs only on what is left.
    """
    count, steps = ego_yaw.shape
    collide = np.zeros((count, steps), dtype=bool)
    close = np.zeros((count, steps), dtype=bool)
    if obstacles.shape[0] == 0:
        return collide, close
    ego_radius = float(np.hypot(half_length + margin, half_width + margin))
    obstacle_radius = 0.5 * np.hypot(obstacles[..., 3], obstacles[..., 4])  # (N, T)
    low = ego_xy.min(axis=0) - ego_radius  # (T, 2) corner of every rollout's reach at each step
    high = ego_xy.max(axis=0) + ego_radius
    inside = np.all(
        (obstacles[..., :2] >= low[None] - obstacle_radius[..., None])
        & (obstacles[..., :2] <= high[None] + obstacle_radius[..., None]),
        axis=-1,
    )  # (N, T)
    obstacle_index, step_index = np.nonzero(inside)
    if obstacle_index.shape[0] == 0:
        return collide, close
    boxes = obstacles[obstacle_index, step_index]  # (P, 5)
    # Pairs (rollout, obstacle step) in float32: only a coarse filter, the exact test follows.
    centres = ego_xy.astype(np.float32)[:, step_index]  # (C, P, 2)
    dx = boxes[None, :, 0].astype(np.float32) - centres[..., 0]
    dy = boxes[None, :, 1].astype(np.float32) - centres[..., 1]
    reach = (ego_radius + obstacle_radius[obstacle_index, step_index]).astype(np.float32)
    rollout, pair = np.nonzero(dx * dx + dy * dy <= reach[None] ** 2)
    if rollout.shape[0] == 0:
        return collide, close
    step = step_index[pair]
    offset_x = boxes[pair, 0] - ego_xy[rollout, step, 0]
    offset_y = boxes[pair, 1] - ego_xy[rollout, step, 1]
    cos_a, sin_a = np.cos(ego_yaw[rollout, step]), np.sin(ego_yaw[rollout, step])
    cos_b, sin_b = np.cos(boxes[pair, 2]), np.sin(boxes[pair, 2])
    half_length_b, half_width_b = 0.5 * boxes[pair, 3], 0.5 * boxes[pair, 4]
    grown = overlap_from_components(
        offset_x, offset_y, cos_a, sin_a, cos_b, sin_b,
        half_length + margin, half_width + margin, half_length_b, half_width_b,
    )  # fmt: skip
    exact = grown & overlap_from_components(
        offset_x, offset_y, cos_a, sin_a, cos_b, sin_b, half_length, half_width, half_length_b, half_width_b
    )
    close[rollout[grown], step[grown]] = True
    collide[rollout[exact], step[exact]] = True
    return collide, close


def _static_overlaps(
    centre: FloatArray, yaw: FloatArray, length: float, width: float, margin: float, grid: ObstacleGrid, circles: int
) -> tuple[BoolArray, BoolArray]:
    """(C, T) whether the ego box touches an occupied cell, and whether it comes within margin [m] of one.

    The box is covered by `circles` equal circles along its length (see footprint_circles).
    """
    offsets, radius = footprint_circles(length, width, circles)
    heading = np.stack([np.cos(yaw), np.sin(yaw)], axis=-1)  # (C, T, 2)
    circles_xy = centre[..., None, :] + offsets[:, None] * heading[..., None, :]  # (C, T, circles, 2)
    clearance = grid.clearance(circles_xy, radius + margin + 0.5).min(axis=-1)  # (C, T)
    return clearance < radius, clearance < radius + margin


def plan(
    ego: EgoState,
    obstacles: FloatArray,
    config: PlannerConfig,
    road_map: RoadMap | None = None,
    drivable: DrivableArea | None = None,
    static: ObstacleGrid | None = None,
) -> PlanChoice:
    """The lowest-cost rollout.

    obstacles (N, T, 5) are the predicted boxes of moving objects at the plan's T steps
    (world frame); `static` holds everything else the sweep saw.
    """
    dt = config.step_s
    steps = round(config.horizon_s / dt)
    t: FloatArray = dt * np.arange(1, steps + 1, dtype=np.float64)
    reference = None
    if road_map is not None and road_map.lane_centerlines:
        reference = lane_reference(ego, road_map, config)
    if reference is None:
        reference = arc_reference(ego, choose_curvature(ego, static, config))
    along0, offset0, offset_rate = _frenet_of(reference, ego)
    lateral_targets, lateral_durations = np.meshgrid(config.lateral_offsets, config.lateral_times, indexing="ij")
    lateral = _quintic_lateral(offset0, offset_rate, lateral_targets.ravel(), lateral_durations.ravel(), t)
    desired = float(np.clip(max(ego.speed, config.min_desired_speed), 0.0, config.speed_limit))
    speed_targets, speed_durations = np.meshgrid(
        np.minimum(np.asarray(config.speed_factors) * desired, config.speed_limit),
        config.longitudinal_times,
        indexing="ij",
    )
    arc, _speeds = _quartic_speed(
        ego.speed, float(np.clip(ego.acceleration, -4.0, 4.0)), speed_targets.ravel(), speed_durations.ravel(), t, dt
    )
    positions = _to_world(reference, along0 + arc, lateral)  # (L, S, T, 2)
    num_lateral, num_speed = lateral.shape[0], arc.shape[0]
    xy = positions.reshape(num_lateral * num_speed, steps, 2)
    yaw = _headings(xy, ego.xy, ego.yaw)
    centre = xy + ego.forward_offset * np.stack([np.cos(yaw), np.sin(yaw)], axis=-1)

    near = np.zeros(0, dtype=bool)
    if obstacles.shape[0]:
        near = np.linalg.norm(obstacles[:, 0, :2] - ego.xy, axis=1) <= config.obstacle_reach
    relevant = obstacles[near] if obstacles.shape[0] else obstacles.reshape(0, steps, 5)
    half_length, half_width = 0.5 * ego.length, 0.5 * ego.width
    checked = slice(config.collision_stride - 1, None, config.collision_stride)  # ends on the last step
    collide, close = _box_overlaps(
        centre[:, checked], yaw[:, checked], half_length, half_width, config.safety_margin, relevant[:, checked]
    )
    if static is not None:
        static_collide, static_close = _static_overlaps(
            centre[:, checked], yaw[:, checked], ego.length, ego.width, config.safety_margin, static,
            config.footprint_circles,
        )  # fmt: skip
        collide |= static_collide
        close |= static_close
    checked_dt = dt * config.collision_stride  # each checked step stands for this long [s]
    decay = np.exp(-t[checked] / config.collision_decay_s)
    terms = {
        "collision": config.weight_collision * (collide * decay).sum(axis=1) * checked_dt,
        "proximity": config.weight_proximity * close.sum(axis=1) * checked_dt,
    }
    goal = max(desired * config.horizon_s, 1.0)
    progress = np.maximum(goal - arc[:, -1], 0.0) / goal
    excess = np.maximum(speed_targets.ravel() - desired, 0.0)
    terms["progress"] = np.tile(config.weight_progress * progress + config.weight_speed_excess * excess, num_lateral)
    lateral_acc, longitudinal_acc, jerk = _kinematics(xy, ego.xy, ego.speed, ego.yaw, dt).mean(axis=-1)
    terms["comfort"] = (
        config.weight_lateral_acceleration * lateral_acc
        + config.weight_longitudinal_acceleration * longitudinal_acc
        + config.weight_jerk * jerk
    )
    terms["offset"] = np.repeat(config.weight_offset * np.mean(lateral**2, axis=1), num_speed)
    if drivable is not None:
        terms["offroad"] = config.weight_offroad * (
            1.0 - drivable.contains(centre[..., 0], centre[..., 1]).mean(axis=1)
        )
    cost = np.sum(list(terms.values()), axis=0)
    best = int(np.argmin(cost))
    return PlanChoice(
        xy=xy[best],
        yaw=np.unwrap(yaw[best]),
        cost=float(cost[best]),
        collides=bool(collide[best].any()),
        reference=reference,
        num_rollouts=int(cost.shape[0]),
        terms=terms,
        best=best,
    )


def drivable_from_map(road_map: RoadMap, config: PlannerConfig, max_cells: int = 4_000_000) -> DrivableArea | None:
    """The map's drivable area as a raster over the map's extent (coarser than configured if it is huge)."""
    if not road_map.drivable_areas:
        return None
    outline = np.concatenate(road_map.drivable_areas, axis=0)
    low, high = outline.min(axis=0) - 1.0, outline.max(axis=0) + 1.0
    area = float(np.prod(high - low))
    resolution = max(config.drivable_resolution, float(np.sqrt(area / max_cells)))
    return drivable_area_from_map(road_map, (low[0], low[1], high[0], high[1]), resolution)
