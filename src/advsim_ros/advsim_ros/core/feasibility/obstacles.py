"""What a perturbed actor must not touch over a window: the SDV's logged boxes and every other actor's."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from advsim_ros.core.dynamics import standing_fit
from advsim_ros.core.feasibility.config import PerturberConfig
from advsim_ros.core.feasibility.window import Window, is_standing, window_observations
from advsim_ros.core.types import ActorTrack, BoolArray, FloatArray, IntArray, Scenario

EGO_ID = "ego"  # obstacle id of the SDV's logged trajectory


@dataclass(frozen=True, eq=False)
class WindowObstacles:
    """Everything a perturbed actor must not touch, per window step: the SDV first, then every actor."""

    ids: tuple[str, ...]  # (J,) EGO_ID, then actor ids
    boxes: FloatArray  # (T, J, 5) [x, y, yaw, length, width] in the world frame
    present: BoolArray  # (T, J) whether obstacle j exists at step t

    def without(self, actor_id: str) -> WindowObstacles:
        keep = [index for index, name in enumerate(self.ids) if name != actor_id]
        return WindowObstacles(
            ids=tuple(self.ids[index] for index in keep),
            boxes=self.boxes[:, keep],
            present=self.present[:, keep],
        )


def actor_window_boxes(actor: ActorTrack, stamps: IntArray) -> tuple[FloatArray, BoolArray]:
    """(T, 5) boxes [x, y, yaw, length, width] of a logged actor at the window stamps, and (T,) presence.

    An actor is present from its first to its last label in the window, positions and headings
    interpolated across unlabelled frames in between; an actor that stands still over the whole
    log is present at every step at its median position, also before it was first seen.
    """
    steps = stamps.shape[0]
    if is_standing(actor):
        fit = standing_fit(actor.centers[:, :2], actor.yaws, steps)
        box = np.tile([*fit.initial[:3], actor.length, actor.width], (steps, 1))
        return box, np.ones(steps, dtype=bool)
    window_steps, indices = window_observations(actor, stamps)
    if window_steps.size == 0:
        return np.zeros((steps, 5)), np.zeros(steps, dtype=bool)
    grid = np.arange(steps)
    box = np.column_stack(
        [
            np.interp(grid, window_steps, actor.centers[indices, 0]),
            np.interp(grid, window_steps, actor.centers[indices, 1]),
            np.interp(grid, window_steps, np.unwrap(actor.yaws[indices])),
            np.full(steps, actor.length),
            np.full(steps, actor.width),
        ]
    )
    return box, (grid >= window_steps[0]) & (grid <= window_steps[-1])


def ego_window_boxes(scenario: Scenario, window: Window, config: PerturberConfig) -> FloatArray:
    """(T, 5) boxes of the SDV's logged trajectory over the window (the scenario's ego geometry)."""
    frames = np.arange(window.start_frame, window.start_frame + window.num_steps)
    boxes: FloatArray = scenario.ego_geometry.boxes(scenario.ego.xy[frames], scenario.ego.yaws[frames])
    return boxes


def window_obstacles(scenario: Scenario, window: Window, config: PerturberConfig) -> WindowObstacles:
    """The SDV's logged boxes and every actor's boxes over the window (see actor_window_boxes)."""
    stamps = window.stamps(scenario, config.frame_period)
    ids = [EGO_ID]
    boxes = [ego_window_boxes(scenario, window, config)]
    present = [np.ones(stamps.shape[0], dtype=bool)]
    for actor in scenario.actors:
        box, mask = actor_window_boxes(actor, stamps)
        if not np.any(mask):
            continue
        ids.append(actor.actor_id)
        boxes.append(box)
        present.append(mask)
    return WindowObstacles(ids=tuple(ids), boxes=np.stack(boxes, axis=1), present=np.stack(present, axis=1))
