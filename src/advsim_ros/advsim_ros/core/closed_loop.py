"""Closed loop: the ego driven by the stack's latest plan through a tracking controller.

Open loop (the paper's evaluation) scores the plan a stack makes after 1 s of history as if
the ego would drive it for 5 s. In closed loop the ego *executes* the plans: every replan
period (one LiDAR sweep) the stack plans from where the ego really is, and between plans a
controller tracks the latest plan on the kinematic bicycle model —

- steering by pure pursuit (R. C. Coulter, "Implementation of the Pure Pursuit Path Tracking
  Algorithm", CMU-RI-TR-92-01, 1992): the ego's reference point (the origin of the ego frame,
  taken as the rear axle) steers onto the arc through the plan point one lookahead distance
  ahead, the lookahead growing with speed;
- speed by a proportional law on the plan's speed a little ahead in time;
- within the limits of ``ControllerConfig``: acceleration, deceleration, jerk, steering angle
  and steering rate, so that the executed trajectory is one a car can drive whatever the plan.

Everything is deterministic (no clocks, no randomness): the same plans give the same
trajectory. The executed trajectory is scored by ``executed_metrics`` against the actors'
boxes — collision, its time, the smallest gap, time to collision, progress and comfort.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import numpy.typing as npt

from advsim_ros.core.futures import ActorFutures, BoolArray, interpolate_trajectory
from advsim_ros.core.geometry import box_distance, boxes_overlap, wrap_angle
from advsim_ros.core.metrics import NS_PER_S, trajectory_kinematics
from advsim_ros.core.types import EgoGeometry, FloatArray, Plan, ScenarioError

STOP_SPEED = 0.3  # below this, a plan that stands is met by braking to a halt [m/s]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True)
class ControllerConfig:
    """The tracking controller and the ego's physical limits; units beside each field."""

    wheelbase: float = 2.8  # [m]
    control_period: float = 0.02  # controller and integration step [s]
    lookahead_time: float = 0.8  # pure-pursuit lookahead distance = speed x this ... [s]
    min_lookahead: float = 3.0  # ... but at least this [m]
    speed_gain: float = 2.0  # acceleration per unit speed error [1/s]
    speed_preview: float = 0.3  # the plan's speed is read this far ahead of now [s]
    max_accel: float = 3.0  # [m/s^2]
    max_decel: float = 8.0  # [m/s^2] (a full brake on dry asphalt)
    max_jerk: float = 15.0  # [m/s^3]
    max_steer: float = 0.55  # road-wheel angle [rad]
    max_steer_rate: float = 0.8  # [rad/s]

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not (np.isfinite(value) and value > 0.0):
                raise ScenarioError(f"ControllerConfig {name}: must be a positive number, got {value}")


@dataclass(frozen=True)
class VehicleState:
    """The ego at one instant: pose of its reference point, speed and what the actuators hold."""

    x: float  # [m]
    y: float  # [m]
    yaw: float  # [rad]
    speed: float  # >= 0 [m/s]
    accel: float  # longitudinal acceleration commanded (at a standstill the brake stays applied) [m/s^2]
    steer: float  # road-wheel angle, positive to the left [rad]


@dataclass(frozen=True, eq=False)
class ExecutedTrajectory:
    """What the ego drove: one state per control step, the first at the start of the loop."""

    stamps_ns: IntArray  # (K,) [ns]
    states: FloatArray  # (K, 6) x, y, yaw, speed, accel, steer [m, m, rad, m/s, m/s^2, rad]
    plans: tuple[Plan, ...]  # the plans the stack gave, in order (one per replan)

    @property
    def xy(self) -> FloatArray:
        return self.states[:, :2]

    @property
    def yaws(self) -> FloatArray:
        return self.states[:, 2]


def yaw_rate_of(speed: float, steer: float, wheelbase: float) -> float:
    """Heading rate of the kinematic bicycle at a speed and road-wheel angle [rad/s]."""
    return speed * float(np.tan(steer)) / wheelbase


