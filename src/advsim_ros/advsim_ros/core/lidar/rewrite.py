"""The rewrite of one sweep for the actors that moved: removal, fill, insertion (see core.lidar.resim).

1. removal: the moved actors' logged points are cut out, their rays freed;
2. fill: the freed rays are cast against the background and the actors that stayed;
3. insertion: the rays through each moved actor's new box are cast against its asset, each
   keeping the nearer of what it had and the asset hit.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from advsim_ros.core.lidar.boxes import (
    AngularWindow,
    BoolArray,
    actor_region,
    inside,
    invert_rigid,
    rays_hit_region,
    removal_region,
    to_box_frame,
)
from advsim_ros.core.lidar.changes import ActorChange, unchanged_actors
from advsim_ros.core.lidar.ray_table import RayTable
from advsim_ros.core.types import ActorTrack, FloatArray, IntArray, SensorModel, Sweep

if TYPE_CHECKING:
    from advsim_ros.core.lidar.resim import ResimModel

RETURN_CLEARANCE = 0.15  # logged returns this close above a box's bottom are not counted as the actor's [m]


@dataclass
class ActorResimStats:
    """What happened to one actor in one sweep."""

    removed_points: int = 0  # logged points cut out with the actor
    freed_rays: int = 0  # rays re-cast after the removal (removed points plus empty rays through the box)
    filled_rays: int = 0  # freed rays that found the background or another actor
    inserted_returns: int = 0  # returns from the actor at its new pose
    dropped_rays: int = 0  # rays that hit the actor at its new pose but returned nothing (ray drop)


@dataclass
class ResimStats:
    """Per-actor figures of one re-simulated sweep, and how many rays were cast."""

    actors: dict[str, ActorResimStats] = field(default_factory=dict)
    cast_rays: int = 0

    @property
    def fill_fraction(self) -> float:
        """Share of freed rays that found something to return (nan when no ray was freed)."""
        freed = sum(actor.freed_rays for actor in self.actors.values())
        filled = sum(actor.filled_rays for actor in self.actors.values())
        return filled / freed if freed else float("nan")


def rewrite_sweep(
    model: ResimModel,
    sweep: Sweep,
    changes: list[ActorChange],
    perturbed_tracks: Sequence[ActorTrack],
    rng: np.random.Generator,
) -> tuple[np.ndarray, ResimStats]:
    """The sweep with the changed actors removed, the freed rays filled and the actors inserted at their new poses."""
    stats = ResimStats()
    geometry = model.geometry(sweep.points, sweep.stamp_ns)
    table = RayTable(sweep.points, geometry, model.beam_rows)
    sensor_T_world = invert_rigid(sweep.sensor_pose)
    for change in changes:
        stats.actors[change.actor_id] = ActorResimStats()
    freed = _remove(model, table, changes, stats)
    unchanged = unchanged_actors(
        sweep, perturbed_tracks, {change.actor_id for change in changes}, sensor_T_world, model.assets
    )
    _fill(model, table, freed, sensor_T_world, unchanged, stats, rng)
    for change in changes:
        if change.new_pose is not None:
            _insert(model, table, change, stats.actors[change.actor_id], rng, stats)
    return table.assemble(), stats


def _remove(
    model: ResimModel, table: RayTable, changes: list[ActorChange], stats: ResimStats
) -> dict[str, tuple[IntArray, IntArray]]:
    """Cut the moved actors out of the sweep; returns each actor's freed logged and added rays."""
    config = model.config
    freed: dict[str, tuple[IntArray, IntArray]] = {}
    for change in changes:
        if change.old_pose is None:
            continue
        region = removal_region(change.size, config.removal_margin)
        window = AngularWindow.of_region(change.old_pose, region, config.window_margin)
        logged, added = table.window_candidates(window)
        local = to_box_frame(table.geometry.spherical.xyz[logged], change.old_pose)
        removed = logged[inside(local, region) & table.returned[logged]]
        table.stop[removed] = np.inf
        table.returned[removed] = False
        table.changed[removed] = True
        rows, columns = table.uncovered_cells(window, logged, added, config.coverage_tolerance)
        through = rays_hit_region(*model.beam_rows.cell_rays(rows, columns), change.old_pose, region)
        cells = table.add_rays(rows[through], columns[through], logged)
        freed[change.actor_id] = (removed, cells)
        actor_stats = stats.actors[change.actor_id]
        actor_stats.removed_points = int(removed.shape[0])
        actor_stats.freed_rays = int(removed.shape[0] + cells.shape[0])
    return freed


