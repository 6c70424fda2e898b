"""The ego trajectories a careful and competent driver could have driven from the decision time: the evasion family.

Fault and avoidability (core.fault) ask whether *some* ego trajectory within the ego's limits avoided every
actor. This module builds that family from the ego's logged state at the decision time, along the human's
(logged ego's) path as the reference line:

- longitudinal profiles s(t): keep the speed; brake at shares of max_decel (the deceleration built up at
  max_jerk, then held to a standstill); accelerate at shares of max_accel (built up likewise) up to the speed
  limit; and the modular planner's quartic speed profiles (end speeds a share of the current speed, reached
  in 3 s or 5 s; Werling, Ziegler, Kammel, Thrun, ICRA 2010);
- lateral profiles d(t): stay on the reference, or a quintic from the reference to an end offset, reached in
  a set time and then held (the planner's offsets and times, plus a quicker swerve);
- every pairing, mapped to the world along the reference (offset along its left normal), headed along the
  motion: heading = reference heading + atan2(d', s').

A trajectory is within the limits when, at every plan step: the longitudinal acceleration lies in
[-max_decel, max_accel] (and the quartics' jerk within max_jerk; the brake and acceleration profiles ramp at
max_jerk by construction); the total acceleration, longitudinal and lateral (speed x yaw rate, as the metrics
measure it), stays within max_decel (the tyres grip sideways as much as they brake: the friction circle); the
path curvature stays within tan(max_steer) / wheelbase, and the road-wheel angle it needs changes by at most
max_steer_rate. These are the limits the closed-loop controller drives with (core.closed_loop.ControllerConfig).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from advsim_ros.core.closed_loop import ControllerConfig
from advsim_ros.core.futures import NS_PER_S, BoolArray
from advsim_ros.core.types import EgoTrajectory, FloatArray, ScenarioError

SPEED_LIMIT = 15.0  # no candidate accelerates beyond this (the planner's and the actors' limit) [m/s]
REFERENCE_STEP = 0.5  # spacing of the reference line's samples, and the least step kept from the log [m]
HEADING_SMOOTHING = 5  # reference headings are averaged over this many samples (2 m): log jitter is no curve
FINE_STEP = 0.01  # longitudinal profiles are integrated at this step, then sampled at the plan stamps [s]
STANDING_STEP = 1e-3  # a move shorter than this between stamps is standing: its curvature is carried over [m]
TOLERANCE = 1e-6  # relative slack on every limit (rounding)


@dataclass(frozen=True)
class EgoLimits:
    """The ego's physical limits (defaults: ControllerConfig's) and the speed limit of the family."""

    max_accel: float = 3.0  # [m/s^2]
    max_decel: float = 8.0  # a full brake on dry asphalt; also the grip sideways (friction circle) [m/s^2]
    max_jerk: float = 15.0  # [m/s^3]
    max_steer: float = 0.55  # road-wheel angle [rad]
    max_steer_rate: float = 0.8  # [rad/s]
    wheelbase: float = 2.8  # [m]
    speed_limit: float = SPEED_LIMIT  # candidates accelerate up to this, or keep a higher current speed [m/s]

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not (np.isfinite(value) and value > 0.0):
                raise ScenarioError(f"EgoLimits {name}: must be a positive number, got {value}")
        if self.max_steer >= 0.5 * np.pi:
            raise ScenarioError(f"EgoLimits max_steer: must be below pi/2 rad, got {self.max_steer}")

    @classmethod
    def from_controller(cls, config: ControllerConfig, speed_limit: float = SPEED_LIMIT) -> EgoLimits:
        """The limits the closed-loop controller drives with."""
        return cls(
            config.max_accel, config.max_decel, config.max_jerk, config.max_steer, config.max_steer_rate,
            config.wheelbase, speed_limit,
        )  # fmt: skip

    @property
    def max_curvature(self) -> float:
        """The tightest path the steering allows [1/m]."""
        return float(np.tan(self.max_steer) / self.wheelbase)


@dataclass(frozen=True)
class EvasionFamily:
    """Which trajectories are tried (module docstring); the Frenet part mirrors params/stack_modular.yaml."""

    brake_shares: tuple[float, ...] = (0.125, 0.25, 0.375, 0.5, 0.625, 0.75, 0.875, 1.0)  # of max_decel [1]
    accel_shares: tuple[float, ...] = (0.5, 1.0)  # of max_accel [1]
    speed_factors: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75, 0.9, 1.0, 1.1)  # quartic end speeds / current [1]
    longitudinal_times: tuple[float, ...] = (3.0, 5.0)  # time to reach the end speed [s]
    lateral_offsets: tuple[float, ...] = (1.0, -1.0, 2.0, -2.0, 3.0, -3.0)  # end offsets, left positive [m]
    lateral_times: tuple[float, ...] = (4.0, 2.5, 1.5)  # time to reach the end offset [s]

    def __post_init__(self) -> None:
        for name in ("brake_shares", "accel_shares"):
            if any(not 0.0 < share <= 1.0 for share in getattr(self, name)):
                raise ScenarioError(f"EvasionFamily {name}: every share must be in (0, 1], got {getattr(self, name)}")
        if any(not (np.isfinite(f) and f >= 0.0) for f in self.speed_factors):
            raise ScenarioError(f"EvasionFamily speed_factors: must be >= 0, got {self.speed_factors}")
        if any(not (np.isfinite(o) and o != 0.0) for o in self.lateral_offsets):
            raise ScenarioError(f"EvasionFamily lateral_offsets: non-zero (0 is always in), got {self.lateral_offsets}")
        for name in ("longitudinal_times", "lateral_times"):
            if not getattr(self, name) or any(not (np.isfinite(t) and t > 0.0) for t in getattr(self, name)):
                raise ScenarioError(f"EvasionFamily {name}: need positive times [s], got {getattr(self, name)}")


@dataclass(frozen=True)
class EgoStart:
    """The ego at the decision time: the human's (logged) pose and speed there."""

    stamp_ns: int  # decision time [ns]
    x: float  # ego frame origin [m]
    y: float  # [m]
    yaw: float  # [rad]
    speed: float  # >= 0 [m/s]

    @classmethod
    def from_log(cls, human: EgoTrajectory, frame: int) -> EgoStart:
        """The logged pose at ``frame`` and the speed of the odometry the stack is given there.

        Speed: numpy's gradient of the logged positions (central over the neighbouring frames, one-sided at the
        log's ends), as contract.spatial.odometry_msgs publishes it and the closed loop starts from.
        """
        if not 0 <= frame < human.stamps_ns.shape[0]:
            raise ScenarioError(f"EgoStart: frame {frame} outside the log's {human.stamps_ns.shape[0]} frames")
        low, high = max(frame - 1, 0), min(frame + 2, human.stamps_ns.shape[0])
        speed = 0.0
        if high - low >= 2:
            times = (human.stamps_ns[low:high] - human.stamps_ns[low]).astype(np.float64) / NS_PER_S
            velocity = np.gradient(human.xy[low:high], times, axis=0)[frame - low]
            speed = float(np.hypot(velocity[0], velocity[1]))
        x, y = (float(value) for value in human.xy[frame])
        return cls(int(human.stamps_ns[frame]), x, y, float(human.yaws[frame]), speed)


