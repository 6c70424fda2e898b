"""A log's points split into the static scene (world frame) and each track's own points (box frame).

One pass over the sweeps: the background of the re-simulation is built from the static points,
each actor's asset from its own points (core.lidar.background, core.lidar.assets).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from advsim_ros.core.lidar.alignment import align_frames
from advsim_ros.core.lidar.background import SweepDepth
from advsim_ros.core.lidar.boxes import BoolArray, to_box_frame, track_pose_at
from advsim_ros.core.lidar.config import ResimConfig
from advsim_ros.core.lidar.sensor import BeamRows, azimuth_columns, point_normals, rotate, spherical, xyz_of
from advsim_ros.core.lidar.surfels import PointSamples, voxel_merge
from advsim_ros.core.memory import release_freed_memory
from advsim_ros.core.types import ActorTrack, FloatArray, Scenario

_THIN_CHUNK_SWEEPS = 16  # background points are thinned every this many sweeps to bound memory
_GROUND_RING = 1.5  # width of the ring around an actor where its ground height is measured [m]
_GROUND_SEARCH = 0.5  # the ground around an actor lies within this of its box bottom [m]
_VOLUME_CELL = 0.1  # grid cell of the volume any actor ever occupied [m]
_STATIC_CLEARANCE = 0.15  # that volume starts this far above the boxes' bottoms (labels sit a little low or high) [m]


@dataclass(frozen=True, eq=False)
class LogPoints:
    """A log's points split into the static scene (world frame) and each track's own points (box frame)."""

    background: PointSamples  # static points, merged on the background grid
    depths: list[SweepDepth]  # range images of every carve_sweep_stride-th sweep
    actors: dict[str, PointSamples]  # track id -> its points in its box frame
    actor_intensity: dict[str, FloatArray]  # track id -> intensity of its raw points
    actor_frames: dict[str, list[int]]  # track id -> sweep indices where it had points

    def actors_only(self) -> LogPoints:
        """The same without the static scene's points and depth images (once the background is built)."""
        return dataclasses.replace(self, background=PointSamples.concatenate([]), depths=[])