def plan_speeds(plan: Plan) -> tuple[FloatArray, FloatArray]:
    """The plan's speed between consecutive poses, at the midpoints of its stamps: (times [s], speeds [m/s])."""
    times = plan.stamps_ns.astype(np.float64) / NS_PER_S
    if times.shape[0] < 2:
        return times, np.zeros_like(times)
    speeds = np.linalg.norm(np.diff(plan.xy, axis=0), axis=1) / np.diff(times)
    return times[:-1] + 0.5 * np.diff(times), speeds


def pursuit_target(plan: Plan, position: FloatArray, lookahead: float) -> FloatArray:
    """The plan point to steer at: the first one at least ``lookahead`` away, after the point nearest the ego."""
    distances = np.linalg.norm(plan.xy - position, axis=1)
    nearest = int(np.argmin(distances))
    beyond = np.flatnonzero(distances[nearest:] >= lookahead)
    if beyond.size == 0:
        last: FloatArray = plan.xy[-1]
        return last
    target: FloatArray = plan.xy[nearest + int(beyond[0])]
    return target


def control_step(state: VehicleState, plan: Plan, now_ns: int, config: ControllerConfig) -> VehicleState:
    """One control period: steer and accelerate toward the plan within the limits, then integrate."""
    dt = config.control_period
    mid_times, speeds = plan_speeds(plan)
    now = now_ns / NS_PER_S
    wanted_speed = float(np.interp(now + config.speed_preview, mid_times, speeds)) if speeds.size else 0.0
    speed_now = float(np.interp(now, mid_times, speeds)) if speeds.size else 0.0
    # the plan's own acceleration ahead (feed-forward), plus a correction of the speed error: a P law alone
    # brakes only gain x preview of what the plan brakes
    feed_forward = (wanted_speed - speed_now) / config.speed_preview
    accel_command = np.clip(
        feed_forward + config.speed_gain * (speed_now - state.speed), -config.max_decel, config.max_accel
    )
    if wanted_speed < STOP_SPEED and state.speed < STOP_SPEED:
        accel_command = -config.max_decel  # the plan stands: brake to a halt, do not creep up to it
    jerk_step = config.max_jerk * dt
    accel = float(np.clip(accel_command, state.accel - jerk_step, state.accel + jerk_step))

    lookahead = max(config.min_lookahead, state.speed * config.lookahead_time)
    target = pursuit_target(plan, np.array([state.x, state.y]), lookahead)
    offset = target - np.array([state.x, state.y])
    alpha = float(wrap_angle(np.arctan2(offset[1], offset[0]) - state.yaw))
    distance = max(float(np.linalg.norm(offset)), 1e-6)
    steer_command = float(np.arctan2(2.0 * config.wheelbase * np.sin(alpha), distance))
    if abs(alpha) > 0.5 * np.pi:
        steer_command = 0.0  # the plan lies behind (the ego overshot a stop): nothing ahead to steer onto
    steer_command = float(np.clip(steer_command, -config.max_steer, config.max_steer))
    rate_step = config.max_steer_rate * dt
    steer = float(np.clip(steer_command, state.steer - rate_step, state.steer + rate_step))

    speed = max(state.speed + accel * dt, 0.0)  # standing, the brake holds: no reversing
    mean_speed = 0.5 * (state.speed + speed)
    yaw_rate = yaw_rate_of(mean_speed, steer, config.wheelbase)
    heading = state.yaw + 0.5 * yaw_rate * dt  # the step's midpoint heading
    return VehicleState(
        x=state.x + mean_speed * dt * float(np.cos(heading)),
        y=state.y + mean_speed * dt * float(np.sin(heading)),
        yaw=float(state.yaw + yaw_rate * dt),
        speed=speed,
        accel=accel,
        steer=steer,
    )


Planner = Callable[[int, VehicleState], Plan]  # (now [ns], the ego's state) -> the stack's plan


class Traffic(Protocol):
    """What moves with the ego in closed loop (core.reactive.ReactiveTraffic)."""

    def step(self, now_ns: int, ego: VehicleState) -> None:
        """Advance one control period from now_ns, the ego being in this state at now_ns."""