@dataclass(frozen=True, eq=False)
class ReferenceLine:
    """The human's path from the ego at the decision on, sampled every REFERENCE_STEP, straight beyond the log."""

    s: FloatArray  # (K,) arc length from the ego at the decision [m]
    xy: FloatArray  # (K, 2) world positions [m]
    heading: FloatArray  # (K,) tangent heading, unwrapped and smoothed [rad]


def human_reference(human: EgoTrajectory, start: EgoStart, length: float) -> ReferenceLine:
    """The reference line at least ``length`` metres long.

    The logged positions after the decision are thinned to steps of at least REFERENCE_STEP (a standing car's
    jitter is no path); where the log ends the line runs straight on. A human who backs up or turns on the
    spot leaves no forward path: the line is then straight along the ego's heading.
    """
    kept = [(start.x, start.y)]
    travelled = 0.0
    for x, y in human.xy[human.stamps_ns > start.stamp_ns].tolist():
        step = math.hypot(x - kept[-1][0], y - kept[-1][1])
        if step >= REFERENCE_STEP:
            kept.append((x, y))
            travelled += step
        if travelled > length:
            break
    polyline = np.array(kept)
    forward = np.array([np.cos(start.yaw), np.sin(start.yaw)])
    if polyline.shape[0] >= 2 and float((polyline[1] - polyline[0]) @ forward) <= 0.0:
        polyline = polyline[:1]
    direction = polyline[-1] - polyline[-2] if polyline.shape[0] >= 2 else forward
    direction = direction / np.linalg.norm(direction)
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(polyline, axis=0), axis=1))])
    extra = max(length - along[-1], 0.0) + 2.0 * REFERENCE_STEP
    polyline = np.vstack([polyline, polyline[-1] + extra * direction])
    along = np.append(along, along[-1] + extra)
    s = np.arange(0.0, along[-1] + 1e-9, REFERENCE_STEP)
    xy = np.stack([np.interp(s, along, polyline[:, 0]), np.interp(s, along, polyline[:, 1])], axis=-1)
    tangent = np.gradient(xy, axis=0)
    heading = np.unwrap(np.arctan2(tangent[:, 1], tangent[:, 0]))
    half = HEADING_SMOOTHING // 2
    padded = np.concatenate([np.full(half, heading[0]), heading, np.full(half, heading[-1])])
    smooth = np.convolve(padded, np.full(HEADING_SMOOTHING, 1.0 / HEADING_SMOOTHING), mode="valid")
    return ReferenceLine(s=s, xy=xy, heading=smooth)


