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

This module holds ``ResimModel``: building (or loading from the cache) and the entry points.
The parts live beside it: ``sensor_estimation``, ``log_points``, ``background``, ``assets`` and
``optics`` (the build), ``model_cache`` (the cache), ``changes`` (which actors moved),
``rewrite`` (steps 1-3) and ``ray_table`` (the rays and the merge).
"""

from __future__ import annotations

import zlib
from collections import OrderedDict
from collections.abc import Collection, Sequence
from pathlib import Path

import numpy as np

from advsim_ros.core.lidar.assets import ActorAsset, build_assets
from advsim_ros.core.lidar.background import BackgroundModel, build_background
from advsim_ros.core.lidar.cache import build_lock, load_arrays, save_arrays
from advsim_ros.core.lidar.changes import actor_changes
from advsim_ros.core.lidar.config import ResimConfig
from advsim_ros.core.lidar.errors import ResimError
from advsim_ros.core.lidar.log_points import collect_log_points
from advsim_ros.core.lidar.model_cache import model_arrays, model_parts, scenario_digest
from advsim_ros.core.lidar.optics import estimate_optics
from advsim_ros.core.lidar.ray_table import SweepGeometry
from advsim_ros.core.lidar.raycast import NO_TRIANGLE, RayHits, SurfaceCaster
from advsim_ros.core.lidar.rewrite import ActorResimStats, ResimStats, rewrite_sweep
from advsim_ros.core.lidar.sensor import BeamRows, rotate, spherical, xyz_of
from advsim_ros.core.lidar.sensor_estimation import estimate_sensor_model
from advsim_ros.core.memory import release_freed_memory
from advsim_ros.core.types import ActorTrack, FloatArray, Scenario, Sweep

_MAX_PASSES = 8  # a ray is walked through at most this many surfels it passes (glass)
_PASS_STEP = 1e-3  # a passing ray goes on from this far beyond the surfel it crossed [m]


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
        self._background_caster: SurfaceCaster | None = None
        self._asset_casters: dict[str, SurfaceCaster] = {}
        self._geometries: OrderedDict[tuple[int, int, int], SweepGeometry] = OrderedDict()

    def prepare(self) -> ResimModel:
        """Build every ray-casting structure now, not on a query's first sweep; returns the model.

        Separate from construction so that a caller can first drop what it no longer needs
        (the lidar_resim node: the sweeps it never re-simulates) and the structures, the
        model's largest part, are not built on top of it.
        """
        for actor_id in self.assets:
            self.asset_caster(actor_id)
        _ = self.background_caster
        return self

    @property
    def background_caster(self) -> SurfaceCaster:
        if self._background_caster is None:
            self._background_caster = SurfaceCaster.lean(self.background.surfels.surface)
        return self._background_caster

    # ----- building and caching -------------------------------------------------------------

    @classmethod
    def build(cls, scenario: Scenario, cache_dir: Path | None = None, config: ResimConfig | None = None) -> ResimModel:
        """The model of a log with sweeps; read from `cache_dir` when built before with the same inputs."""
        config = config or ResimConfig()
        if not scenario.sweeps:
            raise ResimError(f"scenario {scenario.scenario_id} has no LiDAR sweeps to build a re-simulation model from")
        if cache_dir is None:
            return cls._build_fresh(scenario, config)
        path = Path(cache_dir) / f"resim-{scenario_digest(scenario, config)}.npz"
        with build_lock(path):
            arrays = load_arrays(path)
            if arrays is not None:  # the ray-casting structures come with prepare() or the first cast
                return cls(*model_parts(arrays), config)
            model = cls._build_fresh(scenario, config)
            save_arrays(path, model_arrays(model.beam_rows, model.background, model.assets))
        return model

    @classmethod
    def _build_fresh(cls, scenario: Scenario, config: ResimConfig) -> ResimModel:
        """Sensor model, log points, background and assets from the log, then the assets' optics calibrated."""
        beam_rows = estimate_sensor_model(scenario.sweeps)
        log_points = collect_log_points(scenario, beam_rows, config)
        release_freed_memory()  # each stage's temporaries leave holes between what it keeps (~0.5 GB on KITTI)
        assets = build_assets(scenario, log_points, config)
        background = build_background(log_points.background, log_points.depths, beam_rows, config)
        # The static points (~0.5 GB on a KITTI log) are done with before the ray casters are built.
        log_points = log_points.actors_only()
        release_freed_memory()
        model = cls(beam_rows, background, assets, config)
        model.assets = estimate_optics(model, scenario, log_points)
        return model

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
            caster = SurfaceCaster.lean(self.assets[actor_id].surface)
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
        changes = actor_changes(
            sweep, original_tracks, perturbed_tracks, set(moved), self.assets, self.config, self.background.ground
        )
        if not changes:
            return sweep.points.copy(), ResimStats()
        return rewrite_sweep(self, sweep, changes, perturbed_tracks, rng)

    def cast_actor(
        self, actor_id: str, origins: FloatArray, directions: FloatArray, pose: FloatArray, rng: np.random.Generator
    ) -> RayHits:
        """Where rays stop on an actor's asset at `pose` (T_sensor_box), each crossed surfel letting the ray
        through with its pass probability (glass); misses are inf."""
        asset = self.assets[actor_id]
        caster = self.asset_caster(actor_id)
        passing = asset.pass_probability
        count = directions.shape[0]
        if passing is None or count == 0:
            return caster.cast(origins, directions, pose)
        # The rays in the asset's frame (as SurfaceCaster.cast makes them), cast without its conversions.
        rotation_t = pose[:3, :3].T
        rays = np.concatenate([rotate(origins - pose[:3, 3], rotation_t), rotate(directions, rotation_t)], axis=1)
        first, triangle = caster.cast_first(rays.astype(np.float32))
        ranges = first.astype(np.float64)
        triangles = np.where(triangle == NO_TRIANGLE, -1, triangle.astype(np.int64))
        # Walk each ray through the surfels it crosses: only rays that pass a surfel are cast again,
        # from just beyond it (which also skips the twin triangle of the same surfel).
        active = np.arange(count)
        for _ in range(_MAX_PASSES):
            surfel = np.maximum(triangles[active], 0) >> 1
            passes = np.isfinite(ranges[active]) & (rng.random(active.shape[0]) < passing[surfel])
            if not passes.any():
                break
            active = active[passes]
            start = ranges[active] + _PASS_STEP  # where the next cast begins along the ray [m]
            restart = rays[active]
            restart[:, :3] += restart[:, 3:] * start[:, None]
            further, triangle = caster.cast_first(restart.astype(np.float32))
            found = np.isfinite(further)
            ranges[active] = np.where(found, start + further, np.inf)
            triangles[active] = np.where(found, triangle.astype(np.int64), -1)
            active = active[found]
        hit = triangles >= 0
        intensity = np.zeros(count)
        intensity[hit] = caster.intensity[triangles[hit]]
        return RayHits(ranges=ranges, intensity=intensity, source=np.where(hit, 0, -1), triangles=triangles)


__all__ = [
    "ActorResimStats",
    "ResimError",
    "ResimModel",
    "ResimStats",
    "SweepGeometry",
    "collect_log_points",
    "scenario_digest",
]
