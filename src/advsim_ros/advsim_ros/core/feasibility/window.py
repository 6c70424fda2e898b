"""The perturbed horizon of a scenario (``Window``) and how a logged actor appears over it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from advsim_ros.core.dynamics import stands_still
from advsim_ros.core.types import ActorClass, ActorTrack, IntArray, Scenario, ScenarioError

STATIC_SPAN = 1.0  # an actor whose logged centres all lie within this distance stands still [m]


@dataclass(frozen=True)
class Window:
    """Frames start_frame .. start_frame + num_steps - 1 of a scenario: the perturbed horizon."""

    start_frame: int  # index into scenario.frame_stamps_ns
    num_steps: int = 60  # states per trajectory

    def __post_init__(self) -> None:
        if self.start_frame < 0 or self.num_steps < 2:
            raise ScenarioError(f"Window: need start_frame >= 0 and num_steps >= 2, got {self}")

    def stamps(self, scenario: Scenario, frame_period: float) -> IntArray:
        """(T,) frame stamps [ns]; raises ScenarioError if the window leaves the log or frames are not evenly spaced."""
        end = self.start_frame + self.num_steps
        if end > scenario.num_frames:
            raise ScenarioError(
                f"Window frames {self.start_frame}..{end - 1} leave scenario {scenario.scenario_id}, "
                f"which has {scenario.num_frames} frames"
            )
        stamps = scenario.frame_stamps_ns[self.start_frame : end]
        spacing = np.diff(stamps) * 1e-9
        if np.max(np.abs(spacing - frame_period)) > 0.1 * frame_period:
            raise ScenarioError(
                f"scenario {scenario.scenario_id}: frames {self.start_frame}..{end - 1} are not spaced "
                f"{frame_period} s apart (found {spacing.min():.3f}..{spacing.max():.3f} s)"
            )
        return stamps


def window_observations(track: ActorTrack, stamps: IntArray) -> tuple[IntArray, IntArray]:
    """Window steps where the track is labelled, and the matching indices into the track."""
    steps = np.nonzero(np.isin(stamps, track.stamps_ns))[0]
    indices = np.searchsorted(track.stamps_ns, stamps[steps])
    return steps.astype(np.int64), indices.astype(np.int64)


def is_standing(actor: ActorTrack) -> bool:
    """Whether the actor is a parked vehicle: labelled for >= 1 s, all its centres within STATIC_SPAN.

    A parked vehicle was there before it came into view and stays after; a pedestrian or cyclist
    standing for a moment may not, so only vehicles are extended beyond their labels.
    """
    span_s = (actor.stamps_ns[-1] - actor.stamps_ns[0]) * 1e-9
    return actor.actor_class == ActorClass.VEHICLE and span_s >= 1.0 and stands_still(actor.centers[:, :2], STATIC_SPAN)
