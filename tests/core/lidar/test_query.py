"""The sweep of one requested frame (core.lidar.query): re-simulated where the ego was logged, rendered elsewhere."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from advsim_ros.core.lidar.boxes import yaw_pose
from advsim_ros.core.lidar.config import ResimNodeConfig
from advsim_ros.core.lidar.novel_view import render_from_model
from advsim_ros.core.lidar.query import frame_sweep, moved_away, world_rng
from advsim_ros.core.lidar.resim import ResimModel
from advsim_ros.core.types import ScenarioError
from advsim_ros.io.synthetic import SyntheticLog

FRAME = 15
SIM_STAMP = 123_000_000_000


def test_moved_away_compares_the_offset_and_the_turn_with_the_limits() -> None:
    logged = yaw_pose([10.0, 5.0, 0.0], 0.3)
    assert not moved_away(logged, logged, 0.01, 0.001)
    assert moved_away(yaw_pose([10.02, 5.0, 0.0], 0.3), logged, 0.01, 0.001)
    assert not moved_away(yaw_pose([10.005, 5.0, 0.0], 0.3), logged, 0.01, 0.001)
    assert moved_away(yaw_pose([10.0, 5.0, 0.0], 0.302), logged, 0.01, 0.001)
    # the turn is the shorter way round: just either side of +-pi is almost no turn
    assert not moved_away(
        yaw_pose([0.0, 0.0, 0.0], np.pi - 1e-4), yaw_pose([0.0, 0.0, 0.0], -np.pi + 1e-4), 0.01, 0.001
    )


def test_at_the_logged_pose_and_nothing_moved_the_logged_sweep_comes_back_with_the_sim_stamp(
    short_log: SyntheticLog,
) -> None:
    scenario = short_log.scenario
    sweeps = {sweep.stamp_ns: sweep for sweep in scenario.sweeps}
    logged = sweeps[int(scenario.frame_stamps_ns[FRAME])]
    out = frame_sweep(None, scenario, sweeps, FRAME, SIM_STAMP, scenario.ego.poses[FRAME], (), ResimNodeConfig())
    assert out.stamp_ns == SIM_STAMP
    assert out.frame_id == logged.frame_id
    assert out.points is logged.points  # no model needed
    np.testing.assert_array_equal(out.sensor_pose, logged.sensor_pose)


def test_away_from_the_logged_pose_or_without_a_logged_sweep_it_is_rendered_from_the_model(
    short_log: SyntheticLog, short_model: ResimModel
) -> None:
    scenario = short_log.scenario
    sweeps = {sweep.stamp_ns: sweep for sweep in scenario.sweeps}
    config = ResimNodeConfig(seed=3)
    away = scenario.ego.poses[FRAME] @ yaw_pose([0.0, 2.0, 0.0], 0.0)  # 2 m to the left
    with pytest.raises(ScenarioError, match="none was built"):
        frame_sweep(None, scenario, sweeps, FRAME, SIM_STAMP, away, (), config)
    stamp = int(scenario.frame_stamps_ns[FRAME])
    sensor_pose = away @ scenario.ego_T_sensor
    expected = render_from_model(short_model, scenario, sensor_pose, scenario.actors, stamp, world_rng(3, (), stamp))
    out = frame_sweep(short_model, scenario, sweeps, FRAME, SIM_STAMP, away, (), config)
    assert (out.stamp_ns, out.frame_id) == (SIM_STAMP, scenario.sweeps[0].frame_id)
    np.testing.assert_array_equal(out.sensor_pose, sensor_pose)
    np.testing.assert_array_equal(out.points, expected)
    # a frame whose sweep was not kept is rendered even at the logged pose
    at_log = scenario.ego.poses[FRAME]
    kept = {s: sweep for s, sweep in sweeps.items() if s != stamp}
    rendered = frame_sweep(short_model, scenario, kept, FRAME, SIM_STAMP, at_log, (), config)
    logged_sensor = at_log @ scenario.ego_T_sensor
    np.testing.assert_array_equal(rendered.sensor_pose, logged_sensor)
    rng = world_rng(3, (), stamp)
    np.testing.assert_array_equal(
        rendered.points, render_from_model(short_model, scenario, logged_sensor, scenario.actors, stamp, rng)
    )
    # within render_distance the logged sweep is re-simulated, not rendered
    near = frame_sweep(
        None, scenario, sweeps, FRAME, SIM_STAMP, away, (), dataclasses.replace(config, render_distance=3.0)
    )
    assert near.points is sweeps[stamp].points
