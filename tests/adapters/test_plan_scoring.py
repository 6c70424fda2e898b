"""A stack's plan through the adapter and then the scorer: no jerk, standstill or heading the plan does not hold.

The path a profile-attached stack's answer takes in the graph: the adapter parses it
(messages.plan_poses), makes the contract's plan (plans.contract_plan, driven from the odometry the
adapter last had before the plan was made, ego_before), publishes it as nav_msgs/Path (CDR); the
scorer reads it (contract.plan.plan_from_path) and scores it (core.scoring.evaluate_query).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from advsim_ros.adapters.messages import plan_poses
from advsim_ros.adapters.plans import PlanarTransform, Poses, contract_plan, ego_before
from advsim_ros.adapters.profile import PlanOutput, TimingProfile
from advsim_ros.contract import codec, names
from advsim_ros.contract.codec import header_msg, message
from advsim_ros.contract.plan import path_msg, plan_from_path
from advsim_ros.core.lidar.boxes import yaw_pose
from advsim_ros.core.metrics import MetricsConfig
from advsim_ros.core.objective import ObjectiveConfig, ScorerSettings
from advsim_ros.core.scoring import QueryEvaluation, evaluate_query
from advsim_ros.core.types import EgoTrajectory, FloatArray, Scenario

FRAME_NS = 100_000_000  # 10 Hz
START_NS = 1_000_000_000_000
DECISION = 9  # the decision sweep: the last of 1 s of history
SPEED = 8.0  # the logged ego's constant speed [m/s]
HEADING = math.radians(30.0)  # its constant heading: a diagonal, so yaw 0 would be wrong [rad]
DIRECTION = np.array([math.cos(HEADING), math.sin(HEADING)])
DELAY_NS = round(TimingProfile().decision_delay * 1e9)  # a timer-driven stack's plan is made this late
SETTINGS = ScorerSettings(ObjectiveConfig(), MetricsConfig())


def _scenario() -> Scenario:
    """70 frames of an ego driving straight at SPEED along HEADING (the human trajectory), no actors."""
    stamps = START_NS + FRAME_NS * np.arange(70, dtype=np.int64)
    xy = SPEED * ((stamps - START_NS) / 1e9)[:, None] * DIRECTION
    poses = np.stack([yaw_pose([x, y, 0.0], HEADING) for x, y in xy])
    return Scenario("straight", stamps, EgoTrajectory(stamps, poses), ())


def _odometry(scenario: Scenario) -> dict[int, tuple[float, FloatArray]]:
    """What the adapter heard from the player: odometry of every frame up to the decision sweep."""
    return {int(scenario.frame_stamps_ns[f]): (SPEED, scenario.ego.xy[f]) for f in range(DECISION + 1)}


def _spatial_path(start: FloatArray, length: float = 80.0) -> object:
    """A straight nav_msgs/Path along HEADING from `start`, a pose a metre, no times and no orientations."""
    poses = [
        message(
            names.POSE_STAMPED,
            header=header_msg(0, "world"),
            pose=message(
                names.POSE,
                position=message(names.POINT, x=float(x), y=float(y), z=0.0),
                orientation=message(names.QUATERNION, x=0.0, y=0.0, z=0.0, w=1.0),
            ),
        )
        for x, y in (start + np.arange(0.0, length + 1e-9, 1.0)[:, None] * DIRECTION).tolist()
    ]
    return message(names.PATH, header=header_msg(0, "world"), poses=poses)


def _scored(poses: Poses, made_ns: int, output: PlanOutput, anchored: bool = True) -> QueryEvaluation:
    """The adapter's contract plan for the decision sweep, over the wire, scored."""
    scenario = _scenario()
    sweep_ns = int(scenario.frame_stamps_ns[DECISION])
    speed, ego = ego_before(_odometry(scenario), made_ns)
    plan = contract_plan(poses, made_ns, sweep_ns, speed, output, PlanarTransform(), ego if anchored else None)
    wire = codec.decode(codec.encode(path_msg(plan, sweep_ns, "world")), names.PATH)
    return evaluate_query(plan_from_path(wire), scenario, (), DECISION, SETTINGS, None)


