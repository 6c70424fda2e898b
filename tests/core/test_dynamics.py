"""Kinematic bicycle model: rollouts against closed-form motion, knot interpolation, track fitting."""

from __future__ import annotations

import numpy as np
import pytest

from advsim_ros.core.dynamics import (
    WIDE_BATCH,
    KinematicBounds,
    fit_track,
    integrate_speed,
    interpolate_knots,
    knot_weights,
    rollout,
)
from advsim_ros.core.types import ScenarioError

DT = 0.1
STEPS = 60


def _constant_controls(count: int, accel: float, rate: float) -> tuple[np.ndarray, np.ndarray]:
    return np.full((count, STEPS), accel), np.full((count, STEPS), rate)


def test_constant_speed_straight_rollout_moves_along_the_heading() -> None:
    initial = np.array([[3.0, -2.0, 0.6, 7.5, 0.0]])
    accel, rate = _constant_controls(1, 0.0, 0.0)
    traj = rollout(initial, accel, rate, DT)
    times = np.arange(STEPS) * DT
    np.testing.assert_allclose(traj.x[0], 3.0 + 7.5 * times * np.cos(0.6), atol=1e-9)
    np.testing.assert_allclose(traj.y[0], -2.0 + 7.5 * times * np.sin(0.6), atol=1e-9)
    np.testing.assert_allclose(traj.yaw[0], 0.6)
    np.testing.assert_allclose(traj.speed[0], 7.5)


def test_constant_curvature_rollout_stays_on_the_circle_of_radius_one_over_curvature() -> None:
    curvature, speed = 0.1, 10.0
    initial = np.array([[0.0, 0.0, 0.0, speed, curvature]])
    accel, rate = _constant_controls(1, 0.0, 0.0)
    traj = rollout(initial, accel, rate, DT)
    center = np.array([0.0, 1.0 / curvature])  # left turn from the origin heading +x
    radius = np.hypot(traj.x[0] - center[0], traj.y[0] - center[1])
    # The midpoint-heading step is a chord of the arc: 1 - cos(dtheta / 2) relative error per step at most.
    np.testing.assert_allclose(radius, 1.0 / curvature, rtol=2e-3)
    np.testing.assert_allclose(np.diff(traj.yaw[0]), speed * curvature * DT, rtol=1e-12)


def test_braking_stops_the_vehicle_and_it_never_reverses() -> None:
    initial = np.array([[0.0, 0.0, 0.0, 3.0, 0.0]])
    accel, rate = _constant_controls(1, -2.0, 0.0)
    traj = rollout(initial, accel, rate, DT)
    assert np.all(traj.speed >= 0.0)
    stop = int(np.argmax(traj.speed[0] == 0.0))
    assert stop == 15  # 3 m/s at 2 m/s^2: 1.5 s
    assert np.all(traj.speed[0, stop:] == 0.0)
    assert np.all(np.diff(traj.x[0]) >= 0.0)
    np.testing.assert_allclose(traj.x[0, -1], 3.0**2 / (2 * 2.0), atol=0.2)  # braking distance v^2 / 2a


def test_rollout_reports_the_realised_acceleration_and_curvature_rate_as_finite_differences() -> None:
    rng = np.random.default_rng(0)
    count = 5
    initial = np.column_stack(
        [rng.normal(size=count), rng.normal(size=count), rng.normal(size=count), rng.uniform(0, 5, count), np.zeros(5)]
    )
    accel = rng.uniform(-2, 2, (count, STEPS))
    rate = rng.uniform(-0.05, 0.05, (count, STEPS))
    traj = rollout(initial, accel, rate, DT)
    np.testing.assert_allclose(traj.accel[:, :-1], np.diff(traj.speed, axis=1) / DT, atol=1e-9)
    np.testing.assert_allclose(traj.curvature_rate[:, :-1], rate[:, :-1], atol=1e-9)
    # Positions follow the model: each step covers v dt along the midpoint heading.
    step = np.stack([np.diff(traj.x, axis=1), np.diff(traj.y, axis=1)], axis=-1)
    np.testing.assert_allclose(np.linalg.norm(step, axis=-1), traj.speed[:, :-1] * DT, atol=1e-9)


def test_wide_and_narrow_batches_integrate_to_the_same_trajectories() -> None:
    rng = np.random.default_rng(1)
    count = WIDE_BATCH + 10
    initial = np.column_stack(
        [
            rng.normal(size=count),
            rng.normal(size=count),
            rng.normal(size=count),
            rng.uniform(0, 5, count),
            rng.uniform(-0.1, 0.1, count),
        ]
    )
    accel = rng.uniform(-3, 3, (count, STEPS))
    rate = rng.uniform(-0.05, 0.05, (count, STEPS))
    wide = rollout(initial, accel, rate, DT)
    narrow = rollout(initial[:7], accel[:7], rate[:7], DT)
    for name in ("x", "y", "yaw", "speed", "curvature"):
        np.testing.assert_allclose(getattr(wide, name)[:7], getattr(narrow, name), rtol=0, atol=1e-9)
    speeds = integrate_speed(initial[:, 3], np.ascontiguousarray(accel[:, :-1].T), DT)
    assert speeds.shape == (STEPS, count)
    assert np.all(speeds >= 0.0)


