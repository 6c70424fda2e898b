"""Closed-loop episodes offline: the reference stack drives a synthetic log, each sweep rendered where the ego is."""

from __future__ import annotations

import numpy as np
import pytest

from advsim_ros.core.closed_loop import ControllerConfig
from advsim_ros.io.synthetic import SyntheticConfig, SyntheticLog, generate_synthetic_log
from advsim_ros.stacks.closed_loop import closed_loop_episode
from advsim_ros.stacks.modular.config import ModularStackConfig, PlannerConfig
from advsim_ros.stacks.modular.stack import ModularStack
from advsim_ros.stacks.replay import replay


@pytest.fixture(scope="module")
def lead_brake() -> SyntheticLog:
    return generate_synthetic_log(np.random.default_rng(1), SyntheticConfig(family="lead_brake"))


def test_the_stack_drives_from_sweeps_rendered_where_it_is_and_the_run_repeats_exactly(
    lead_brake: SyntheticLog,
) -> None:
    episode = closed_loop_episode(ModularStack(), lead_brake, decision_frame=9)
    again = closed_loop_episode(ModularStack(), lead_brake, decision_frame=9)
    assert np.array_equal(episode.executed.states, again.executed.states)
    executed = episode.executed
    assert len(executed.plans) == 50  # a new plan every 0.1 s for 5 s
    offline = replay(ModularStack(), lead_brake.scenario, range(0, 10))[-1].output.plan
    assert np.array_equal(executed.plans[0].xy, offline.xy)  # the decision plan is the open-loop one
    limits = ControllerConfig()
    assert np.abs(np.diff(executed.states[:, 4])).max() <= limits.max_jerk * limits.control_period + 1e-9
    assert np.abs(executed.states[:, 5]).max() <= limits.max_steer + 1e-9
    # the stack overtakes the braking lead: it steers out of its lane, around it, without touching it
    assert np.abs(executed.xy[:, 1] - executed.xy[0, 1]).max() > 1.0
    assert not episode.closed_loop.collided
    assert episode.closed_loop.progress > 30.0


def test_a_lane_keeping_stack_is_scored_open_and_closed_loop_on_the_same_scene(lead_brake: SyntheticLog) -> None:
    lane_keeping = ModularStackConfig(planner=PlannerConfig(lateral_offsets=(0.0,)))
    episode = closed_loop_episode(ModularStack(lane_keeping), lead_brake, decision_frame=9)
    # the plan made before the lead brakes runs into it (open loop) ...
    assert 1.0 < episode.open_loop_collision_time < 5.0
    # ... and what the ego drove is scored on its own: with a collision, its time and a zero gap
    metrics = episode.closed_loop
    assert metrics.collided == np.isfinite(metrics.collision_time)
    if metrics.collided:
        assert metrics.min_distance == 0.0
        assert metrics.min_time_to_collision == 0.0
    assert np.abs(episode.executed.xy[:, 1] - episode.executed.xy[0, 1]).max() < 0.05  # it kept its lane
