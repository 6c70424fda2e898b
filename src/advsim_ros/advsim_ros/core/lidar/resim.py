"""LiDAR re-simulation: the sweep a perturbed world would have produced, from the logged sweep.

``ResimModel.build(scenario, cache_dir)`` estimates the sensor model from the sweeps, builds
the background (static scene) and one asset per track, and caches them on disk. Then
``resimulate(sweep, original_tracks, perturbed_tracks, rng=...)`` rewrites one sweep:

1. removal: for every actor whose pose changed, the points inside its slightly grown
   logged box are taken out; their rays, and the rays through the box that had no return,
   are "freed";
2. fill: freed rays are cast against the background and against the assets of the actors
   that did not move (an actor hidden behind the moved one becomes visible);
3. insertion: the rays through each moved actor's new box (the sweep's own rays, plus
   the cells with no return) are cast against its asset, and each ray keeps the nearest
   of what it had and the asset hit (element-wise minimum range): the actor occludes what
   lies behind it, and a ray the asset absorbs without a return (ray drop) returns nothing.

Only rays inside the moved actors' old and new angular footprints are cast. Every other
point passes through untouched, with all its fields; a changed point keeps its own ray
direction and fields and gets the new range and intensity; a new point (a cell that had
no return) copies the fields of its nearest neighbour on the same beam.
"""

from __future__ import annotations

import zlib
from collections import OrderedDict
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from advsim_ros.core.lidar.assets import ActorAsset, align_frames, build_asset
from advsim_ros.core.lidar.background import BackgroundModel, SweepDepth, build_background
from advsim_ros.core.lidar.boxes import (
    AngularWindow,
    BoolArray,
    actor_region,
    inside,
    invert_rigid,
    rays_hit_region,
    removal_region,
    to_box_frame,
    track_pose_at,
    yaw_pose,
)
from advsim_ros.core.lidar.cache import Digest, load_arrays, save_arrays
from advsim_ros.core.lidar.config import ResimConfig
from advsim_ros.core.lidar.raycast import RayHits, SurfaceCaster
from advsim_ros.core.lidar.sensor import (
    BeamRows,
    SphericalPoints,
    azimuth_columns,
    column_azimuths,
    estimate_sensor_model,
    point_normals,
    rotate,
    spherical,
    xyz_of,
)
from advsim_ros.core.lidar.surfels import PointSamples, SurfelCloud, voxel_merge
from advsim_ros.core.types import (
    ActorClass,
    ActorTrack,
    FloatArray,
    IntArray,
    Scenario,
    ScenarioError,
    SensorModel,
    Sweep,
)

MODEL_VERSION = "resim-model-6"  # bump when the built model's content changes meaning
_THIN_CHUNK_SWEEPS = 16  # background points are thinned every this many sweeps to bound memory
_RETURN_CLEARANCE = 0.15  # logged returns this close above a box's bottom are not counted as the actor's [m]
_MIN_DROP_RAYS = 30  # an asset's ray drop is estimated from at least this many re-simulated returns
_CALIBRATION_SEED = 20210601  # the ray-drop calibration's own random stream (the build stays deterministic)
_GROUND_RING = 1.5  # width of the ring around an actor where its ground height is measured [m]
_GROUND_SEARCH = 0.5  # the ground around an actor lies within this of its box bottom [m]
_VOLUME_CELL = 0.1  # grid cell of the volume any actor ever occupied [m]
_STATIC_CLEARANCE = 0.15  # that volume starts this far above the boxes' bottoms (labels sit a little low or high) [m]
_SURFACE_BAND = 0.1  # a logged return within this (+ 1 % of its range) of a surfel ended on it [m]
_PASS_PRIOR_STOPS = 1.0  # a surfel no logged ray crossed or ended on counts as opaque
_MAX_PASSES = 8  # a ray is walked through at most this many surfels it passes (glass)
_PASS_STEP = 1e-3  # a passing ray goes on from this far beyond the surfel it crossed [m]
_MERGE_EPSILON = 1e-3  # an inserted hit must be nearer than the current return by this much [m]


class ResimError(ScenarioError):
    """Input the re-simulation cannot work with; the message names the problem."""


@dataclass(frozen=True, eq=False)
class SweepGeometry:
    """Per-point geometry of one logged sweep (cached between calls)."""

    spherical: SphericalPoints
    rows: IntArray  # (N,) beam row of every point
    valid: BoolArray  # (N,) the point is a return (not the (0, 0, 0) placeholder)
    beam_ranges: FloatArray  # (N,) distance of every point from its beam's origin [m]


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


@dataclass(frozen=True, eq=False)
class _Change:
    actor_id: str
    old_pose: FloatArray | None  # (4, 4) T_sensor_box at the logged pose
    new_pose: FloatArray | None  # (4, 4) T_sensor_box at the perturbed pose
    size: FloatArray  # (3,) [m]