def test_rollout_keeps_float32_inputs_in_float32() -> None:
    initial = np.zeros((3, 5), dtype=np.float32)
    accel = np.ones((3, STEPS), dtype=np.float32)
    traj = rollout(initial, accel, np.zeros_like(accel), DT)
    assert traj.x.dtype == np.float32
    assert traj.speed.dtype == np.float32


def test_knot_weights_interpolate_linearly_and_pass_through_the_knots() -> None:
    weights = knot_weights(STEPS, 4)
    np.testing.assert_allclose(weights.sum(axis=0), 1.0)
    assert np.all(weights >= 0.0)
    knots = np.array([[1.0, -2.0, 0.5, 3.0]])
    controls = interpolate_knots(knots, weights)
    assert controls[0, 0] == pytest.approx(1.0)
    assert controls[0, -1] == pytest.approx(3.0)
    # Between the first two knots (steps 0 and 59 / 3) the control is a straight line.
    inner = np.arange(0, 19)
    np.testing.assert_allclose(controls[0, inner], 1.0 + (-3.0) * inner / (59.0 / 3.0), atol=1e-12)
    with pytest.raises(ScenarioError, match="num_knots"):
        knot_weights(3, 4)


def test_fit_track_reproduces_a_track_the_model_can_drive() -> None:
    weights = knot_weights(STEPS, 4)
    initial = np.array([[10.0, 5.0, 0.3, 8.0, 0.01]])
    accel = interpolate_knots(np.array([[0.5, -1.0, 0.2, 1.0]]), weights)
    rate = interpolate_knots(np.array([[0.01, -0.02, 0.0, 0.01]]), weights)
    logged = rollout(initial, accel, rate, DT)
    steps = np.arange(STEPS)
    fit = fit_track(steps, np.column_stack([logged.x[0], logged.y[0]]), logged.yaw[0], STEPS, DT, KinematicBounds())
    assert fit.max_position_error < 0.05
    replay = rollout(fit.initial[None, :], fit.accel[None, :], fit.curvature_rate[None, :], DT)
    np.testing.assert_allclose(replay.x[0], logged.x[0], atol=0.05)
    np.testing.assert_allclose(replay.y[0], logged.y[0], atol=0.05)


def test_fit_track_of_a_noisy_track_stays_within_the_bounds_and_near_the_labels() -> None:
    rng = np.random.default_rng(2)
    times = np.arange(STEPS) * DT
    xy = np.column_stack([6.0 * times, 0.2 * times**2]) + rng.normal(0, 0.15, (STEPS, 2))
    yaws = np.arctan2(0.4 * times, 6.0) + rng.normal(0, 0.05, STEPS)
    bounds = KinematicBounds()
    fit = fit_track(np.arange(STEPS), xy, yaws, STEPS, DT, bounds)
    assert np.all(np.abs(fit.accel) <= bounds.max_accel + 1e-9)
    assert np.all(np.abs(fit.curvature_rate) <= bounds.max_curvature_rate + 1e-9)
    assert fit.position_rmse < 0.3
    replay = rollout(fit.initial[None, :], fit.accel[None, :], fit.curvature_rate[None, :], DT)
    assert np.max(np.abs(replay.curvature)) <= bounds.max_curvature + 1e-3
    assert np.max(np.abs(replay.lateral_accel())) <= bounds.max_lateral_accel + 1e-2


def test_fit_track_of_a_jittering_parked_car_stands_still() -> None:
    rng = np.random.default_rng(3)
    xy = np.array([3.0, 4.0]) + rng.normal(0, 0.05, (30, 2))
    fit = fit_track(np.arange(30), xy, np.full(30, 1.0), STEPS, DT, KinematicBounds())
    assert fit.initial[3] == 0.0
    assert np.all(fit.accel == 0.0)
    np.testing.assert_allclose(fit.initial[:2], np.median(xy, axis=0))


def test_fit_track_extends_a_track_seen_only_at_the_start() -> None:
    times = np.arange(20) * DT
    xy = np.column_stack([5.0 * times, np.zeros(20)])
    fit = fit_track(np.arange(20), xy, np.zeros(20), STEPS, DT, KinematicBounds())
    replay = rollout(fit.initial[None, :], fit.accel[None, :], fit.curvature_rate[None, :], DT)
    assert replay.x.shape == (1, STEPS)
    np.testing.assert_allclose(replay.x[0, 59], 5.0 * 5.9, atol=0.5)  # goes on at about the same speed


def test_fit_track_rejects_observations_that_do_not_start_at_step_zero() -> None:
    with pytest.raises(ScenarioError, match="start at 0"):
        fit_track(np.array([1, 2, 3]), np.zeros((3, 2)), np.zeros(3), STEPS, DT, KinematicBounds())


def test_kinematic_bounds_reject_non_positive_limits_by_name() -> None:
    with pytest.raises(ScenarioError, match="max_speed"):
        KinematicBounds(max_speed=0.0)
