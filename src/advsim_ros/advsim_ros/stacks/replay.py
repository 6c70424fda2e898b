"""Offline replay: feed a scenario's sweeps to a stack exactly as the topics would, without ROS.

A sweep becomes a StackFrame with the points in the sensor frame, the logged ego pose at
the sweep's stamp, the sensor mount and the ego motion estimated from the poses up to
that stamp (as the nodes estimate it from odometry). Stacks are reset at the start of a
replay and on every jump in time, as in the attack graph.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

from advsim_ros.core.types import Scenario
from advsim_ros.stacks.interface import (
    AutonomyStack,
    EgoMotion,
    StackError,
    StackFrame,
    StackOutput,
    ego_motion_from_poses,
    points_xyz,
)


@dataclass(frozen=True, eq=False)
class ReplayStep:
    """One sweep of a replay and the stack's answer."""

    frame_index: int  # index into scenario.frame_stamps_ns
    output: StackOutput


def _first_motion(scenario: Scenario, index: int) -> EgoMotion:
    """With no earlier pose, the motion towards the next pose (what an odometry twist would say)."""
    if index + 1 >= scenario.num_frames:
        return EgoMotion(speed=0.0, yaw_rate=0.0)
    motion = ego_motion_from_poses(
        scenario.frame_stamps_ns[index : index + 2],
        scenario.ego.poses[index : index + 2],
        int(scenario.frame_stamps_ns[index + 1]),
    )
    return motion


def scenario_frames(scenario: Scenario, frame_indices: Sequence[int] | None = None) -> Iterator[tuple[int, StackFrame]]:
    """(frame index, StackFrame) for each sweep of the scenario (or of the given frames that have a sweep)."""
    if not scenario.sweeps:
        raise StackError(f"scenario {scenario.scenario_id} has no LiDAR sweeps to replay")
    index_of = {int(stamp): index for index, stamp in enumerate(scenario.frame_stamps_ns.tolist())}
    wanted = None if frame_indices is None else set(frame_indices)
    for sweep in scenario.sweeps:
        index = index_of[sweep.stamp_ns]
        if wanted is not None and index not in wanted:
            continue
        motion = ego_motion_from_poses(
            scenario.frame_stamps_ns, scenario.ego.poses, sweep.stamp_ns, fallback=_first_motion(scenario, index)
        )
        yield (
            index,
            StackFrame(
                stamp_ns=sweep.stamp_ns,
                xyz=points_xyz(sweep.points),
                world_T_ego=scenario.ego.poses[index],
                ego_T_sensor=scenario.ego_T_sensor,
                motion=motion,
            ),
        )


def replay(stack: AutonomyStack, scenario: Scenario, frame_indices: Sequence[int] | None = None) -> list[ReplayStep]:
    """Run the stack over the scenario's sweeps in order (optionally only some frames); one step per sweep."""
    stack.reset()
    stack.set_road_map(scenario.road_map)
    steps: list[ReplayStep] = []
    previous: int | None = None
    for index, frame in scenario_frames(scenario, frame_indices):
        if previous is not None and index != previous + 1:
            stack.reset()  # frames were skipped: a jump in time, as between two queries
        steps.append(ReplayStep(frame_index=index, output=stack.step(frame)))
        previous = index
    return steps


def window_frames(scenario: Scenario, history: int, horizon: int, stride: int) -> list[tuple[int, int]]:
    """(first history frame, decision frame) of windows: `history` sweeps up to the decision frame, `horizon` after."""
    if history < 1 or horizon < 1 or stride < 1:
        raise StackError("window_frames: history, horizon and stride must be >= 1")
    last_decision = scenario.num_frames - 1 - horizon
    return [(decision - history + 1, decision) for decision in range(history - 1, last_decision + 1, stride)]