def covered_cells(rows: IntArray, azimuths: FloatArray, sensor: SensorModel, tolerance: float) -> BoolArray:
    """(B, A) image of the cells whose centre lies within `tolerance` azimuth steps of a ray on the same row."""
    covered = np.zeros((sensor.num_beams, sensor.num_azimuths), dtype=bool)
    fractional = np.mod(azimuths, 2.0 * np.pi) / sensor.azimuth_resolution
    first = np.ceil(fractional - tolerance - 0.5).astype(np.int64)
    last = np.floor(fractional + tolerance - 0.5).astype(np.int64)
    for offset in range(int(np.ceil(2.0 * tolerance)) + 1):
        column = first + offset
        mask = column <= last
        covered[rows[mask], np.mod(column[mask], sensor.num_azimuths)] = True
    return covered


def _nearest_on_row(rows: IntArray, azimuths: FloatArray, candidates: IntArray, geometry: SweepGeometry) -> IntArray:
    """Per query (row, azimuth), the candidate logged point on the same row nearest in azimuth; -1 if none."""
    result = np.full(rows.shape[0], -1, dtype=np.int64)
    if candidates.size == 0 or rows.size == 0:
        return result
    span = 2.0 * np.pi + 1.0  # keys of different rows never mix
    keys = geometry.rows[candidates] * span + (geometry.spherical.azimuths[candidates] + np.pi)
    order = np.argsort(keys)
    sorted_keys, sorted_candidates = keys[order], candidates[order]
    queries = rows * span + (azimuths + np.pi)
    position = np.searchsorted(sorted_keys, queries)
    best_gap = np.full(rows.shape[0], np.inf)
    for offset in (-1, 0):
        index = np.clip(position + offset, 0, sorted_keys.shape[0] - 1)
        same_row = geometry.rows[sorted_candidates[index]] == rows
        gap = np.where(same_row, np.abs(sorted_keys[index] - queries), np.inf)
        better = gap < best_gap
        result[better] = sorted_candidates[index][better]
        best_gap = np.minimum(best_gap, gap)
    return result