@dataclass(frozen=True, eq=False)
class Longitudinal:
    """Speed profiles sampled at the plan's times."""

    s: FloatArray  # (P, T) arc length travelled [m]
    speed: FloatArray  # (P, T) [m/s]
    accel: FloatArray  # (P, T) [m/s^2]
    within_limits: BoolArray  # (P,)
    labels: tuple[str, ...]  # (P,)


def longitudinal_profiles(speed0: float, times: FloatArray, limits: EgoLimits, family: EvasionFamily) -> Longitudinal:
    """Keep, brake, accelerate and the planner's quartics (module docstring), duplicates dropped."""
    horizon = float(times[-1]) if times.size else 0.0
    fine = np.arange(0.0, horizon + FINE_STEP, FINE_STEP)
    top = max(limits.speed_limit, speed0)
    brakes = np.asarray(family.brake_shares) * limits.max_decel
    gains = np.asarray(family.accel_shares) * limits.max_accel
    # Commanded accelerations, built up at max_jerk: keep, brake, accelerate; integrated, clipped to [0, top].
    levels = np.concatenate([[0.0], -brakes, gains])[:, None]
    command = np.sign(levels) * np.minimum(np.abs(levels), limits.max_jerk * fine[None])
    increments = np.cumsum(0.5 * (command[:, 1:] + command[:, :-1]) * FINE_STEP, axis=1)
    ramped = np.clip(speed0 + np.concatenate([np.zeros((levels.shape[0], 1)), increments], axis=1), 0.0, top)
    desired = min(speed0, limits.speed_limit)
    targets = np.minimum(np.asarray(family.speed_factors) * desired, limits.speed_limit)
    target_grid, duration_grid = np.meshgrid(targets, family.longitudinal_times, indexing="ij")
    quartics = _quartic_speeds(speed0, target_grid.ravel(), duration_grid.ravel(), fine)
    speed = np.concatenate([ramped, quartics])
    labels = [f"keep {speed0:.1f} m/s"] + [f"brake at {value:.1f} m/s²" for value in brakes]
    labels += [f"accelerate at {value:.1f} m/s² to {top:.1f} m/s" for value in gains]
    labels += [
        f"speed to {t:.1f} m/s in {d:.1f} s" for t, d in zip(target_grid.ravel(), duration_grid.ravel(), strict=True)
    ]
    jerk_checked = np.arange(speed.shape[0]) >= ramped.shape[0]  # the ramps keep max_jerk by construction
    arc = np.concatenate([np.zeros((speed.shape[0], 1)), np.cumsum(0.5 * (speed[:, 1:] + speed[:, :-1]), 1)], 1)
    arc *= FINE_STEP
    accel = np.diff(speed, axis=1) / FINE_STEP
    slack = TOLERANCE * max(limits.max_decel, limits.max_accel)
    ok = np.all((accel >= -limits.max_decel - slack) & (accel <= limits.max_accel + slack), axis=1)
    jerk = np.abs(np.diff(accel, axis=1)) / FINE_STEP
    rolling = np.all(np.stack([speed[:, :-2], speed[:, 1:-1], speed[:, 2:]]) > 0.0, axis=0)  # a stop jumps
    ok &= ~jerk_checked | np.all(~rolling | (jerk <= limits.max_jerk * (1 + TOLERANCE)), axis=1)
    accel = np.concatenate([accel, accel[:, -1:]], axis=1)
    sampled = [_sample(values, fine, times) for values in (arc, speed, accel)]
    # Duplicates: a quartic to the current speed is "keep"; standing, every profile but the accelerations is.
    seen: set[bytes] = set()
    unique = []
    for index, row in enumerate(np.round(sampled[0], 6)):
        if row.tobytes() not in seen:
            seen.add(row.tobytes())
            unique.append(index)
    return Longitudinal(
        sampled[0][unique], sampled[1][unique], sampled[2][unique], ok[unique], tuple(labels[i] for i in unique)
    )


