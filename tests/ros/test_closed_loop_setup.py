"""The player's closed-loop setup (ros.closed_loop.closed_loop_setup) on a synthetic log's ego and window."""

from __future__ import annotations

import numpy as np
import pytest

from advsim_ros.contract.spatial import odometry_msgs
from advsim_ros.core.closed_loop import ControllerConfig, initial_state
from advsim_ros.core.episode import WindowConfig
from advsim_ros.core.reactive import IdmConfig
from advsim_ros.io.synthetic import SyntheticConfig, SyntheticLog, generate_synthetic_log
from advsim_ros.ros.closed_loop import closed_loop_setup


@pytest.fixture(scope="module")
def log() -> SyntheticLog:
    return generate_synthetic_log(np.random.default_rng(7), SyntheticConfig(duration=3.0), "short_7")


def test_the_drive_starts_from_the_logged_ego_at_the_decision_and_replans_at_every_later_frame_but_the_last(
    log: SyntheticLog,
) -> None:
    scenario = log.scenario
    window = WindowConfig(window_start_frame=2, history_frames=5, future_frames=20)
    frames = window.frame_indices(scenario.num_frames)
    odometry = odometry_msgs(scenario.ego, "world", "base_link")
    controller = ControllerConfig()
    setup = closed_loop_setup(scenario, frames, odometry, window, controller, None)
    decision = 2 + 4  # the window's first frame + the last history frame's index
    assert setup.decision_stamp_ns == int(scenario.frame_stamps_ns[decision])
    twist = odometry[decision].twist.twist
    speed = float(np.hypot(twist.linear.x, twist.linear.y))
    assert speed > 1.0  # the synthetic ego drives
    assert setup.start == initial_state(scenario.ego.poses[decision], speed, twist.angular.z, controller)
    assert [frame.log_frame for frame in setup.frames] == list(range(decision + 1, frames.stop - 1))
    assert setup.frames[0].log_stamp_ns == int(scenario.frame_stamps_ns[decision + 1])
    np.testing.assert_array_equal(setup.frames[-1].logged_world_T_ego, scenario.ego.poses[frames.stop - 2])
    assert setup.period_s == window.frame_period
    assert setup.horizon_s == pytest.approx(window.future_frames * window.frame_period)
    np.testing.assert_array_equal(setup.ego_size, scenario.ego_geometry.size)
    assert setup.reactive is None
    idm = IdmConfig()
    reactive = closed_loop_setup(scenario, frames, odometry, window, controller, idm).reactive
    assert reactive is not None
    assert reactive.config is idm
    assert reactive.actors == scenario.actors