class _RayTable:
    """Every ray of one sweep being rewritten: the logged points' rays, then added cell rays."""

    def __init__(self, points: np.ndarray, geometry: SweepGeometry, beam_rows: BeamRows) -> None:
        self.points = points
        self.geometry = geometry
        self.beam_rows = beam_rows
        self.sensor = beam_rows.sensor
        count = points.shape[0]
        self.count = count
        self.stop = geometry.beam_ranges.copy()  # distance from the beam's origin where the ray ends [m]; inf: none
        self.returned = geometry.valid.copy()  # the ray gives a point
        self.intensity = np.zeros(count)  # intensity of changed rays
        self.changed = np.zeros(count, dtype=bool)
        # Added rays (cells with no logged return), as lists of chunks joined on demand.
        self.added_origins = np.zeros((0, 3))
        self.added_directions = np.zeros((0, 3))
        self.added_rows = np.zeros(0, dtype=np.int64)
        self.added_azimuths = np.zeros(0)
        self.added_elevations = np.zeros(0)
        self.added_stop = np.zeros(0)
        self.added_returned = np.zeros(0, dtype=bool)
        self.added_intensity = np.zeros(0)
        self.added_template = np.zeros(0, dtype=np.int64)  # logged point whose fields a new point copies; -1: none

    def logged_rays(self, indices: IntArray) -> tuple[FloatArray, FloatArray]:
        """Origins and unit directions of logged points' rays."""
        origins = self.beam_rows.origins(self.geometry.rows[indices])
        directions: FloatArray = (self.geometry.spherical.xyz[indices] - origins) / self.geometry.beam_ranges[
            indices, None
        ]
        return origins, directions

    def window_candidates(self, window: AngularWindow) -> tuple[IntArray, IntArray]:
        """Logged and added rays seen under the window (by direction, or by beam row for coverage)."""
        geometry = self.geometry
        rows_in = np.zeros(self.sensor.num_beams, dtype=bool)
        rows_in[window.rows(self.sensor)] = True
        relaxed = AngularWindow(
            window.center_azimuth, window.azimuth_low, window.azimuth_high, -np.pi, np.pi, window.full_turn
        )
        az_ok = relaxed.contains(geometry.spherical.azimuths, geometry.spherical.elevations)
        el = geometry.spherical.elevations
        el_ok = (el >= window.elevation_low) & (el <= window.elevation_high)
        logged = np.flatnonzero(az_ok & (el_ok | rows_in[geometry.rows]) & geometry.valid)
        added_az_ok = relaxed.contains(self.added_azimuths, self.added_elevations)
        added = np.flatnonzero(added_az_ok & rows_in[self.added_rows])
        return logged, added

    def uncovered_cells(
        self, window: AngularWindow, logged: IntArray, added: IntArray, tolerance: float
    ) -> tuple[IntArray, IntArray]:
        """Rows and columns of window cells that no ray within `tolerance` azimuth steps serves."""
        sensor = self.sensor
        rows = window.rows(sensor)
        columns = window.columns(sensor)
        if rows.size == 0 or columns.size == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        covered = covered_cells(
            np.concatenate([self.geometry.rows[logged], self.added_rows[added]]),
            np.concatenate([self.geometry.spherical.azimuths[logged], self.added_azimuths[added]]),
            sensor,
            tolerance,
        )
        grid_rows = np.repeat(rows, columns.shape[0])
        grid_columns = np.tile(columns, rows.shape[0])
        open_cells = ~covered[grid_rows, grid_columns]
        return grid_rows[open_cells], grid_columns[open_cells]

    def add_rays(self, rows: IntArray, columns: IntArray, nearby: IntArray) -> IntArray:
        """Append cell rays (no return yet); their indices among the added rays.

        `nearby` are logged rays near the cells, where new points look for the fields to copy.
        """
        elevations = self.sensor.beam_elevations[rows]
        azimuths = column_azimuths(columns, self.sensor)
        origins, directions = self.beam_rows.cell_rays(rows, columns)
        start = self.added_rows.shape[0]
        self.added_origins = np.concatenate([self.added_origins, origins])
        self.added_directions = np.concatenate([self.added_directions, directions])
        self.added_rows = np.concatenate([self.added_rows, rows])
        self.added_azimuths = np.concatenate([self.added_azimuths, azimuths])
        self.added_elevations = np.concatenate([self.added_elevations, elevations])
        self.added_stop = np.concatenate([self.added_stop, np.full(rows.shape[0], np.inf)])
        self.added_returned = np.concatenate([self.added_returned, np.zeros(rows.shape[0], dtype=bool)])
        self.added_intensity = np.concatenate([self.added_intensity, np.zeros(rows.shape[0])])
        self.added_template = np.concatenate([self.added_template, self._templates(rows, azimuths, nearby)])
        return np.arange(start, self.added_rows.shape[0], dtype=np.int64)

    def _templates(self, rows: IntArray, azimuths: FloatArray, nearby: IntArray) -> IntArray:
        """For each new cell, the logged point of its row nearest in azimuth (-1 when the row has none).

        Searched among `nearby` logged points first (the window's), then the whole row.
        """
        geometry = self.geometry
        templates = _nearest_on_row(rows, azimuths, nearby, geometry)
        missing = np.flatnonzero(templates < 0)
        if missing.size:
            everyone = np.flatnonzero(np.isin(geometry.rows, np.unique(rows[missing])) & geometry.valid)
            templates[missing] = _nearest_on_row(rows[missing], azimuths[missing], everyone, geometry)
        return templates

    def update(
        self, logged: IntArray, added: IntArray, hits: RayHits, returns: BoolArray, displaced: BoolArray | None = None
    ) -> BoolArray:
        """Keep the nearer of the current end and the hit per ray; True where the hit won.

        hits/returns are ordered as logged rays then added rays. Where `displaced` is set the
        current end cannot be there any more (it lies inside the inserted actor), so any hit wins.
        """
        count = logged.shape[0]
        current = np.concatenate([self.stop[logged], self.added_stop[added]])
        nearer = hits.ranges < current - _MERGE_EPSILON
        if displaced is not None:
            nearer |= displaced & np.isfinite(hits.ranges)
        logged_win, added_win = nearer[:count], nearer[count:]
        chosen = logged[logged_win]
        self.stop[chosen] = hits.ranges[:count][logged_win]
        self.returned[chosen] = returns[:count][logged_win]
        self.intensity[chosen] = hits.intensity[:count][logged_win]
        self.changed[chosen] = True
        chosen_added = added[added_win]
        self.added_stop[chosen_added] = hits.ranges[count:][added_win]
        self.added_returned[chosen_added] = returns[count:][added_win]
        self.added_intensity[chosen_added] = hits.intensity[count:][added_win]
        result: BoolArray = nearer
        return result

    def rays(self, logged: IntArray, added: IntArray) -> tuple[FloatArray, FloatArray]:
        """Origins (N, 3) and unit directions (N, 3) of logged rays then added rays."""
        origins, directions = self.logged_rays(logged)
        return (
            np.concatenate([origins, self.added_origins[added]]).reshape(-1, 3),
            np.concatenate([directions, self.added_directions[added]]).reshape(-1, 3),
        )

    def assemble(self) -> np.ndarray:
        """The rewritten sweep: logged points that still return (changed ones moved along their ray), then new ones."""
        points = self.points
        names = points.dtype.names or ()
        keep = self.returned | ~self.geometry.valid  # (0, 0, 0) placeholders pass through as they came
        result = points[keep].copy()
        changed = np.flatnonzero(self.changed[keep])
        if changed.size:
            source = np.flatnonzero(keep)[changed]
            origins, directions = self.logged_rays(source)
            xyz = origins + directions * self.stop[source, None]
            _write_points(result, changed, xyz, self.intensity[source], names)
        new = np.flatnonzero(self.added_returned)
        if new.size == 0:
            return result
        extra = np.zeros(new.shape[0], dtype=points.dtype)
        templates = self.added_template[new]
        has_template = templates >= 0
        extra[has_template] = points[templates[has_template]]
        xyz = self.added_origins[new] + self.added_directions[new] * self.added_stop[new, None]
        _write_points(extra, np.arange(new.shape[0]), xyz, self.added_intensity[new], names)
        return np.concatenate([result, extra])


def _write_points(
    target: np.ndarray, indices: IntArray, xyz: FloatArray, intensity: FloatArray, names: Sequence[str]
) -> None:
    """Set x, y, z and (when the layout has it) intensity of target[indices], in each field's own type."""
    for axis, name in enumerate(("x", "y", "z")):
        target[name][indices] = xyz[:, axis].astype(target.dtype[name])
    if "intensity" in names:
        kind = target.dtype["intensity"]
        values = intensity
        if np.issubdtype(kind, np.integer):
            info = np.iinfo(kind)
            values = np.clip(np.rint(values), info.min, info.max)
        target["intensity"][indices] = values.astype(kind)


