"""Closed loop: plans tracked within the ego's limits; a replanning ego avoids what one plan would hit."""

from __future__ import annotations

import numpy as np
import pytest

from advsim_ros.core.closed_loop import (
    NS_PER_S,
    ControllerConfig,
    VehicleState,
    drive_closed_loop,
    executed_metrics,
)
from advsim_ros.core.futures import ActorFutures, actor_futures_at
from advsim_ros.core.metrics import MetricsConfig, collision_steps
from advsim_ros.core.types import ActorClass, ActorTrack, EgoGeometry, Plan, ScenarioError

START_NS = 10 * NS_PER_S
EGO = EgoGeometry()
LIMITS = ControllerConfig()


def _plan(now_ns: int, xy_of_t: object, horizon: float = 5.0) -> Plan:
    """A plan of 50 poses 0.1 s apart starting 0.1 s after now, positions from a function of time since now."""
    times = np.arange(1, round(horizon / 0.1) + 1) * 0.1
    xy = np.array([xy_of_t(t) for t in times])  # type: ignore[operator]
    heading = np.diff(np.vstack([xy[:1] - (xy[1] - xy[0]), xy]), axis=0)
    return Plan(now_ns + np.round(times * NS_PER_S).astype(np.int64), xy, np.arctan2(heading[:, 1], heading[:, 0]))


def _limits_hold(states: np.ndarray, config: ControllerConfig) -> None:
    dt = config.control_period
    accel, steer = states[:, 4], states[:, 5]
    assert accel.max() <= config.max_accel + 1e-9
    assert accel.min() >= -config.max_decel - 1e-9
    assert np.abs(np.diff(accel)).max() <= config.max_jerk * dt + 1e-9
    assert np.abs(steer).max() <= config.max_steer + 1e-9
    assert np.abs(np.diff(steer)).max() <= config.max_steer_rate * dt + 1e-9
    assert states[:, 3].min() >= 0.0


def test_a_straight_constant_speed_plan_is_tracked_closely() -> None:
    start = VehicleState(0.0, 0.0, 0.0, 10.0, 0.0, 0.0)

    def planner(now_ns: int, state: VehicleState) -> Plan:
        return _plan(now_ns, lambda t: (state.x + 10.0 * t, 0.0))

    executed = drive_closed_loop(start, planner, START_NS, 5.0)
    assert executed.stamps_ns[0] == START_NS
    assert executed.stamps_ns[-1] == START_NS + 5 * NS_PER_S
    assert np.abs(executed.xy[:, 1]).max() < 1e-9
    assert executed.states[-1, 3] == pytest.approx(10.0, abs=0.05)
    assert executed.xy[-1, 0] == pytest.approx(50.0, abs=0.5)
    assert len(executed.plans) == 50  # one plan per 0.1 s


def test_a_lane_change_is_followed_within_the_steering_and_jerk_limits() -> None:
    start = VehicleState(0.0, 0.0, 0.0, 10.0, 0.0, 0.0)
    lane_change = _plan(START_NS, lambda t: (10.0 * t, 3.5 / (1.0 + np.exp(-3.0 * (t - 2.0)))))

    executed = drive_closed_loop(start, lambda now_ns, state: lane_change, START_NS, 5.0)
    _limits_hold(executed.states, LIMITS)
    assert executed.xy[-1, 1] == pytest.approx(3.5, abs=0.15)  # in the next lane
    assert abs(executed.yaws[-1]) < 0.05  # and straight again
    assert np.abs(executed.states[:, 5]).max() > 0.02  # it did steer