def collect_log_points(scenario: Scenario, beam_rows: BeamRows, config: ResimConfig) -> LogPoints:
    """Split every sweep of the log into static points and per-track points (one pass)."""
    ids = [actor.actor_id for actor in scenario.actors]
    actor_parts: dict[str, list[PointSamples]] = {key: [] for key in ids}
    actor_intensity: dict[str, list[FloatArray]] = {key: [] for key in ids}
    actor_frames: dict[str, list[int]] = {key: [] for key in ids}
    reach = {actor.actor_id: 0.5 * float(np.linalg.norm(actor.size)) + config.box_margin for actor in scenario.actors}
    pending: list[PointSamples] = []
    merged: list[PointSamples] = []
    depths: list[SweepDepth] = []
    volume = ActorVolume.of_tracks(scenario.actors, config)
    for index, sweep in enumerate(scenario.sweeps):
        geometry = spherical(xyz_of(sweep.points))
        valid = geometry.ranges > 1e-3
        rows = beam_rows.rows(sweep.points, geometry)
        normals = point_normals(geometry, rows, beam_rows.sensor, valid)
        intensity = _intensity_of(sweep.points)
        rotation, origin = sweep.sensor_pose[:3, :3], sweep.sensor_pose[:3, 3]
        world = rotate(geometry.xyz, rotation) + origin
        world_normals = rotate(normals, rotation)
        static = valid & (geometry.ranges <= config.background_max_range)
        static[static] = ~volume.contains(world[static])
        for actor in scenario.actors:
            pose = track_pose_at(actor, sweep.stamp_ns)
            if pose is None:
                continue
            limit = reach[actor.actor_id] + _GROUND_RING
            near = np.flatnonzero(
                valid & (np.abs(world[:, 0] - pose[0, 3]) <= limit) & (np.abs(world[:, 1] - pose[1, 3]) <= limit)
            )
            local = to_box_frame(world[near], pose)
            local_normals = rotate(world_normals[near], pose[:3, :3].T)
            split = _split_actor_points(local, local_normals, actor.size, config)
            static[near[split.actor]] = False
            if np.any(split.actor):
                chosen = near[split.actor]
                sensor_in_box = to_box_frame(origin[None, :], pose)[0]
                actor_parts[actor.actor_id].append(
                    PointSamples.of_points(
                        local[split.actor], intensity[chosen], local_normals[split.actor], sensor_in_box
                    )
                )
                actor_intensity[actor.actor_id].append(intensity[chosen])
                actor_frames[actor.actor_id].append(index)
        if index % config.carve_sweep_stride == 0:
            usable = np.flatnonzero(valid)
            columns = azimuth_columns(geometry.azimuths[usable], beam_rows.sensor)
            depths.append(
                SweepDepth.of_points(
                    sweep.sensor_pose, geometry.ranges[usable], rows[usable], columns, beam_rows.sensor
                )
            )
        if index % config.background_sweep_stride == 0:
            pending.append(PointSamples.of_points(world[static], intensity[static], world_normals[static], origin))
        if len(pending) >= _THIN_CHUNK_SWEEPS:
            merged.append(voxel_merge(PointSamples.concatenate(pending), config.background_voxel))
            pending = []
            release_freed_memory()  # the chunk's sweep-sized temporaries would stay resident as holes
    merged.extend(pending)
    del pending
    return LogPoints(
        background=PointSamples.gather(merged),
        depths=depths,
        actors={key: PointSamples.concatenate(align_frames(parts)) for key, parts in actor_parts.items()},
        actor_intensity={
            key: np.concatenate(parts) if parts else np.zeros(0) for key, parts in actor_intensity.items()
        },
        actor_frames=actor_frames,
    )


@dataclass(frozen=True, eq=False)
class ActorVolume:
    """Where any actor stood at any labelled time: a ground-plane grid with a height interval per cell.

    Points inside it never go into the background, also in sweeps where the actor has no
    label (KITTI labels only what the camera sees: a parked car behind the ego would
    otherwise stay in the background, and no amount of carving removes what never moved).
    """

    origin: FloatArray  # (2,) world x, y of cell (0, 0)'s corner [m]
    cell_size: float  # [m]
    low: FloatArray  # (H, W) lowest bottom (+ STATIC_CLEARANCE) of the boxes over the cell [m]; inf where none
    high: FloatArray  # (H, W) highest top (+ margin) of the boxes over the cell [m]; -inf where none

    @classmethod
    def of_tracks(cls, tracks: Sequence[ActorTrack], config: ResimConfig) -> ActorVolume:
        cell = _VOLUME_CELL
        margin = config.removal_margin  # what a removal cuts out must not come back from the background
        corners: list[FloatArray] = []
        for track in tracks:
            reach = 0.5 * float(np.hypot(track.size[0], track.size[1])) + margin
            corners.append(track.centers[:, :2] - reach)
            corners.append(track.centers[:, :2] + reach)
        if not corners:
            return cls(np.zeros(2), cell, np.full((1, 1), np.inf), np.full((1, 1), -np.inf))
        low_corner = np.min([block.min(axis=0) for block in corners], axis=0)
        high_corner = np.max([block.max(axis=0) for block in corners], axis=0)
        shape = (
            int(np.ceil((high_corner[1] - low_corner[1]) / cell)) + 1,
            int(np.ceil((high_corner[0] - low_corner[0]) / cell)) + 1,
        )
        low = np.full(shape, np.inf)
        high = np.full(shape, -np.inf)
        for track in tracks:
            half = 0.5 * track.size[:2] + margin
            reach = float(np.hypot(half[0], half[1]))
            span = int(np.ceil(reach / cell))
            offsets = np.arange(-span, span + 1)
            for center, yaw in zip(track.centers, track.yaws, strict=True):
                base = np.floor((center[:2] - low_corner) / cell).astype(np.int64)
                rows = np.clip(base[1] + offsets, 0, shape[0] - 1)
                columns = np.clip(base[0] + offsets, 0, shape[1] - 1)
                grid_rows, grid_columns = np.meshgrid(rows, columns, indexing="ij")
                xy = low_corner + (np.stack([grid_columns, grid_rows], axis=-1) + 0.5) * cell - center[:2]
                along = xy[..., 0] * np.cos(yaw) + xy[..., 1] * np.sin(yaw)
                across = -xy[..., 0] * np.sin(yaw) + xy[..., 1] * np.cos(yaw)
                covered = (np.abs(along) <= half[0]) & (np.abs(across) <= half[1])
                bottom = center[2] - 0.5 * track.size[2] + _STATIC_CLEARANCE
                top = center[2] + 0.5 * track.size[2] + margin
                cells = (grid_rows[covered], grid_columns[covered])
                low[cells] = np.minimum(low[cells], bottom)
                high[cells] = np.maximum(high[cells], top)
        return cls(origin=low_corner, cell_size=cell, low=low, high=high)

    def contains(self, world: FloatArray) -> BoolArray:
        """(N,) whether world points (N, 3) lie inside the volume."""
        cells = np.floor((world[:, :2] - self.origin) / self.cell_size).astype(np.int64)
        rows, columns = self.low.shape
        on_grid = (cells[:, 1] >= 0) & (cells[:, 1] < rows) & (cells[:, 0] >= 0) & (cells[:, 0] < columns)
        result = np.zeros(world.shape[0], dtype=bool)
        index = np.flatnonzero(on_grid)
        row, column = cells[index, 1], cells[index, 0]
        height = world[index, 2]
        result[index] = (height > self.low[row, column]) & (height <= self.high[row, column])
        return result


