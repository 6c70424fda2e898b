"""What both reference stacks must do, checked the same way for each (a new stack is added to STACKS).

An attack is a measurement only if the stack under test answers the same sweeps with the same
plan: every plan is 5 s of poses 0.1 s apart after its sweep, finite and starting where the ego
is; two fresh stacks give bit-identical plans; and a stack that has driven another window forgets
it on the jump in time that separates two queries (the sim clock moves on by a segment), so what
it plans for a query never depends on the queries before it.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from advsim_ros.io.synthetic import SyntheticLog
from advsim_ros.stacks.commands import make_stack
from advsim_ros.stacks.interface import StackFrame, StackOutput
from advsim_ros.stacks.replay import scenario_frames

STACKS = ("modular", "learned")
QUERY_GAP_NS = 100 * 1_000_000_000  # between two queries' segments of the sim clock (far beyond any max gap)


def _frames(log: SyntheticLog, first: int, count: int, shift_ns: int = 0) -> list[StackFrame]:
    return [
        dataclasses.replace(frame, stamp_ns=frame.stamp_ns + shift_ns)
        for _, frame in scenario_frames(log.scenario, range(first, first + count))
    ]


def _predicted(output: StackOutput) -> tuple[int, bytes] | None:
    """The predicted futures without their track ids (a tracker never reuses an id, even after a reset)."""
    predictions = output.predictions
    if predictions is None:
        return None
    rows = predictions.xy.reshape(predictions.xy.shape[0], predictions.xy.shape[1] * 2)
    return len(predictions.actor_ids), np.sort(rows, axis=0).tobytes()


def _plans(stack_name: str, *windows: list[StackFrame]) -> list[StackOutput]:
    """Outputs of one fresh stack fed the windows one after the other, never reset in between."""
    stack = make_stack(stack_name)
    stack.reset()
    return [stack.step(frame) for window in windows for frame in window]


@pytest.mark.parametrize("stack_name", STACKS)
def test_every_plan_is_five_seconds_of_finite_poses_from_where_the_ego_is(
    stack_name: str, synthetic_log: SyntheticLog
) -> None:
    frames = _frames(synthetic_log, 0, 10)
    for frame, output in zip(frames, _plans(stack_name, frames), strict=True):
        plan = output.plan
        np.testing.assert_array_equal(plan.stamps_ns - frame.stamp_ns, 100_000_000 * np.arange(1, 51))
        assert np.isfinite(plan.xy).all()
        assert np.isfinite(plan.yaws).all()
        first_step = float(np.linalg.norm(plan.xy[0] - frame.world_T_ego[:2, 3]))
        assert first_step < 0.1 * 15.0 + 0.5, f"{stack_name}: the plan starts {first_step:.2f} m from the ego"


@pytest.mark.parametrize("stack_name", STACKS)
def test_two_fresh_stacks_give_bit_identical_plans(stack_name: str, synthetic_log: SyntheticLog) -> None:
    frames = _frames(synthetic_log, 5, 10)
    first, second = _plans(stack_name, frames), _plans(stack_name, frames)
    for mine, theirs in zip(first, second, strict=True):
        assert mine.plan.xy.tobytes() == theirs.plan.xy.tobytes()
        assert mine.plan.yaws.tobytes() == theirs.plan.yaws.tobytes()


@pytest.mark.parametrize("stack_name", STACKS)
def test_a_stack_forgets_the_previous_query_on_the_jump_in_time_between_queries(
    stack_name: str, synthetic_log: SyntheticLog
) -> None:
    earlier = _frames(synthetic_log, 20, 10)  # another window, driven first
    query = _frames(synthetic_log, 0, 10, shift_ns=QUERY_GAP_NS)
    after_another = _plans(stack_name, earlier, query)[len(earlier) :]
    fresh = _plans(stack_name, query)
    for mine, theirs in zip(after_another, fresh, strict=True):
        assert mine.plan.xy.tobytes() == theirs.plan.xy.tobytes()
        np.testing.assert_array_equal(mine.plan.stamps_ns, theirs.plan.stamps_ns)
        assert _predicted(mine) == _predicted(theirs)  # tracks of the other window are gone too
