"""Each observed asset's optics, calibrated on the log: per-surfel pass probabilities (glass) and ray drop.

Run once when a model is built: the asset is re-inserted at its logged poses by the model's own
re-simulation and compared with the returns the sensor got there.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from advsim_ros.core.lidar.assets import ActorAsset
from advsim_ros.core.lidar.boxes import (
    AngularWindow,
    actor_region,
    inside,
    invert_rigid,
    removal_region,
    to_box_frame,
    track_pose_at,
)
from advsim_ros.core.lidar.config import ResimConfig
from advsim_ros.core.lidar.log_points import LogPoints
from advsim_ros.core.lidar.ray_table import RayTable
from advsim_ros.core.lidar.rewrite import RETURN_CLEARANCE
from advsim_ros.core.lidar.sensor import xyz_of
from advsim_ros.core.types import ActorClass, ActorTrack, FloatArray, Scenario, Sweep

if TYPE_CHECKING:
    from advsim_ros.core.lidar.resim import ResimModel

_MIN_DROP_RAYS = 30  # an asset's ray drop is estimated from at least this many re-simulated returns
_CALIBRATION_SEED = 20210601  # the ray-drop calibration's own random stream (the build stays deterministic)
_SURFACE_BAND = 0.1  # a logged return within this (+ 1 % of its range) of a surfel ended on it [m]
_PASS_PRIOR_STOPS = 1.0  # a surfel no logged ray crossed or ended on counts as opaque


def estimate_optics(model: ResimModel, scenario: Scenario, log_points: LogPoints) -> dict[str, ActorAsset]:
    """Each observed asset's per-surfel pass probabilities and ray drop, from the log at the logged poses.

    A surfel that logged rays crossed to return from farther behind it (through a car's
    windows) lets rays pass. The ray drop then makes the asset, re-inserted at its logged
    poses by this very re-simulation, return as many points inside its grown box as the
    actor did: 1 - (logged returns) / (re-simulated returns without drop). Template assets
    take their class's median drop and are opaque.
    """
    config = model.config
    views: dict[str, list[Sweep]] = {}
    for actor in scenario.actors:
        asset = model.assets[actor.actor_id]
        frames = log_points.actor_frames[actor.actor_id]
        if asset.is_template or not frames:
            continue
        picks = np.unique(np.linspace(0, len(frames) - 1, min(config.drop_estimate_frames, len(frames))).round())
        views[actor.actor_id] = [scenario.sweeps[frames[int(pick)]] for pick in picks]
        passed = np.zeros(asset.surfels.count)
        stopped = np.zeros(asset.surfels.count)
        for sweep in views[actor.actor_id]:
            _count_crossings(model, sweep, actor, _sensor_pose_of(actor, sweep), passed, stopped)
        model.assets[actor.actor_id] = asset.with_optics(0.0, passed / (passed + stopped + _PASS_PRIOR_STOPS))
    by_class: dict[ActorClass, list[float]] = {}
    measured: set[str] = set()
    for actor in scenario.actors:
        if actor.actor_id not in views:
            continue
        returns = resimulated = 0
        for index, sweep in enumerate(views[actor.actor_id]):
            count_returns, count_resimulated = _returns_and_reinserted(model, sweep, actor, scenario.actors, index)
            returns += count_returns
            resimulated += count_resimulated
        if resimulated < _MIN_DROP_RAYS:
            continue  # too few returns to tell the drop: the class value below
        probability = float(np.clip(1.0 - returns / resimulated, 0.0, config.max_drop_probability))
        asset = model.assets[actor.actor_id]
        model.assets[actor.actor_id] = asset.with_optics(probability, asset.pass_probability)
        measured.add(actor.actor_id)
        by_class.setdefault(asset.actor_class, []).append(probability)
    for actor in scenario.actors:
        if actor.actor_id in measured:
            continue
        asset = model.assets[actor.actor_id]
        known = by_class.get(asset.actor_class)
        probability = float(np.median(known)) if known else config.default_drop_probability
        model.assets[actor.actor_id] = asset.with_optics(probability, asset.pass_probability)
    return model.assets


def _sensor_pose_of(actor: ActorTrack, sweep: Sweep) -> FloatArray:
    """T_sensor_box of an actor at a sweep it was labelled in."""
    pose = track_pose_at(actor, sweep.stamp_ns)
    assert pose is not None
    return invert_rigid(sweep.sensor_pose) @ pose


def _returns_and_reinserted(
    model: ResimModel, sweep: Sweep, actor: ActorTrack, tracks: Sequence[ActorTrack], index: int
) -> tuple[int, int]:
    """The actor's logged returns in its grown box, and its returns there when re-inserted where it was."""
    pose = _sensor_pose_of(actor, sweep)
    region = actor_region(actor.size, model.config.box_margin, RETURN_CLEARANCE)
    rng = np.random.default_rng([_CALIBRATION_SEED, index])
    points = model.resimulate(sweep, tracks, tracks, rng=rng, moved=[actor.actor_id])
    logged = int(np.count_nonzero(inside(to_box_frame(xyz_of(sweep.points), pose), region)))
    return logged, int(np.count_nonzero(inside(to_box_frame(xyz_of(points), pose), region)))


def _window(config: ResimConfig, actor: ActorTrack, pose: FloatArray) -> AngularWindow:
    """The angular window of an actor's grown box at `pose` (T_sensor_box)."""
    return AngularWindow.of_region(pose, removal_region(actor.size, config.removal_margin), config.window_margin)


def _count_crossings(
    model: ResimModel, sweep: Sweep, actor: ActorTrack, pose: FloatArray, passed: FloatArray, stopped: FloatArray
) -> None:
    """Add, per surfel, the logged rays that went through it and the ones that ended on it."""
    geometry = model.geometry(sweep.points, sweep.stamp_ns)
    table = RayTable(sweep.points, geometry, model.beam_rows)
    window = _window(model.config, actor, pose)
    logged, _ = table.window_candidates(window)
    origins, directions = table.logged_rays(logged)
    crossings = model.asset_caster(actor.actor_id).cast_all(origins, directions, pose)
    surfel = crossings.triangles // 2
    measured = geometry.beam_ranges[logged][crossings.ray_ids]
    surfels = model.assets[actor.actor_id].surfels
    # How far the logged return lies from the crossed surfel: a ray grazing a surface crosses
    # its surfels well before its return, yet the return sits on the same surface.
    returns_in_box = to_box_frame(geometry.spherical.xyz[logged][crossings.ray_ids], pose)
    apart = np.linalg.norm(returns_in_box - surfels.centers[surfel], axis=1) - surfels.half_sizes[surfel]
    beyond = (crossings.ranges < measured - _SURFACE_BAND - 0.01 * measured) & (apart > _SURFACE_BAND)
    np.add.at(passed, surfel[beyond], 1.0)
    np.add.at(stopped, surfel[~beyond & (crossings.ranges <= measured + _SURFACE_BAND)], 1.0)