@dataclass(frozen=True, eq=False)
class _LogPoints:
    """A log's points split into the static scene (world frame) and each track's own points (box frame)."""

    background: PointSamples  # static points, merged on the background grid
    depths: list[SweepDepth]  # range images of every carve_sweep_stride-th sweep
    actors: dict[str, PointSamples]  # track id -> its points in its box frame
    actor_intensity: dict[str, FloatArray]  # track id -> intensity of its raw points
    actor_frames: dict[str, list[int]]  # track id -> sweep indices where it had points


def collect_log_points(scenario: Scenario, beam_rows: BeamRows, config: ResimConfig) -> _LogPoints:
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
    return _LogPoints(
        background=PointSamples.concatenate(merged + pending),
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


def scenario_digest(scenario: Scenario, config: ResimConfig) -> str:
    """A hash of everything the built model depends on: sweeps, poses, tracks, settings."""
    digest = Digest(MODEL_VERSION)
    digest.text(config.model_key())
    digest.array(scenario.frame_stamps_ns)
    for sweep in scenario.sweeps:
        digest.array(np.array([sweep.stamp_ns]))
        digest.array(sweep.sensor_pose)
        digest.text(str(sweep.points.dtype))
        digest.array(
            sweep.points.view(np.uint8).reshape(-1) if sweep.points.flags.c_contiguous else sweep.points.copy()
        )
    for actor in scenario.actors:
        digest.text(f"{actor.actor_id}|{actor.actor_class.value}")
        for array in (actor.size, actor.stamps_ns, actor.centers, actor.yaws):
            digest.array(array)
    return digest.hexdigest()


class ResimModel:
    """The log's sensor model, background and actor assets, ready to rewrite its sweeps."""

    def __init__(
        self,
        beam_rows: BeamRows,
        background: BackgroundModel,
        assets: dict[str, ActorAsset],
        config: ResimConfig,
    ) -> None:
        self.beam_rows = beam_rows
        self.sensor = beam_rows.sensor
        self.background = background
        self.assets = assets
        self.config = config
        self.background_caster = SurfaceCaster(background.surfels.surface())
        # Every asset's acceleration structure is built now, not on a query's first sweep.
        self._asset_casters: dict[str, SurfaceCaster] = {
            key: SurfaceCaster(asset.surface()) for key, asset in assets.items()
        }
        self._geometries: OrderedDict[tuple[int, int, int], SweepGeometry] = OrderedDict()

    # ----- building and caching -------------------------------------------------------------

    @classmethod
    def build(cls, scenario: Scenario, cache_dir: Path | None = None, config: ResimConfig | None = None) -> ResimModel:
        """The model of a log with sweeps; read from `cache_dir` when built before with the same inputs."""
        config = config or ResimConfig()
        if not scenario.sweeps:
            raise ResimError(f"scenario {scenario.scenario_id} has no LiDAR sweeps to build a re-simulation model from")
        path = None
        if cache_dir is not None:
            path = Path(cache_dir) / f"resim-{scenario_digest(scenario, config)}.npz"
            arrays = load_arrays(path)
            if arrays is not None:
                return cls._from_arrays(arrays, config)
        model = cls._build_fresh(scenario, config)
        if path is not None:
            save_arrays(path, model._to_arrays())
        return model

    @classmethod
    def _build_fresh(cls, scenario: Scenario, config: ResimConfig) -> ResimModel:
        beam_rows = estimate_sensor_model(scenario.sweeps)
        log_points = collect_log_points(scenario, beam_rows, config)
        background = build_background(log_points.background, log_points.depths, beam_rows, config)
        assets = _build_assets(scenario, log_points, config)
        model = cls(beam_rows, background, assets, config)
        model.assets = model._estimate_optics(scenario, log_points)
        return model

    def _to_arrays(self) -> dict[str, np.ndarray]:
        arrays = self.background.to_arrays()
        sensor = self.sensor
        arrays["sensor/beam_elevations"] = sensor.beam_elevations
        arrays["sensor/limits"] = np.array([sensor.azimuth_resolution, sensor.min_range, sensor.max_range])
        arrays["sensor/source"] = np.array(self.beam_rows.source)
        arrays["sensor/ring_to_row"] = self.beam_rows.ring_to_row
        arrays["sensor/beam_heights"] = self.beam_rows.beam_heights
        arrays["sensor/scan_start"] = np.array(self.beam_rows.scan_start)
        arrays["assets/ids"] = np.array(list(self.assets), dtype=str)
        for key, asset in self.assets.items():
            arrays.update(asset.surfels.to_arrays(f"asset/{key}/"))
            arrays[f"asset/{key}/class"] = np.array(asset.actor_class.value)
            if asset.pass_probability is not None:
                arrays[f"asset/{key}/pass"] = asset.pass_probability
            arrays[f"asset/{key}/numbers"] = np.concatenate(
                [asset.size, [asset.template_intensity, asset.drop_probability, asset.num_points]]
            )
        return arrays

    @classmethod
    def _from_arrays(cls, arrays: dict[str, np.ndarray], config: ResimConfig) -> ResimModel:
        resolution, min_range, max_range = (float(value) for value in arrays["sensor/limits"])
        sensor = SensorModel(
            beam_elevations=arrays["sensor/beam_elevations"],
            azimuth_resolution=resolution,
            min_range=min_range,
            max_range=max_range,
        )
        beam_rows = BeamRows(
            sensor=sensor,
            source=str(arrays["sensor/source"]),
            ring_to_row=arrays["sensor/ring_to_row"],
            beam_heights=arrays["sensor/beam_heights"],
            scan_start=float(arrays["sensor/scan_start"]),
        )
        assets: dict[str, ActorAsset] = {}
        for key in (str(value) for value in arrays["assets/ids"]):
            numbers = arrays[f"asset/{key}/numbers"]
            assets[key] = ActorAsset(
                actor_id=key,
                actor_class=ActorClass(str(arrays[f"asset/{key}/class"])),
                size=numbers[:3],
                surfels=SurfelCloud.from_arrays(arrays, f"asset/{key}/"),
                template_intensity=float(numbers[3]),
                drop_probability=float(numbers[4]),
                num_points=int(numbers[5]),
                pass_probability=arrays.get(f"asset/{key}/pass"),
            )
        return cls(beam_rows, BackgroundModel.from_arrays(arrays), assets, config)

    # ----- per-sweep geometry --------------------------------------------------------------

    def geometry(self, points: np.ndarray, stamp_ns: int) -> SweepGeometry:
        """Per-point geometry of a sweep, cached by stamp and content."""
        key = (stamp_ns, points.shape[0], zlib.crc32(np.ascontiguousarray(points).data.cast("B")))
        cached = self._geometries.get(key)
        if cached is not None:
            self._geometries.move_to_end(key)
            return cached
        spherical_points = spherical(xyz_of(points))
        rows = self.beam_rows.rows(points, spherical_points)
        _, _, beam_ranges = self.beam_rows.point_rays(spherical_points.xyz, rows)
        geometry = SweepGeometry(
            spherical=spherical_points, rows=rows, valid=spherical_points.ranges > 1e-3, beam_ranges=beam_ranges
        )
        self._geometries[key] = geometry
        while len(self._geometries) > self.config.sweep_cache_size:
            self._geometries.popitem(last=False)
        return geometry

    def asset_caster(self, actor_id: str) -> SurfaceCaster:
        caster = self._asset_casters.get(actor_id)
        if caster is None:
            caster = SurfaceCaster(self.assets[actor_id].surface())
            self._asset_casters[actor_id] = caster
        return caster

    # ----- re-simulation -------------------------------------------------------------------

    def resimulate(
        self,
        sweep: Sweep,
        original_tracks: Sequence[ActorTrack],
        perturbed_tracks: Sequence[ActorTrack],
        *,
        rng: np.random.Generator,
        moved: Collection[str] = (),
    ) -> np.ndarray:
        """The sweep of the perturbed world, as a structured array with the sweep's own fields."""
        points, _ = self.resimulate_with_stats(sweep, original_tracks, perturbed_tracks, rng=rng, moved=moved)
        return points

    def resimulate_with_stats(
        self,
        sweep: Sweep,
        original_tracks: Sequence[ActorTrack],
        perturbed_tracks: Sequence[ActorTrack],
        *,
        rng: np.random.Generator,
        moved: Collection[str] = (),
    ) -> tuple[np.ndarray, ResimStats]:
        """``resimulate`` plus per-actor figures.

        Actors are matched by id; an actor only in `original_tracks` at the sweep's stamp is
        removed, one only in `perturbed_tracks` is inserted (it needs an asset: the id of a
        track of this log). Ids in `moved` are re-simulated even where their pose did not
        change (to check that re-inserting an actor where it was reproduces the sweep).
        """
        stats = ResimStats()
        changes = self._changes(sweep, original_tracks, perturbed_tracks, set(moved))
        if not changes:
            return sweep.points.copy(), stats
        geometry = self.geometry(sweep.points, sweep.stamp_ns)
        table = _RayTable(sweep.points, geometry, self.beam_rows)
        sensor_T_world = invert_rigid(sweep.sensor_pose)
        for change in changes:
            stats.actors[change.actor_id] = ActorResimStats()
        freed = self._remove(table, changes, stats)
        unchanged = self._unchanged_actors(
            sweep, perturbed_tracks, {change.actor_id for change in changes}, sensor_T_world
        )
        self._fill(table, freed, sensor_T_world, unchanged, stats, rng)
        for change in changes:
            if change.new_pose is not None:
                self._insert(table, change, stats.actors[change.actor_id], rng, stats)
        return table.assemble(), stats

    def _changes(
        self,
        sweep: Sweep,
        original_tracks: Sequence[ActorTrack],
        perturbed_tracks: Sequence[ActorTrack],
        forced: set[str],
    ) -> list[_Change]:
        originals = {track.actor_id: track for track in original_tracks}
        perturbed = {track.actor_id: track for track in perturbed_tracks}
        sensor_T_world = invert_rigid(sweep.sensor_pose)
        changes: list[_Change] = []
        for actor_id in sorted(set(originals) | set(perturbed)):
            old = track_pose_at(originals[actor_id], sweep.stamp_ns) if actor_id in originals else None
            new = track_pose_at(perturbed[actor_id], sweep.stamp_ns) if actor_id in perturbed else None
            if old is None and new is None:
                continue
            if old is not None and new is not None and actor_id not in forced and self._same_pose(old, new):
                continue
            if new is not None and actor_id not in self.assets:
                raise ResimError(
                    f"actor {actor_id!r} has no asset in this log's model: only logged actors can be inserted"
                )
            if new is not None and self.config.snap_to_ground:
                new = self._snapped(new, old)
            track = perturbed[actor_id] if actor_id in perturbed else originals[actor_id]
            changes.append(
                _Change(
                    actor_id=actor_id,
                    old_pose=None if old is None else sensor_T_world @ old,
                    new_pose=None if new is None else sensor_T_world @ new,
                    size=track.size,
                )
            )
        return changes

    def _same_pose(self, old: FloatArray, new: FloatArray) -> bool:
        offset = float(np.linalg.norm(old[:3, 3] - new[:3, 3]))
        turn = float(np.arccos(np.clip(0.5 * (np.trace(old[:3, :3].T @ new[:3, :3]) - 1.0), -1.0, 1.0)))
        return offset < self.config.pose_tolerance and turn < self.config.yaw_tolerance

    def _snapped(self, new: FloatArray, old: FloatArray | None) -> FloatArray:
        """The new pose with its height following the background ground between the old and new place."""
        ground = self.background.ground
        heights = ground.height_at(np.array([new[:2, 3], new[:2, 3] if old is None else old[:2, 3]]))
        if old is None or not np.all(np.isfinite(heights)):
            return new
        yaw = float(np.arctan2(new[1, 0], new[0, 0]))
        center = new[:3, 3].copy()
        center[2] = old[2, 3] + heights[0] - heights[1]
        return yaw_pose(center, yaw)

    def _unchanged_actors(
        self, sweep: Sweep, perturbed_tracks: Sequence[ActorTrack], changed: set[str], sensor_T_world: FloatArray
    ) -> list[tuple[str, FloatArray]]:
        present: list[tuple[str, FloatArray]] = []
        for track in perturbed_tracks:
            if track.actor_id in changed or track.actor_id not in self.assets:
                continue
            pose = track_pose_at(track, sweep.stamp_ns)
            if pose is not None:
                present.append((track.actor_id, sensor_T_world @ pose))
        return present

    def _remove(
        self, table: _RayTable, changes: list[_Change], stats: ResimStats
    ) -> dict[str, tuple[IntArray, IntArray]]:
        """Cut the moved actors out of the sweep; returns each actor's freed logged and added rays."""
        config = self.config
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
            through = rays_hit_region(*self.beam_rows.cell_rays(rows, columns), change.old_pose, region)
            cells = table.add_rays(rows[through], columns[through], logged)
            freed[change.actor_id] = (removed, cells)
            actor_stats = stats.actors[change.actor_id]
            actor_stats.removed_points = int(removed.shape[0])
            actor_stats.freed_rays = int(removed.shape[0] + cells.shape[0])
        return freed

    def _fill(
        self,
        table: _RayTable,
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
        hits = self.background_caster.cast(origins, directions, sensor_T_world)
        dropped = np.zeros(directions.shape[0], dtype=bool)
        azimuths = np.arctan2(directions[:, 1], directions[:, 0])
        elevations = np.arcsin(np.clip(directions[:, 2], -1.0, 1.0))
        for actor_id, pose in unchanged:
            asset = self.assets[actor_id]
            window = AngularWindow.of_region(
                pose, removal_region(asset.size, self.config.removal_margin), self.config.window_margin
            )
            seen = np.flatnonzero(window.contains(azimuths, elevations))
            if seen.size == 0:
                continue
            found = self.cast_actor(actor_id, origins[seen], directions[seen], pose, rng)
            nearer = found.ranges < hits.ranges[seen]
            chosen = seen[nearer]
            hits.ranges[chosen] = found.ranges[nearer]
            hits.intensity[chosen] = found.intensity[nearer]
            dropped[chosen] = rng.random(chosen.shape[0]) < asset.drop_probability
            stats.cast_rays += int(seen.shape[0])
        stats.cast_rays += int(directions.shape[0])
        returns = self._in_range(hits.ranges) & ~dropped
        table.update(logged, added, hits, returns)
        for actor_id, (own_logged, own_added) in freed.items():
            filled = np.count_nonzero(table.returned[own_logged]) + np.count_nonzero(table.added_returned[own_added])
            stats.actors[actor_id].filled_rays = int(filled)

    def _insert(
        self,
        table: _RayTable,
        change: _Change,
        actor_stats: ActorResimStats,
        rng: np.random.Generator,
        stats: ResimStats,
    ) -> None:
        """Cast the rays through the actor's new box against its asset and keep the nearer return per ray."""
        assert change.new_pose is not None
        config = self.config
        region = removal_region(change.size, config.removal_margin)
        window = AngularWindow.of_region(change.new_pose, region, config.window_margin)
        logged, added = table.window_candidates(window)
        rows, columns = table.uncovered_cells(window, logged, added, config.coverage_tolerance)
        through = rays_hit_region(*self.beam_rows.cell_rays(rows, columns), change.new_pose, region)
        existing_through = rays_hit_region(*table.rays(logged, added), change.new_pose, region)
        count = logged.shape[0]
        cells = table.add_rays(rows[through], columns[through], logged)
        logged, added = logged[existing_through[:count]], added[existing_through[count:]]
        added = np.concatenate([added, cells])
        origins, directions = table.rays(logged, added)
        asset = self.assets[change.actor_id]
        hits = self.cast_actor(change.actor_id, origins, directions, change.new_pose, rng)
        stats.cast_rays += int(directions.shape[0])
        dropped = rng.random(directions.shape[0]) < asset.drop_probability
        returns = np.logical_and(self._in_range(hits.ranges), np.logical_not(dropped))
        # Whatever the ray ended on inside the actor's new box (background left over from the log,
        # e.g. parts of the actor itself outside its label) gives way to the actor.
        current = np.concatenate([table.stop[logged], table.added_stop[added]])
        ends = origins + directions * np.where(np.isfinite(current), current, 0.0)[:, None]
        inner = actor_region(change.size, config.box_margin, _RETURN_CLEARANCE)
        displaced = np.isfinite(current) & inside(to_box_frame(ends, change.new_pose), inner)
        won = table.update(logged, added, hits, returns, displaced)
        actor_stats.inserted_returns = int(np.count_nonzero(won & returns))
        actor_stats.dropped_rays = int(np.count_nonzero(won & ~returns))

    def cast_actor(
        self, actor_id: str, origins: FloatArray, directions: FloatArray, pose: FloatArray, rng: np.random.Generator
    ) -> RayHits:
        """Where rays stop on an actor's asset at `pose` (T_sensor_box), each crossed surfel letting the ray
        through with its pass probability (glass); misses are inf."""
        asset = self.assets[actor_id]
        caster = self.asset_caster(actor_id)
        hits = caster.cast(origins, directions, pose)
        passing = asset.pass_probability
        if passing is None:
            return hits
        # Walk each ray through the surfels it crosses: only rays that pass a surfel are cast again,
        # from just beyond it (which also skips the twin triangle of the same surfel).
        start = np.zeros(directions.shape[0])  # where the current cast begins along the ray [m]
        active = np.arange(directions.shape[0])
        for _ in range(_MAX_PASSES):
            assert hits.triangles is not None
            surfel = np.maximum(hits.triangles[active], 0) // 2
            passes = np.isfinite(hits.ranges[active]) & (rng.random(active.shape[0]) < passing[surfel])
            if not np.any(passes):
                break
            active = active[passes]
            start[active] = hits.ranges[active] + _PASS_STEP
            further = caster.cast(origins[active] + directions[active] * start[active, None], directions[active], pose)
            assert further.triangles is not None
            found = np.isfinite(further.ranges)
            hits.ranges[active] = np.where(found, start[active] + further.ranges, np.inf)
            hits.intensity[active] = further.intensity
            hits.source[active] = further.source
            hits.triangles[active] = further.triangles
            active = active[found]
        return hits

    def _in_range(self, ranges: FloatArray) -> BoolArray:
        result: BoolArray = (ranges >= self.sensor.min_range) & (ranges <= self.sensor.max_range)
        return result

    # ----- ray drop estimation ----------------------------------------------------------------

    def _estimate_optics(self, scenario: Scenario, log_points: _LogPoints) -> dict[str, ActorAsset]:
        """Each observed asset's per-surfel pass probabilities and ray drop, from the log at the logged poses.

        A surfel that logged rays crossed to return from farther behind it (through a car's
        windows) lets rays pass. The ray drop then makes the asset, re-inserted at its logged
        poses by this very re-simulation, return as many points inside its grown box as the
        actor did: 1 - (logged returns) / (re-simulated returns without drop). Template assets
        take their class's median drop and are opaque.
        """
        config = self.config
        views: dict[str, list[Sweep]] = {}
        for actor in scenario.actors:
            asset = self.assets[actor.actor_id]
            frames = log_points.actor_frames[actor.actor_id]
            if asset.is_template or not frames:
                continue
            picks = np.unique(np.linspace(0, len(frames) - 1, min(config.drop_estimate_frames, len(frames))).round())
            views[actor.actor_id] = [scenario.sweeps[frames[int(pick)]] for pick in picks]
            passed = np.zeros(asset.surfels.count)
            stopped = np.zeros(asset.surfels.count)
            for sweep in views[actor.actor_id]:
                self._count_crossings(sweep, actor, self._sensor_pose_of(actor, sweep), passed, stopped)
            self.assets[actor.actor_id] = asset.with_optics(0.0, passed / (passed + stopped + _PASS_PRIOR_STOPS))
        by_class: dict[ActorClass, list[float]] = {}
        measured: set[str] = set()
        for actor in scenario.actors:
            if actor.actor_id not in views:
                continue
            returns = resimulated = 0
            for index, sweep in enumerate(views[actor.actor_id]):
                count_returns, count_resimulated = self._returns_and_reinserted(sweep, actor, scenario.actors, index)
                returns += count_returns
                resimulated += count_resimulated
            if resimulated < _MIN_DROP_RAYS:
                continue  # too few returns to tell the drop: the class value below
            probability = float(np.clip(1.0 - returns / resimulated, 0.0, config.max_drop_probability))
            asset = self.assets[actor.actor_id]
            self.assets[actor.actor_id] = asset.with_optics(probability, asset.pass_probability)
            measured.add(actor.actor_id)
            by_class.setdefault(asset.actor_class, []).append(probability)
        for actor in scenario.actors:
            if actor.actor_id in measured:
                continue
            asset = self.assets[actor.actor_id]
            known = by_class.get(asset.actor_class)
            probability = float(np.median(known)) if known else config.default_drop_probability
            self.assets[actor.actor_id] = asset.with_optics(probability, asset.pass_probability)
        return self.assets

    @staticmethod
    def _sensor_pose_of(actor: ActorTrack, sweep: Sweep) -> FloatArray:
        """T_sensor_box of an actor at a sweep it was labelled in."""
        pose = track_pose_at(actor, sweep.stamp_ns)
        assert pose is not None
        return invert_rigid(sweep.sensor_pose) @ pose

    def _returns_and_reinserted(
        self, sweep: Sweep, actor: ActorTrack, tracks: Sequence[ActorTrack], index: int
    ) -> tuple[int, int]:
        """The actor's logged returns in its grown box, and its returns there when re-inserted where it was."""
        pose = self._sensor_pose_of(actor, sweep)
        region = actor_region(actor.size, self.config.box_margin, _RETURN_CLEARANCE)
        rng = np.random.default_rng([_CALIBRATION_SEED, index])
        points = self.resimulate(sweep, tracks, tracks, rng=rng, moved=[actor.actor_id])
        logged = int(np.count_nonzero(inside(to_box_frame(xyz_of(sweep.points), pose), region)))
        return logged, int(np.count_nonzero(inside(to_box_frame(xyz_of(points), pose), region)))

    def _window(self, actor: ActorTrack, pose: FloatArray) -> AngularWindow:
        """The angular window of an actor's grown box at `pose` (T_sensor_box)."""
        config = self.config
        return AngularWindow.of_region(pose, removal_region(actor.size, config.removal_margin), config.window_margin)

    def _count_crossings(
        self, sweep: Sweep, actor: ActorTrack, pose: FloatArray, passed: FloatArray, stopped: FloatArray
    ) -> None:
        """Add, per surfel, the logged rays that went through it and the ones that ended on it."""
        geometry = self.geometry(sweep.points, sweep.stamp_ns)
        table = _RayTable(sweep.points, geometry, self.beam_rows)
        window = self._window(actor, pose)
        logged, _ = table.window_candidates(window)
        origins, directions = table.logged_rays(logged)
        crossings = self.asset_caster(actor.actor_id).cast_all(origins, directions, pose)
        surfel = crossings.triangles // 2
        measured = geometry.beam_ranges[logged][crossings.ray_ids]
        surfels = self.assets[actor.actor_id].surfels
        # How far the logged return lies from the crossed surfel: a ray grazing a surface crosses
        # its surfels well before its return, yet the return sits on the same surface.
        returns_in_box = to_box_frame(geometry.spherical.xyz[logged][crossings.ray_ids], pose)
        apart = np.linalg.norm(returns_in_box - surfels.centers[surfel], axis=1) - surfels.half_sizes[surfel]
        beyond = (crossings.ranges < measured - _SURFACE_BAND - 0.01 * measured) & (apart > _SURFACE_BAND)
        np.add.at(passed, surfel[beyond], 1.0)
        np.add.at(stopped, surfel[~beyond & (crossings.ranges <= measured + _SURFACE_BAND)], 1.0)


def _build_assets(scenario: Scenario, log_points: _LogPoints, config: ResimConfig) -> dict[str, ActorAsset]:
    """One asset per track: observed where it has enough points, the class template otherwise."""
    every = np.concatenate([values for values in log_points.actor_intensity.values()] + [np.zeros(0)])
    fallback = float(np.median(every)) if every.size else float(np.median(log_points.background.intensity))
    by_class: dict[ActorClass, list[FloatArray]] = {}
    for actor in scenario.actors:
        by_class.setdefault(actor.actor_class, []).append(log_points.actor_intensity[actor.actor_id])
    class_intensity = {
        actor_class: float(np.median(np.concatenate(values))) if sum(v.size for v in values) else fallback
        for actor_class, values in by_class.items()
    }
    assets: dict[str, ActorAsset] = {}
    for actor in scenario.actors:
        assets[actor.actor_id] = build_asset(
            actor.actor_id,
            actor.actor_class,
            actor.size,
            log_points.actors[actor.actor_id],
            mirror=actor.actor_class.value in config.mirror_classes,
            voxel_size=config.asset_voxel,
            size_scale=config.surfel_size_scale,
            max_half_size=config.asset_max_half_size,
            min_points=config.asset_min_points,
            template_intensity=class_intensity[actor.actor_class],
        )
    return assets


__all__ = [
    "ActorResimStats",
    "ResimError",
    "ResimModel",
    "ResimStats",
    "SweepGeometry",
    "collect_log_points",
    "scenario_digest",
]