@pytest.mark.parametrize(
    "start_along",
    [
        0.0,  # from the pose the stack last heard of (the decision sweep's odometry): 0.1 s old when it plans
        SPEED * DELAY_NS / 1e9,  # from where the ego is when it plans (the stack extrapolated its pose)
        -1.0,  # from a metre behind the ego (planners that keep a little of the path behind)
    ],
)
def test_a_constant_speed_straight_spatial_plan_made_a_decision_delay_late_scores_no_jerk(start_along: float) -> None:
    scenario = _scenario()
    made_ns = int(scenario.frame_stamps_ns[DECISION]) + DELAY_NS
    start = scenario.ego.xy[DECISION] + start_along * DIRECTION
    poses = plan_poses("spatial_path", _spatial_path(start))
    evaluation = _scored(poses, made_ns, PlanOutput(type="spatial_path", topic="/planner/path"))
    assert evaluation.metrics.jerk <= 0.5
    assert evaluation.metrics.lateral_acceleration <= 0.5
    assert evaluation.terms.comfort == 0.0
    np.testing.assert_allclose(evaluation.metrics.l2_human[0], 0.0, atol=1e-6)  # it drives as the human did
    assert evaluation.terms.value == pytest.approx(0.0, abs=1e-9)


def test_driven_from_the_plans_own_time_the_same_path_would_stand_for_the_delay() -> None:
    # What the anchor removes: from its start at the time it was made, the ego stands at the path's start
    # (the sweep's pose) for 0.1 s and then drives at 8 m/s: a jerk of 8 / 0.1 / 0.1 = 800 m/s^3.
    scenario = _scenario()
    made_ns = int(scenario.frame_stamps_ns[DECISION]) + DELAY_NS
    poses = plan_poses("spatial_path", _spatial_path(scenario.ego.xy[DECISION]))
    evaluation = _scored(poses, made_ns, PlanOutput(type="spatial_path", topic="/p"), anchored=False)
    assert evaluation.metrics.jerk == pytest.approx(800.0, rel=1e-6)


def test_a_path_with_the_stacks_own_speeds_made_late_scores_no_jerk() -> None:
    scenario = _scenario()
    made_ns = int(scenario.frame_stamps_ns[DECISION]) + DELAY_NS
    along = np.arange(0.0, 81.0)
    xy = scenario.ego.xy[DECISION] + along[:, None] * DIRECTION  # from the last pose it heard of, as Autoware's
    poses = Poses(xy, np.full(along.size, HEADING), speeds=np.full(along.size, SPEED))
    evaluation = _scored(poses, made_ns, PlanOutput(type="autoware_trajectory", topic="/p"))
    assert evaluation.metrics.jerk <= 0.5
    np.testing.assert_allclose(evaluation.metrics.l2_human[0], 0.0, atol=1e-6)


def test_a_timed_plan_that_starts_after_the_first_contract_stamp_is_continued_back_not_held() -> None:
    # Made 0.25 s after the sweep, its poses from 0.35 s on: the contract's poses at 0.1-0.3 s come before it.
    scenario = _scenario()
    sweep_ns = int(scenario.frame_stamps_ns[DECISION])
    stamps = sweep_ns + 350_000_000 + FRAME_NS * np.arange(50, dtype=np.int64)
    xy = scenario.ego.xy[DECISION] + SPEED * ((stamps - sweep_ns) / 1e9)[:, None] * DIRECTION  # the human's
    poses = Poses(xy, np.full(50, HEADING), stamps_ns=stamps)
    evaluation = _scored(poses, sweep_ns + 250_000_000, PlanOutput(topic="/p"))
    assert evaluation.metrics.jerk <= 0.5  # held at its first pose until 0.35 s (the old rule): 2800 m/s^3
    np.testing.assert_allclose(evaluation.metrics.l2_human[0], 0.0, atol=1e-6)