@dataclass(frozen=True, eq=False)
class _ActorSplit:
    actor: BoolArray  # (N,) points of the actor: its asset is built from them, the background without them
    ground: float  # ground height under the actor in the box frame [m]


def _split_actor_points(
    local: FloatArray, local_normals: FloatArray, size: FloatArray, config: ResimConfig
) -> _ActorSplit:
    """Which points near an actor (box frame) belong to it, measuring heights from the ground around it.

    The ground is the lower quartile height of the upward-facing points in a ring around
    the box (the box bottom when there are too few): a label's bottom is often a few
    centimetres off, and a wheel left in the background would leave a trail along the
    actor's path.
    """
    half = 0.5 * np.asarray(size, dtype=np.float64)
    reach_x, reach_y = half[0] + config.box_margin, half[1] + config.box_margin
    in_footprint = (np.abs(local[:, 0]) <= reach_x) & (np.abs(local[:, 1]) <= reach_y)
    in_ring = ~in_footprint & (np.abs(local[:, 0]) <= reach_x + _GROUND_RING)
    in_ring &= np.abs(local[:, 1]) <= reach_y + _GROUND_RING
    in_ring &= np.abs(local_normals[:, 2]) >= config.ground_normal_min_z
    in_ring &= np.abs(local[:, 2] + half[2]) <= _GROUND_SEARCH
    ground = float(np.quantile(local[in_ring, 2], 0.25)) if np.count_nonzero(in_ring) >= 10 else -half[2]
    below_top = local[:, 2] <= half[2] + config.box_margin
    actor = in_footprint & below_top & (local[:, 2] > ground + config.ground_clearance)
    return _ActorSplit(actor=actor, ground=ground)


def _intensity_of(points: np.ndarray) -> FloatArray:
    if "intensity" in (points.dtype.names or ()):
        values: FloatArray = points["intensity"].astype(np.float64)
        return values
    return np.zeros(points.shape[0])
