"""A closed-loop episode on a synthetic log, offline: the stack drives, every sweep is rendered where the ego is.

The stack hears the logged sweeps of the history (as in open loop) and plans at the decision
frame. From there the ego executes the plans (``core.closed_loop``): every 0.1 s the sweep is
ray cast from the ego's *actual* sensor pose with the actors at their logged poses (a
synthetic log keeps its meshes, so this is the exact sensor, not an approximation), the stack
plans from it and from the ego's actual motion, and the controller tracks the new plan. The
same decision plan is also scored open loop, as the paper does, so that the two can be put
side by side. Actors are not reactive. This is the offline path (no ROS, as ``stacks.replay``);
the attack graph does not run closed loop yet.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from advsim_ros.core.closed_loop import (
    ClosedLoopMetrics,
    ControllerConfig,
    ExecutedTrajectory,
    VehicleState,
    drive_closed_loop,
    executed_metrics,
    initial_state,
    yaw_rate_of,
)
from advsim_ros.core.futures import actor_futures_at
from advsim_ros.core.lidar.boxes import yaw_pose
from advsim_ros.core.metrics import NS_PER_S, MetricsConfig, collision_steps, plan_from_decision
from advsim_ros.core.types import Plan
from advsim_ros.io.synthetic import SyntheticLog
from advsim_ros.stacks.interface import AutonomyStack, EgoMotion, StackError, StackFrame, points_xyz
from advsim_ros.stacks.replay import scenario_frames


@dataclass(frozen=True, eq=False)
class ClosedLoopEpisode:
    """The decision plan scored open loop, and what the ego drove in closed loop."""

    decision_plan: Plan  # the stack's plan at the decision frame (with the ego's pose in front)
    open_loop_collision_time: float  # first plan stamp at which it overlaps an actor [s after the decision]; inf
    executed: ExecutedTrajectory
    closed_loop: ClosedLoopMetrics


def closed_loop_episode(
    stack: AutonomyStack,
    log: SyntheticLog,
    decision_frame: int,
    horizon_s: float = 5.0,
    history_frames: int = 10,
    controller: ControllerConfig | None = None,
    render_seed: int = 0,
) -> ClosedLoopEpisode:
    """Run the stack over the history, then close the loop for ``horizon_s`` from the decision frame."""
    scenario = log.scenario
    period_ns = int(scenario.frame_stamps_ns[1] - scenario.frame_stamps_ns[0])  # a sweep, and a replan, per frame
    first = decision_frame - history_frames + 1
    last_frame = decision_frame + round(horizon_s * NS_PER_S / period_ns)
    if first < 0 or last_frame >= scenario.num_frames:
        raise StackError(
            f"closed loop: frames {first}..{last_frame} are not all in {scenario.scenario_id} "
            f"({scenario.num_frames} frames)"
        )
    controller = controller or ControllerConfig()
    stack.reset()
    stack.set_road_map(scenario.road_map)
    decision: tuple[StackFrame, Plan] | None = None
    for index, frame in scenario_frames(scenario, range(first, decision_frame + 1)):
        plan = stack.step(frame).plan
        if index == decision_frame:
            decision = (frame, plan)
    assert decision is not None
    frame, plan = decision
    decision_ns = frame.stamp_ns
    rng = np.random.default_rng(render_seed)

    def planner(now_ns: int, state: VehicleState) -> Plan:
        if now_ns == decision_ns:
            return plan
        world_T_ego = yaw_pose([state.x, state.y, 0.0], state.yaw)
        sensor_pose = world_T_ego @ scenario.ego_T_sensor
        points = log.render(sensor_pose, log.actor_poses_at(now_ns), rng)
        yaw_rate = yaw_rate_of(state.speed, state.steer, controller.wheelbase)
        motion = EgoMotion(speed=state.speed, yaw_rate=yaw_rate, acceleration=state.accel)
        return stack.step(StackFrame(now_ns, points_xyz(points), world_T_ego, scenario.ego_T_sensor, motion)).plan

    start = initial_state(frame.world_T_ego, frame.motion.speed, frame.motion.yaw_rate, controller)
    executed = drive_closed_loop(start, planner, decision_ns, horizon_s, period_ns / NS_PER_S, controller)
    actors = scenario.actors
    metrics = executed_metrics(executed, actor_futures_at(actors, executed.stamps_ns), scenario.ego_geometry)
    scored = plan_from_decision(plan, frame.world_T_ego, decision_ns)
    within = scored.stamps_ns <= decision_ns + round(horizon_s * NS_PER_S)
    scored = Plan(scored.stamps_ns[within], scored.xy[within], scored.yaws[within])
    hits = collision_steps(scored, actor_futures_at(actors, scored.stamps_ns), scenario.ego_geometry, MetricsConfig())
    open_time = float((scored.stamps_ns[np.argmax(hits)] - decision_ns) / NS_PER_S) if hits.any() else np.inf
    return ClosedLoopEpisode(scored, open_time, executed, metrics)