def initial_state(world_T_ego: FloatArray, speed: float, yaw_rate: float, config: ControllerConfig) -> VehicleState:
    """The ego at the decision frame as the controller takes it over: the logged pose, speed and the steer
    that gives the logged yaw rate (within the steering limit), no acceleration commanded yet."""
    yaw = float(np.arctan2(world_T_ego[1, 0], world_T_ego[0, 0]))
    steer = float(np.arctan2(yaw_rate * config.wheelbase, max(speed, 0.1)))
    return VehicleState(
        float(world_T_ego[0, 3]), float(world_T_ego[1, 3]), yaw, max(float(speed), 0.0), 0.0,
        float(np.clip(steer, -config.max_steer, config.max_steer)),
    )  # fmt: skip


def executed_as_plan(executed: ExecutedTrajectory, start_ns: int, step_ns: int, horizon_ns: int) -> Plan:
    """What the ego drove, sampled like a plan (start + step, ..., start + horizon), for the plan metrics."""
    stamps = start_ns + step_ns * np.arange(1, horizon_ns // step_ns + 1, dtype=np.int64)
    stamps = stamps[stamps <= executed.stamps_ns[-1]]
    xy, yaws, _ = interpolate_trajectory(executed.stamps_ns, executed.xy, executed.yaws, stamps)
    return Plan(stamps_ns=stamps, xy=xy, yaws=yaws)


def drive_closed_loop(
    initial: VehicleState,
    planner: Planner,
    start_ns: int,
    horizon_s: float,
    replan_period_s: float = 0.1,
    config: ControllerConfig | None = None,
    traffic: Traffic | None = None,
) -> ExecutedTrajectory:
    """Drive ``horizon_s`` from ``initial``: the planner is asked every replan period, the controller tracks between.

    The planner sees the ego's true state at each replan instant (in the graph: the pose the
    sweep is rendered from and the odometry published); a replan period must hold a whole
    number of control periods. ``traffic`` (reactive actors) steps with the ego: when the planner
    is asked at a stamp, the traffic is at that stamp too.
    """
    config = config or ControllerConfig()
    steps_per_plan = round(replan_period_s / config.control_period)
    if steps_per_plan < 1 or abs(steps_per_plan * config.control_period - replan_period_s) > 1e-9:
        raise ScenarioError(
            f"closed loop: replan period {replan_period_s} s is not a whole number of "
            f"control periods ({config.control_period} s)"
        )
    if horizon_s <= 0.0:
        raise ScenarioError(f"closed loop: horizon must be positive, got {horizon_s} s")
    step_ns = round(config.control_period * NS_PER_S)
    total = round(horizon_s / config.control_period)
    state, plan = initial, None
    stamps, states, plans = [start_ns], [_as_row(initial)], []
    for step in range(total):
        now_ns = start_ns + step * step_ns
        if step % steps_per_plan == 0:
            plan = planner(now_ns, state)
            plans.append(plan)
        assert plan is not None
        following = control_step(state, plan, now_ns, config)
        if traffic is not None:
            traffic.step(now_ns, state)  # the actors see the ego where it is at the step's start, as the controller
        state = following
        stamps.append(now_ns + step_ns)
        states.append(_as_row(state))
    return ExecutedTrajectory(np.asarray(stamps, dtype=np.int64), np.asarray(states), tuple(plans))


def _as_row(state: VehicleState) -> list[float]:
    return [state.x, state.y, state.yaw, state.speed, state.accel, state.steer]


@dataclass(frozen=True)
class ClosedLoopMetrics:
    """How the executed trajectory went, against the actors' boxes at the same stamps."""

    collided: bool  # the ego's box overlapped an actor's at some step
    collision_time: float  # first such step after the start [s]; inf without a collision
    min_distance: float  # smallest gap between the ego's box and any actor's [m]; inf without actors
    min_time_to_collision: float  # smallest constant-velocity time to collision over the run [s]; inf if none
    progress: float  # path length driven [m]
    max_lateral_acceleration: float  # [m/s^2]
    max_longitudinal_acceleration: float  # largest |change of speed| per second [m/s^2]
    max_jerk: float  # largest |change of the commanded acceleration| per second [m/s^3]


def executed_metrics(
    executed: ExecutedTrajectory,
    actors: ActorFutures,
    ego: EgoGeometry,
    ttc_horizon_s: float = 5.0,
    ttc_step_s: float = 0.1,
) -> ClosedLoopMetrics:
    """Collision, gaps, time to collision, progress and comfort of what the ego drove.

    ``actors`` must hold one state per executed stamp; an actor counts only at the stamps where it
    exists. Time to collision at a step extrapolates the ego and every actor present then and at the
    next step at their current velocities (finite differences of their poses) up to ``ttc_horizon_s``
    and takes the first overlap.
    """
    if actors.states.shape[1] != executed.stamps_ns.shape[0]:
        raise ScenarioError(
            f"executed metrics: {actors.states.shape[1]} actor states per actor for "
            f"{executed.stamps_ns.shape[0]} executed stamps"
        )
    times = (executed.stamps_ns - executed.stamps_ns[0]).astype(np.float64) / NS_PER_S
    ego_boxes = ego.boxes(executed.xy, executed.yaws)
    kinematics = trajectory_kinematics(times, executed.xy, np.unwrap(executed.yaws))
    progress = float(np.linalg.norm(np.diff(executed.xy, axis=0), axis=1).sum())
    comfort = {
        "max_lateral_acceleration": _largest(kinematics.lateral_acceleration),
        "max_longitudinal_acceleration": _largest(np.diff(executed.states[:, 3]) / np.diff(times)),
        "max_jerk": _largest(np.diff(executed.states[:, 4]) / np.diff(times)),  # of the command: bounded
    }
    if actors.num_actors == 0:
        return ClosedLoopMetrics(False, np.inf, np.inf, np.inf, progress, **comfort)
    actor_boxes, present = actors.finite_boxes(), actors.present
    overlapping = (boxes_overlap(actor_boxes, ego_boxes[None]) & present).any(axis=0)
    hits = np.flatnonzero(overlapping)
    collision_time = float(times[hits[0]]) if hits.size else np.inf
    min_distance = float(np.where(present, box_distance(actor_boxes, ego_boxes[None]), np.inf).min())
    ttc = _time_to_collision(times, ego_boxes, actor_boxes, present, ttc_horizon_s, ttc_step_s)
    return ClosedLoopMetrics(bool(hits.size), collision_time, min_distance, ttc, progress, **comfort)


def _largest(values: FloatArray) -> float:
    return float(np.abs(values).max()) if values.size else 0.0


def _time_to_collision(
    times: FloatArray, ego_boxes: FloatArray, actor_boxes: FloatArray, present: BoolArray, horizon: float, step: float
) -> float:
    """Smallest constant-velocity time to collision over the run [s] (inf when none within the horizon).

    An actor is extrapolated from a step only when it exists then and at the next (its velocity needs both).
    """
    if times.shape[0] < 2:
        return np.inf
    dt = np.diff(times)[:, None]
    ego_velocity = np.diff(ego_boxes[:, :2], axis=0) / dt  # (K-1, 2)
    actor_velocity = np.diff(actor_boxes[:, :, :2], axis=1) / dt[None]  # (N, K-1, 2)
    ahead = np.arange(0.0, horizon + 1e-9, step)  # (L,)
    ego_future = np.repeat(ego_boxes[:-1, None, :], ahead.shape[0], axis=1)  # (K-1, L, 5)
    ego_future[..., :2] += ego_velocity[:, None, :] * ahead[None, :, None]
    actor_future = np.repeat(actor_boxes[:, :-1, None, :], ahead.shape[0], axis=2)  # (N, K-1, L, 5)
    actor_future[..., :2] += actor_velocity[:, :, None, :] * ahead[None, None, :, None]
    moving = present[:, :-1] & present[:, 1:]  # (N, K-1)
    overlapping = np.any(boxes_overlap(actor_future, ego_future[None]) & moving[:, :, None], axis=0)  # (K-1, L)
    first = np.where(np.any(overlapping, axis=1), ahead[np.argmax(overlapping, axis=1)], np.inf)
    return float(first.min())
