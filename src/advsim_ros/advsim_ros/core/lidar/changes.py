"""Which actors a sweep's re-simulation moves: their logged and perturbed poses in the sensor frame."""

from __future__ import annotations

from collections.abc import Container, Sequence
from dataclasses import dataclass

import numpy as np

from advsim_ros.core.lidar.background import GroundGrid
from advsim_ros.core.lidar.boxes import invert_rigid, track_pose_at, yaw_pose
from advsim_ros.core.lidar.config import ResimConfig
from advsim_ros.core.lidar.errors import ResimError
from advsim_ros.core.types import ActorTrack, FloatArray, Sweep


@dataclass(frozen=True, eq=False)
class ActorChange:
    """One actor to re-simulate in one sweep: None where it is absent at the logged or the perturbed pose."""

    actor_id: str
    old_pose: FloatArray | None  # (4, 4) T_sensor_box at the logged pose
    new_pose: FloatArray | None  # (4, 4) T_sensor_box at the perturbed pose
    size: FloatArray  # (3,) [m]


def actor_changes(
    sweep: Sweep,
    original_tracks: Sequence[ActorTrack],
    perturbed_tracks: Sequence[ActorTrack],
    forced: set[str],
    assets: Container[str],
    config: ResimConfig,
    ground: GroundGrid,
) -> list[ActorChange]:
    """The actors whose pose at the sweep's stamp differs between the logged and the perturbed tracks.

    Actors are matched by id; ids in `forced` count as changed even where their pose is the same.
    Raises ResimError when a changed actor has no asset (is not a track of the log).
    """
    originals = {track.actor_id: track for track in original_tracks}
    perturbed = {track.actor_id: track for track in perturbed_tracks}
    sensor_T_world = invert_rigid(sweep.sensor_pose)
    changes: list[ActorChange] = []
    for actor_id in sorted(set(originals) | set(perturbed)):
        old = track_pose_at(originals[actor_id], sweep.stamp_ns) if actor_id in originals else None
        new = track_pose_at(perturbed[actor_id], sweep.stamp_ns) if actor_id in perturbed else None
        if old is None and new is None:
            continue
        if old is not None and new is not None and actor_id not in forced and _same_pose(old, new, config):
            continue
        if new is not None and actor_id not in assets:
            raise ResimError(f"actor {actor_id!r} has no asset in this log's model: only logged actors can be inserted")
        if new is not None and config.snap_to_ground:
            new = _snapped(new, old, ground)
        track = perturbed[actor_id] if actor_id in perturbed else originals[actor_id]
        changes.append(
            ActorChange(
                actor_id=actor_id,
                old_pose=None if old is None else sensor_T_world @ old,
                new_pose=None if new is None else sensor_T_world @ new,
                size=track.size,
            )
        )
    return changes


def _same_pose(old: FloatArray, new: FloatArray, config: ResimConfig) -> bool:
    offset = float(np.linalg.norm(old[:3, 3] - new[:3, 3]))
    turn = float(np.arccos(np.clip(0.5 * (np.trace(old[:3, :3].T @ new[:3, :3]) - 1.0), -1.0, 1.0)))
    return offset < config.pose_tolerance and turn < config.yaw_tolerance


def _snapped(new: FloatArray, old: FloatArray | None, ground: GroundGrid) -> FloatArray:
    """The new pose with its height following the background ground between the old and new place."""
    heights = ground.height_at(np.array([new[:2, 3], new[:2, 3] if old is None else old[:2, 3]]))
    if old is None or not np.all(np.isfinite(heights)):
        return new
    yaw = float(np.arctan2(new[1, 0], new[0, 0]))
    center = new[:3, 3].copy()
    center[2] = old[2, 3] + heights[0] - heights[1]
    return yaw_pose(center, yaw)


def unchanged_actors(
    sweep: Sweep,
    perturbed_tracks: Sequence[ActorTrack],
    changed: set[str],
    sensor_T_world: FloatArray,
    assets: Container[str],
) -> list[tuple[str, FloatArray]]:
    """The actors with an asset present at the sweep's stamp that did not change, with their T_sensor_box."""
    present: list[tuple[str, FloatArray]] = []
    for track in perturbed_tracks:
        if track.actor_id in changed or track.actor_id not in assets:
            continue
        pose = track_pose_at(track, sweep.stamp_ns)
        if pose is not None:
            present.append((track.actor_id, sensor_T_world @ pose))
    return present