def test_a_plan_asking_for_the_impossible_gets_what_the_limits_allow() -> None:
    start = VehicleState(0.0, 0.0, 0.0, 15.0, 0.0, 0.0)
    stop_now = Plan(START_NS + np.arange(1, 51) * NS_PER_S // 10, np.tile([[1.0, 0.0]], (50, 1)), np.zeros(50))
    executed = drive_closed_loop(start, lambda now_ns, state: stop_now, START_NS, 5.0)
    _limits_hold(executed.states, LIMITS)
    assert executed.states[:, 4].min() == pytest.approx(-LIMITS.max_decel)  # full brake, reached through the jerk limit
    assert executed.states[-1, 3] == 0.0  # stands, never reverses
    stopping = 15.0**2 / (2 * LIMITS.max_decel)
    assert executed.xy[-1, 0] > stopping  # the jerk limit costs distance: no instant full brake


def _braking_lead(stamps_ns: np.ndarray) -> ActorFutures:
    """A car 20 m ahead at 10 m/s that brakes at 6 m/s^2 to a stop from 1 s on."""
    t = (stamps_ns - START_NS) / NS_PER_S
    braking = np.clip(t - 1.0, 0.0, 10.0 / 6.0)
    x = 20.0 + 10.0 * np.minimum(t, 1.0) + 10.0 * braking - 3.0 * braking**2
    states = np.stack([x, np.zeros_like(x), np.zeros_like(x)], axis=-1)[None]
    return ActorFutures(states=states, sizes=np.array([[4.5, 1.9]]))


def _keeps_a_gap(lead_x_at: object) -> object:
    """A planner predicting the lead at constant velocity: cruise while it is as fast, else stop behind it."""

    def planner(now_ns: int, state: VehicleState) -> Plan:
        lead_now = lead_x_at(now_ns)  # type: ignore[operator]
        lead_speed = (lead_now - lead_x_at(now_ns - NS_PER_S // 10)) / 0.1  # type: ignore[operator]
        stop_at = lead_now - 4.5 - 4.0
        if lead_speed >= state.speed - 0.1:
            return _plan(now_ns, lambda t: (state.x + state.speed * t, 0.0))
        decel = min(state.speed**2 / (2 * max(stop_at - state.x, 0.1)), 8.0)
        stop_t = state.speed / decel if decel > 0 else 0.0
        return _plan(
            now_ns, lambda t: (state.x + state.speed * min(t, stop_t) - 0.5 * decel * min(t, stop_t) ** 2, 0.0)
        )

    return planner


def test_closed_loop_brakes_for_a_braking_lead_where_the_open_loop_plan_collides() -> None:
    start = VehicleState(0.0, 0.0, 0.0, 10.0, 0.0, 0.0)

    def lead_x(now_ns: int) -> float:
        return float(_braking_lead(np.array([now_ns])).states[0, 0, 0])

    planner = _keeps_a_gap(lead_x)
    open_loop = Plan(**vars(planner(START_NS, start)))  # the plan made at the start, driven blind for 5 s
    open_plan = Plan(
        np.concatenate([[START_NS], open_loop.stamps_ns]),
        np.vstack([[0.0, 0.0], open_loop.xy]),
        np.concatenate([[0.0], open_loop.yaws]),
    )
    assert collision_steps(open_plan, _braking_lead(open_plan.stamps_ns), EGO, MetricsConfig()).any()

    executed = drive_closed_loop(start, planner, START_NS, 5.0)
    metrics = executed_metrics(executed, _braking_lead(executed.stamps_ns), EGO)
    assert not metrics.collided
    assert metrics.collision_time == np.inf
    assert 0.5 < metrics.min_distance < 8.0  # it stopped behind the lead, close
    assert metrics.min_time_to_collision < 5.0  # the braking lead was a threat at some point
    assert executed.states[-1, 3] < 0.5
    _limits_hold(executed.states, LIMITS)
    assert metrics.max_longitudinal_acceleration <= LIMITS.max_decel + 1e-9


def test_executed_metrics_find_a_collision_and_its_time() -> None:
    start = VehicleState(0.0, 0.0, 0.0, 10.0, 0.0, 0.0)
    blind = drive_closed_loop(start, lambda now_ns, s: _plan(now_ns, lambda t: (s.x + 10.0 * t, 0.0)), START_NS, 5.0)
    metrics = executed_metrics(blind, _braking_lead(blind.stamps_ns), EGO)
    assert metrics.collided
    assert 1.0 < metrics.collision_time < 5.0
    assert metrics.min_distance == 0.0
    assert metrics.progress == pytest.approx(50.0, abs=0.5)


def test_the_same_plans_drive_the_same_trajectory_and_bad_settings_are_named() -> None:
    start = VehicleState(0.0, 0.0, 0.0, 10.0, 0.0, 0.0)
    lane_change = _plan(START_NS, lambda t: (10.0 * t, 3.5 / (1.0 + np.exp(-3.0 * (t - 2.0)))))
    first = drive_closed_loop(start, lambda now_ns, state: lane_change, START_NS, 3.0)
    again = drive_closed_loop(start, lambda now_ns, state: lane_change, START_NS, 3.0)
    assert np.array_equal(first.states, again.states)
    with pytest.raises(ScenarioError, match="ControllerConfig max_jerk: must be a positive number"):
        ControllerConfig(max_jerk=0.0)
    with pytest.raises(ScenarioError, match=r"replan period 0\.05 s is not a whole number"):
        drive_closed_loop(start, lambda now_ns, state: lane_change, START_NS, 1.0, 0.05, ControllerConfig(0.03))


def _parked_from(first_s: float, x: float) -> ActorTrack:
    """A 4.5 x 1.9 m car labelled at x (on the ego's line) from `first_s` after the start to 5 s, 10 Hz."""
    times = np.arange(round(first_s * 10), 51) / 10.0
    stamps = START_NS + np.round(times * NS_PER_S).astype(np.int64)
    centers = np.tile([x, 0.0, 0.75], (times.size, 1))
    return ActorTrack("late", ActorClass.VEHICLE, np.array([4.5, 1.9, 1.5]), stamps, centers, np.zeros(times.size))


def test_an_actor_that_appears_late_is_hit_only_once_it_is_there() -> None:
    late = _parked_from(4.0, 20.0)  # labelled from 4.0 s: box 17.75-22.25 m
    start = VehicleState(0.0, 0.0, 0.0, 10.0, 0.0, 0.0)
    passing = drive_closed_loop(start, lambda now_ns, s: _plan(now_ns, lambda t: (s.x + 10.0 * t, 0.0)), START_NS, 5.0)
    metrics = executed_metrics(passing, actor_futures_at([late], passing.stamps_ns), EGO)
    assert not metrics.collided  # it drove over that spot at ~2 s, before the car was there
    assert metrics.min_distance > 10.0
    assert metrics.min_time_to_collision == np.inf
    standing = VehicleState(16.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # the ego's box reaches x = 19.25 m
    stop = Plan(START_NS + np.arange(1, 51) * NS_PER_S // 10, np.tile([[16.0, 0.0]], (50, 1)), np.zeros(50))
    waiting = drive_closed_loop(standing, lambda now_ns, s: stop, START_NS, 5.0)
    hit = executed_metrics(waiting, actor_futures_at([late], waiting.stamps_ns), EGO)
    assert hit.collided
    assert hit.collision_time == pytest.approx(3.96)  # the first 20 ms step within 0.05 s of its first label