def _sample(values: FloatArray, fine: FloatArray, times: FloatArray) -> FloatArray:
    """(P, T) rows of (P, F) on the fine grid, linearly at ``times``."""
    position = np.clip(times / FINE_STEP, 0.0, fine.shape[0] - 1.0)
    below = np.minimum(np.floor(position).astype(np.int64), fine.shape[0] - 1)
    above = np.minimum(below + 1, fine.shape[0] - 1)
    weight = position - below
    result: FloatArray = values[:, below] * (1.0 - weight) + values[:, above] * weight
    return result


def _quartic_speeds(speed0: float, targets: FloatArray, durations: FloatArray, fine: FloatArray) -> FloatArray:
    """(Q, F) the planner's quartic s(t) from (0, speed0, accel 0) to (target speed, accel 0), then held.

    With no initial acceleration the speed is speed0 + (target - speed0) (3 tau^2 - 2 tau^3), tau = t / duration
    (the planner's c3, c4); clipped at 0, as the planner does: the ego never reverses.
    """
    tau = np.minimum(fine[None] / durations[:, None], 1.0)
    speed: FloatArray = speed0 + (targets - speed0)[:, None] * (3 * tau**2 - 2 * tau**3)
    return np.maximum(speed, 0.0)


def lateral_profiles(times: FloatArray, family: EvasionFamily) -> tuple[FloatArray, FloatArray, tuple[str, ...]]:
    """(L, T) offsets [m] and their rates [m/s]: 0 first, then quintics (0, 0, 0) -> (offset, 0, 0) over a time."""
    offset, duration = (
        grid.ravel() for grid in np.meshgrid(family.lateral_offsets, family.lateral_times, indexing="ij")
    )
    tau = np.clip(times[None] / duration[:, None], 0.0, 1.0)
    offsets = offset[:, None] * (10 * tau**3 - 15 * tau**4 + 6 * tau**5)
    rates = (offset / duration)[:, None] * (30 * tau**2 - 60 * tau**3 + 30 * tau**4)
    labels = ["in lane"] + [f"offset {o:+.1f} m in {d:.1f} s" for o, d in zip(offset, duration, strict=True)]
    zero = np.zeros((1, times.shape[0]))
    return np.concatenate([zero, offsets]), np.concatenate([zero, rates]), tuple(labels)


@dataclass(frozen=True, eq=False)
class EvasionCandidates:
    """Every lateral x longitudinal pairing, lateral-major: candidate i = lateral i // P, longitudinal i % P."""

    xy: FloatArray  # (C, T, 2) ego frame origin at each plan stamp [m]
    yaws: FloatArray  # (C, T) [rad]
    within_limits: BoolArray  # (C,)
    in_lane: BoolArray  # (C,) stays on the reference (lateral offset 0)
    lateral_labels: tuple[str, ...]  # (L,)
    longitudinal_labels: tuple[str, ...]  # (P,)

    def label(self, index: int) -> str:
        """What candidate ``index`` does, e.g. "in lane, brake at 4.0 m/s²"."""
        count = len(self.longitudinal_labels)
        return f"{self.lateral_labels[index // count]}, {self.longitudinal_labels[index % count]}"