def _fill(
    model: ResimModel,
    table: RayTable,
    freed: dict[str, tuple[IntArray, IntArray]],
    sensor_T_world: FloatArray,
    unchanged: list[tuple[str, FloatArray]],
    stats: ResimStats,
    rng: np.random.Generator,
) -> None:
    """Cast the freed rays against the background and the actors that stayed where they were."""
    if not freed:
        return
    logged = np.unique(np.concatenate([value[0] for value in freed.values()]))
    added = np.unique(np.concatenate([value[1] for value in freed.values()]))
    if logged.size + added.size == 0:
        return
    origins, directions = table.rays(logged, added)
    hits = model.background_caster.cast(origins, directions, sensor_T_world)
    dropped = np.zeros(directions.shape[0], dtype=bool)
    azimuths = np.arctan2(directions[:, 1], directions[:, 0])
    elevations = np.arcsin(np.clip(directions[:, 2], -1.0, 1.0))
    for actor_id, pose in unchanged:
        asset = model.assets[actor_id]
        window = AngularWindow.of_region(
            pose, removal_region(asset.size, model.config.removal_margin), model.config.window_margin
        )
        seen = np.flatnonzero(window.contains(azimuths, elevations))
        if seen.size == 0:
            continue
        found = model.cast_actor(actor_id, origins[seen], directions[seen], pose, rng)
        nearer = found.ranges < hits.ranges[seen]
        chosen = seen[nearer]
        hits.ranges[chosen] = found.ranges[nearer]
        hits.intensity[chosen] = found.intensity[nearer]
        dropped[chosen] = rng.random(chosen.shape[0]) < asset.drop_probability
        stats.cast_rays += int(seen.shape[0])
    stats.cast_rays += int(directions.shape[0])
    returns = _in_range(model.sensor, hits.ranges) & ~dropped
    table.update(logged, added, hits, returns)
    for actor_id, (own_logged, own_added) in freed.items():
        filled = np.count_nonzero(table.returned[own_logged]) + np.count_nonzero(table.added_returned[own_added])
        stats.actors[actor_id].filled_rays = int(filled)


def _insert(
    model: ResimModel,
    table: RayTable,
    change: ActorChange,
    actor_stats: ActorResimStats,
    rng: np.random.Generator,
    stats: ResimStats,
) -> None:
    """Cast the rays through the actor's new box against its asset and keep the nearer return per ray."""
    assert change.new_pose is not None
    config = model.config
    region = removal_region(change.size, config.removal_margin)
    window = AngularWindow.of_region(change.new_pose, region, config.window_margin)
    logged, added = table.window_candidates(window)
    rows, columns = table.uncovered_cells(window, logged, added, config.coverage_tolerance)
    through = rays_hit_region(*model.beam_rows.cell_rays(rows, columns), change.new_pose, region)
    existing_through = rays_hit_region(*table.rays(logged, added), change.new_pose, region)
    count = logged.shape[0]
    cells = table.add_rays(rows[through], columns[through], logged)
    logged, added = logged[existing_through[:count]], added[existing_through[count:]]
    added = np.concatenate([added, cells])
    origins, directions = table.rays(logged, added)
    asset = model.assets[change.actor_id]
    hits = model.cast_actor(change.actor_id, origins, directions, change.new_pose, rng)
    stats.cast_rays += int(directions.shape[0])
    dropped = rng.random(directions.shape[0]) < asset.drop_probability
    returns = np.logical_and(_in_range(model.sensor, hits.ranges), np.logical_not(dropped))
    # Whatever the ray ended on inside the actor's new box (background left over from the log,
    # e.g. parts of the actor itself outside its label) gives way to the actor.
    current = np.concatenate([table.stop[logged], table.added_stop[added]])
    ends = origins + directions * np.where(np.isfinite(current), current, 0.0)[:, None]
    inner = actor_region(change.size, config.box_margin, RETURN_CLEARANCE)
    displaced = np.isfinite(current) & inside(to_box_frame(ends, change.new_pose), inner)
    won = table.update(logged, added, hits, returns, displaced)
    actor_stats.inserted_returns = int(np.count_nonzero(won & returns))
    actor_stats.dropped_rays = int(np.count_nonzero(won & ~returns))


def _in_range(sensor: SensorModel, ranges: FloatArray) -> BoolArray:
    result: BoolArray = (ranges >= sensor.min_range) & (ranges <= sensor.max_range)
    return result