def evasion_candidates(
    start: EgoStart, human: EgoTrajectory, times: FloatArray, limits: EgoLimits, family: EvasionFamily
) -> EvasionCandidates:
    """The family at ``times`` [s after the decision, >= 0, increasing], each checked against the limits."""
    longitudinal = longitudinal_profiles(start.speed, times, limits, family)
    offsets, rates, lateral_labels = lateral_profiles(times, family)
    reach = float(longitudinal.s.max()) if longitudinal.s.size else 0.0
    reference = human_reference(human, start, reach + 1.0)
    heading = np.interp(longitudinal.s, reference.s, reference.heading)  # (P, T)
    base_x = np.interp(longitudinal.s, reference.s, reference.xy[:, 0])
    base_y = np.interp(longitudinal.s, reference.s, reference.xy[:, 1])
    d = offsets[:, None, :]  # (L, 1, T)
    xy = np.stack([base_x[None] - d * np.sin(heading)[None], base_y[None] + d * np.cos(heading)[None]], axis=-1)
    yaws = heading[None] + np.arctan2(rates[:, None, :], longitudinal.speed[None])  # (L, P, T)
    lateral_count, profile_count, steps = offsets.shape[0], longitudinal.s.shape[0], times.shape[0]
    count = lateral_count * profile_count
    xy, yaws = xy.reshape(count, steps, 2), yaws.reshape(count, steps)
    ok = np.tile(longitudinal.within_limits, lateral_count)
    accel = np.broadcast_to(longitudinal.accel[None], (lateral_count, profile_count, steps)).reshape(count, steps)
    ok[ok] = _path_within_limits(xy[ok], yaws[ok], accel[ok], times, limits)
    in_lane = np.arange(count) < profile_count
    return EvasionCandidates(
        xy=xy,
        yaws=yaws,
        within_limits=ok,
        in_lane=in_lane,
        lateral_labels=lateral_labels,
        longitudinal_labels=longitudinal.labels,
    )


def _path_within_limits(
    xy: FloatArray, yaws: FloatArray, accel: FloatArray, times: FloatArray, limits: EgoLimits
) -> BoolArray:
    """(C,) whether each trajectory (C, T) keeps the friction circle, the curvature and the steering-rate limits."""
    if times.shape[0] < 2:
        return np.ones(yaws.shape[0], dtype=bool)
    dt = np.diff(times)
    step = np.diff(xy, axis=1)
    moved = np.hypot(step[..., 0], step[..., 1])  # (C, T-1)
    turned = np.diff(yaws, axis=1)
    lateral = moved * turned / (dt * dt)  # speed x yaw rate, as the metrics measure it
    longitudinal = 0.5 * (accel[:, 1:] + accel[:, :-1])
    ok = np.all(lateral**2 + longitudinal**2 <= (limits.max_decel * (1 + TOLERANCE)) ** 2, axis=1)
    standing = moved < STANDING_STEP
    curvature = turned / np.maximum(moved, STANDING_STEP)
    if np.any(standing):
        ok &= ~np.any(standing & (np.abs(turned) > 1e-4), axis=1)  # turning without moving: no car does that
        # A standing car holds its steering: carry the last curvature over the stamps it stands still.
        last = np.maximum.accumulate(np.where(standing, -1, np.arange(curvature.shape[1])), axis=1)
        carried = np.take_along_axis(curvature, np.maximum(last, 0), axis=1)
        curvature = np.where(last >= 0, carried, 0.0)
    ok &= np.all(np.abs(curvature) <= limits.max_curvature * (1 + TOLERANCE), axis=1)
    steer_rate = np.abs(np.diff(np.arctan(limits.wheelbase * curvature), axis=1)) / (0.5 * (dt[1:] + dt[:-1]))
    ok &= np.all(steer_rate <= limits.max_steer_rate * (1 + TOLERANCE), axis=1)
    return np.asarray(ok, dtype=bool)
