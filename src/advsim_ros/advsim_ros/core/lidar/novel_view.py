"""A full sweep rendered from a log's re-simulation model for any sensor pose (the closed loop's sensor).

The re-simulation (``resim``) rewrites a *logged* sweep and so needs the ego where it was;
in closed loop the ego drives elsewhere and every sweep is rendered from the model instead:
every ray of the log's sensor model (its beams with their origin heights, its azimuth step)
is cast from the ego's actual sensor pose against

- the background: the static scene's surfels, the ground-grid fill included (the fill
  surfels, flat squares over every ground cell near seen ground, are the ground grid made
  castable), and
- the actor assets, at their (perturbed or logged) poses, each cast only with the rays of
  its box's angular footprint; glass surfels let rays through as in ``ResimModel.cast_actor``.

Each ray keeps its nearest hit. Then the log's sensor effects: an actor hit returns nothing
with its asset's ray-drop probability, a background hit with its beam's drop probability,
background ranges get their beam's bias back, and ranges get Gaussian noise; all three are
estimated from the log by ``calibrate_rendering`` (render at the logged poses, compare with
the logged sweeps). The points come out in the logged
sweeps' own fields (x, y, z, intensity, ring where the log has them; other fields zero), beam
after beam, each beam one counter-clockwise turn from the log's scan start, like the log.

The per-model part (the grid of rays, the background caster the model built) is made once
and kept with the model (``renderer_for``), so a sweep costs its ray casts only. The
background is cast in tiles of 8 beams x 32 azimuth steps (neighbouring rays meet the same
part of the scene: ~30 % faster in Embree than beam after beam), and nothing on a sweep's
path goes through BLAS (its threads stall on a busy machine).
"""

from __future__ import annotations

import weakref
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from advsim_ros.core.lidar.boxes import AngularWindow, BoolArray, Region, invert_rigid, rays_hit_region, track_pose_at
from advsim_ros.core.lidar.errors import ResimError
from advsim_ros.core.lidar.resim import ResimModel
from advsim_ros.core.lidar.sensor import RING_FIELD, azimuth_columns, rotate, spherical, xyz_of
from advsim_ros.core.types import ActorTrack, FloatArray, IntArray, Scenario

# What a ray ended on (RenderedRays.kind).
MISS, BACKGROUND, GROUND_FILL, ACTOR = 0, 1, 2, 3

CALIBRATION_FRAMES = 6  # logged sweeps spread over the log that the ray drop and noise are estimated from
_CALIBRATION_SEED = 20210602  # the calibration's own random stream (the same model calibrates the same way)
_NOISE_BAND = 0.3  # residuals beyond this are model error (a missing surfel), not sensor noise [m]
_BIAS_BAND = 0.5  # residuals beyond this are left out of a beam's range bias [m]
_NOISE_MIN_COSINE = 0.7  # the noise is measured on rays meeting the background within ~45 deg of its normal
_MAX_NOISE = 0.05  # cap on the estimated range noise [m]
_WINDOW_MARGIN = 0.01  # growth of an actor's angular window [rad]
_BOX_MARGIN = 0.05  # growth of an actor's box when selecting the rays that may hit its asset [m]


@dataclass(frozen=True, eq=False)
class RenderCalibration:
    """The sensor effects a rendered sweep gets, estimated from the log."""

    background_drop: FloatArray  # (B,) chance that a ray of each beam hitting the background returns nothing
    range_noise_std: float  # Gaussian range noise of every return [m]
    background_bias: FloatArray  # (B,) added to the range of each beam's background hits [m]

    @staticmethod
    def none(num_beams: int) -> RenderCalibration:
        """No ray drop on the background, no noise, no bias (actors keep their assets' drop)."""
        return RenderCalibration(np.zeros(num_beams), 0.0, np.zeros(num_beams))


@dataclass(frozen=True, eq=False)
class RenderedRays:
    """Every ray of one rendered sweep, in range-image order (row-major), before and after the sensor effects."""

    ranges: FloatArray  # (R,) distance from the beam's origin to the nearest hit [m] (noise added); inf: none
    intensity: FloatArray  # (R,)
    kind: IntArray  # (R,) MISS, BACKGROUND, GROUND_FILL or ACTOR
    actor: IntArray  # (R,) index into actor_ids of the actor hit; -1 otherwise
    surfel: IntArray  # (R,) index of the background surfel hit (the model's surfels, fill included); -1 otherwise
    returned: BoolArray  # (R,) the ray gives a point (in range and not dropped)
    actor_ids: tuple[str, ...]  # the actors placed, sorted

    def cell_ranges(self) -> FloatArray:
        """(R,) the range of every cell's return; inf where the ray returns nothing."""
        result: FloatArray = np.where(self.returned, self.ranges, np.inf)
        return result


class ModelRenderer:
    """A model made ready to render full sweeps: its grid of rays and its casters."""

    def __init__(self, model: ResimModel) -> None:
        # A weak reference: renderer_for keeps renderers in a dict weakly keyed by their model.
        self._model = weakref.ref(model)
        sensor = model.sensor
        rows = np.repeat(np.arange(sensor.num_beams, dtype=np.int64), sensor.num_azimuths)
        columns = np.tile(np.arange(sensor.num_azimuths, dtype=np.int64), sensor.num_beams)
        self.rows, self.columns = rows, columns
        origins, directions = model.beam_rows.cell_rays(rows, columns)
        if np.any(origins[:, :2] != 0.0):
            raise ResimError("render: the beams' origins must lie on the sensor's z axis")
        self.origins: FloatArray = origins
        self.directions: FloatArray = directions
        # The background is cast in small tiles of neighbouring rays (beams x azimuth steps): a batch
        # of rays then meets the same part of the scene, ~30 % faster in Embree than beam after beam.
        cast_order = _tile_order(sensor.num_beams, sensor.num_azimuths)
        self._cast_inverse = np.argsort(cast_order)
        self._cast_heights = origins[cast_order, 2].astype(np.float32)
        self._cast_directions = np.ascontiguousarray(directions[cast_order].T, dtype=np.float32)  # (3, R)
        surfels = model.background.surfels
        # Surfels become two triangles each; the ground fill was appended last.
        self.fill_triangles = 2 * (surfels.count - model.background.fill_count)
        # What a hit on each background triangle returns; the last entry stands for no hit.
        triangle_intensity = model.background_caster.intensity
        self._no_triangle = triangle_intensity.shape[0]
        self._triangle_intensity = np.append(triangle_intensity, 0.0).astype(np.float64)
        self.beam_height = float(np.max(np.abs(model.beam_rows.beam_heights)))
        self.order = self._scan_order()
        self.row_labels = self._row_labels()
        # The rays in firing order, for the points: beam origin heights and direction components.
        self._fired_heights = origins[self.order, 2]
        self._fired_directions = np.ascontiguousarray(directions[self.order].T)  # (3, R)
        self._fired_labels = self.row_labels[rows[self.order]]
        self._calibrations: dict[str, RenderCalibration] = {}

    @property
    def model(self) -> ResimModel:
        model = self._model()
        if model is None:
            raise ResimError("render: the model of this renderer is gone")
        return model

    def _row_labels(self) -> IntArray:
        """(B,) the ring value (or scan-order segment) the log gives each row; the row itself where none."""
        beam_rows = self.model.beam_rows
        labels = np.arange(self.model.sensor.num_beams, dtype=np.int64)
        seen = beam_rows.ring_to_row >= 0
        labels[beam_rows.ring_to_row[seen]] = np.flatnonzero(seen)
        return labels

    def _scan_order(self) -> IntArray:
        """Cells in the log's firing order: by ring label, each a counter-clockwise turn from the scan start."""
        sensor = self.model.sensor
        labels = self._row_labels()
        start_column = int(azimuth_columns(np.array([self.model.beam_rows.scan_start]), sensor)[0])
        turn = np.mod(self.columns - start_column, sensor.num_azimuths)
        order: IntArray = np.lexsort((turn, labels[self.rows]))
        return order

    # ----- casting ------------------------------------------------------------------------

    def cast(
        self,
        sensor_pose: FloatArray,
        actor_poses: Mapping[str, FloatArray],
        rng: np.random.Generator,
        calibration: RenderCalibration,
    ) -> RenderedRays:
        """Every ray from `sensor_pose` (T_world_sensor) with actors at `actor_poses` (T_world_box)."""
        model = self.model
        unknown = sorted(set(actor_poses) - set(model.assets))
        if unknown:
            raise ResimError(f"render: no asset for actors {unknown} (only actors of the log can be rendered)")
        sensor_T_world = invert_rigid(sensor_pose)
        ranges, intensity, kind, surfel = self._cast_background(sensor_pose)
        actor = np.full(ranges.shape[0], -1, dtype=np.int64)
        actor_ids = tuple(sorted(actor_poses))
        for index, actor_id in enumerate(actor_ids):
            pose = sensor_T_world @ actor_poses[actor_id]
            cells = self._actor_cells(pose, model.assets[actor_id].size)
            if cells.size == 0:
                continue
            found = model.cast_actor(actor_id, self.origins[cells], self.directions[cells], pose, rng)
            nearer = found.ranges < ranges[cells]
            chosen = cells[nearer]
            ranges[chosen] = found.ranges[nearer]
            intensity[chosen] = found.intensity[nearer]
            kind[chosen] = ACTOR
            actor[chosen] = index
            surfel[chosen] = -1
        # Per beam (rows of the range image): the bias and drop of background hits.
        image = (self.model.sensor.num_beams, -1)
        background = ((kind == BACKGROUND) | (kind == GROUND_FILL)).reshape(image)
        ranges.reshape(image)[...] += np.where(background, calibration.background_bias[:, None], 0.0)
        if calibration.range_noise_std > 0:
            ranges += rng.normal(0.0, calibration.range_noise_std, ranges.shape[0])
        sensor = model.sensor
        returned = np.isfinite(ranges) & (ranges >= sensor.min_range) & (ranges <= sensor.max_range)
        chance = np.where(background, calibration.background_drop[:, None], 0.0).reshape(-1)
        on_actor = np.flatnonzero(actor >= 0)
        drops = np.array([model.assets[actor_id].drop_probability for actor_id in actor_ids] + [0.0])
        chance[on_actor] = drops[actor[on_actor]]
        returned &= rng.random(ranges.shape[0]) >= chance
        return RenderedRays(ranges, intensity, kind, actor, surfel, returned, actor_ids)

    def _cast_background(self, sensor_pose: FloatArray) -> tuple[FloatArray, FloatArray, IntArray, IntArray]:
        """(R,) range (inf: no hit), intensity, kind (MISS, BACKGROUND, GROUND_FILL) and surfel (-1: none)
        of every ray on the background, in range-image order."""
        t_hit, triangle = self.model.background_caster.cast_first(self._world_rays(sensor_pose))
        # Back from the cast order to range-image order.
        ranges = t_hit[self._cast_inverse].astype(np.float64)
        triangles = np.minimum(triangle[self._cast_inverse], self._no_triangle).astype(np.int64)
        intensity: FloatArray = self._triangle_intensity[triangles]
        hit = triangles < self._no_triangle
        surface = np.where(triangles >= self.fill_triangles, GROUND_FILL, BACKGROUND)
        kind: IntArray = np.where(hit, surface, MISS)
        surfel: IntArray = np.where(hit, triangles // 2, -1)
        return ranges, intensity, kind, surfel

    def _world_rays(self, sensor_pose: FloatArray) -> npt.NDArray[np.float32]:
        """(R, 6) float32 origins and directions of every ray in the world frame, in the cast order.

        Written out per component rather than as a matrix product: on a busy machine BLAS's
        threads stall on (R, 3) x (3, 3) products (60 ms instead of 2).
        """
        rotation = sensor_pose[:3, :3].astype(np.float32)
        translation = sensor_pose[:3, 3].astype(np.float32)
        directions = self._cast_directions
        rays = np.empty((directions.shape[1], 6), dtype=np.float32)
        column = np.empty(directions.shape[1], dtype=np.float32)
        for axis in range(3):
            # The beams' origins lie on the sensor's z axis.
            np.multiply(self._cast_heights, rotation[axis, 2], out=column)
            column += translation[axis]
            rays[:, axis] = column
            np.multiply(directions[0], rotation[axis, 0], out=column)
            column += directions[1] * rotation[axis, 1]
            column += directions[2] * rotation[axis, 2]
            rays[:, 3 + axis] = column
        return rays

    def _actor_cells(self, pose: FloatArray, size: FloatArray) -> IntArray:
        """Cells whose ray crosses the actor's (slightly grown) box at `pose` (T_sensor_box)."""
        half = 0.5 * np.asarray(size, dtype=np.float64) + _BOX_MARGIN
        box = Region(lower=-half, upper=half)
        # The window is seen from the sensor origin; grow it by the beams' origin heights.
        lift = np.array([0.0, 0.0, self.beam_height])
        tall = Region(lower=box.lower - lift, upper=box.upper + lift)
        window = AngularWindow.of_region(pose, tall, _WINDOW_MARGIN)
        sensor = self.model.sensor
        rows, columns = window.rows(sensor), window.columns(sensor)
        if rows.size == 0 or columns.size == 0:
            return np.zeros(0, dtype=np.int64)
        cells = (rows[:, None] * sensor.num_azimuths + columns[None, :]).reshape(-1)
        through = rays_hit_region(self.origins[cells], self.directions[cells], pose, box)
        selected: IntArray = cells[through]
        return selected

    # ----- points -------------------------------------------------------------------------

    def points(self, rays: RenderedRays, dtype: np.dtype) -> np.ndarray:
        """The returned rays as points of `dtype` (sensor frame), in the log's firing order."""
        fired = rays.returned[self.order]
        chosen = self.order[fired]
        ranges = rays.ranges[chosen]
        points = np.zeros(chosen.shape[0], dtype=dtype)
        # The beams' origins lie on the sensor's z axis.
        points["x"] = self._fired_directions[0][fired] * ranges
        points["y"] = self._fired_directions[1][fired] * ranges
        points["z"] = self._fired_heights[fired] + self._fired_directions[2][fired] * ranges
        names = dtype.names or ()
        if "intensity" in names:
            points["intensity"] = rays.intensity[chosen]
        if RING_FIELD in names:
            points[RING_FIELD] = self._fired_labels[fired]
        return points

    # ----- calibration --------------------------------------------------------------------

    def calibration(self, scenario: Scenario) -> RenderCalibration:
        """The log's ray drop and noise for this model (estimated once per scenario)."""
        cached = self._calibrations.get(scenario.scenario_id)
        if cached is None:
            cached = calibrate_rendering(self, scenario)
            self._calibrations[scenario.scenario_id] = cached
        return cached

    def cell_ranges(self, points: np.ndarray) -> FloatArray:
        """(R,) a logged sweep as this grid's cells: the nearest return per cell from its beam's origin; inf: none."""
        xyz = xyz_of(points)
        geometry = spherical(xyz)
        valid = geometry.ranges > 1e-3
        rows = self.model.beam_rows.rows(points, geometry)
        _, _, beam_ranges = self.model.beam_rows.point_rays(xyz, rows)
        offsets = xyz - self.model.beam_rows.origins(rows)
        columns = azimuth_columns(np.arctan2(offsets[:, 1], offsets[:, 0]), self.model.sensor)
        cells = rows * self.model.sensor.num_azimuths + columns
        result = np.full(self.rows.shape[0], np.inf)
        np.minimum.at(result, cells[valid], beam_ranges[valid])
        return result


def calibrate_rendering(
    renderer: ModelRenderer, scenario: Scenario, frames: int = CALIBRATION_FRAMES
) -> RenderCalibration:
    """Per-beam background ray drop and the range noise, from sweeps rendered at their logged poses.

    Rendered without drop or noise, with the actors at their logged poses: a beam's drop is
    1 - (cells where the background was hit and the log has a return) / (cells where the
    background was hit). The noise comes from the range residual logged - rendered over
    cells where both hit the background within 0.3 m and the ray meets the surfel within
    ~45 deg of its normal (at grazing incidence, e.g. far road, a beam's small elevation
    error becomes a large range error that is not noise). That residual is mostly the
    model's own error (surfel layers, the sweep's motion during its turn: ~0.1 m on KITTI),
    which neighbouring rays share; the sensor's noise is not shared, so it is taken from the
    difference of the residuals of azimuth neighbours on one beam: 1.4826 x MAD / sqrt(2)
    (capped at 5 cm). The shared part has a per-beam bias: rays that graze the road meet the
    highest of the overlapping ground surfels first, so the far-reaching beams return ~0.1 m
    short on KITTI; each beam's median residual over its background hits (within 0.5 m) is
    added back to its background ranges.
    """
    sensor = renderer.model.sensor
    picks = np.unique(np.linspace(0, len(scenario.sweeps) - 1, min(frames, len(scenario.sweeps))).round().astype(int))
    hit = np.zeros(sensor.num_beams)
    kept = np.zeros(sensor.num_beams)
    residuals: list[FloatArray] = []
    per_beam: list[list[FloatArray]] = [[] for _ in range(sensor.num_beams)]
    clean = RenderCalibration.none(sensor.num_beams)
    for pick in picks:
        sweep = scenario.sweeps[int(pick)]
        poses = actor_poses_at(scenario.actors, sweep.stamp_ns)
        rays = renderer.cast(sweep.sensor_pose, poses, np.random.default_rng([_CALIBRATION_SEED, int(pick)]), clean)
        logged = renderer.cell_ranges(sweep.points)
        background = ((rays.kind == BACKGROUND) | (rays.kind == GROUND_FILL)) & rays.returned
        hit += np.bincount(renderer.rows[background], minlength=sensor.num_beams)
        kept += np.bincount(renderer.rows[background & np.isfinite(logged)], minlength=sensor.num_beams)
        normals = renderer.model.background.surfels.normals[np.maximum(rays.surfel, 0)]
        directions = rotate(renderer.directions, sweep.sensor_pose[:3, :3])
        facing = np.abs(np.einsum("ij,ij->i", normals, directions)) >= _NOISE_MIN_COSINE
        with np.errstate(invalid="ignore"):
            residual = logged - rays.ranges
            usable = background & np.isfinite(logged) & facing & (np.abs(residual) <= _NOISE_BAND)
            banded = background & np.isfinite(logged) & (np.abs(residual) <= _BIAS_BAND)
        for beam in range(sensor.num_beams):
            per_beam[beam].append(residual[banded & (renderer.rows == beam)])
        image = np.where(usable, residual, np.nan).reshape(sensor.num_beams, sensor.num_azimuths)
        step = (np.roll(image, -1, axis=1) - image).reshape(-1)
        residuals.append(step[np.isfinite(step)])
    drop = np.clip(1.0 - np.divide(kept, hit, out=np.ones(sensor.num_beams), where=hit > 0), 0.0, 1.0)
    steps = np.concatenate(residuals) if residuals else np.zeros(0)
    noise = 1.4826 * float(np.median(np.abs(steps - np.median(steps)))) / np.sqrt(2.0) if steps.size else 0.0
    beams = [np.concatenate(parts) for parts in per_beam]
    bias = np.array([float(np.median(values)) if values.size else 0.0 for values in beams])
    return RenderCalibration(background_drop=drop, range_noise_std=min(noise, _MAX_NOISE), background_bias=bias)


_TILE = (8, 32)  # beams x azimuth steps of a tile of the background cast


def _tile_order(num_beams: int, num_azimuths: int) -> IntArray:
    """(B * A,) the cells (row-major indices) tile after tile, each tile row-major."""
    cells = np.arange(num_beams * num_azimuths, dtype=np.int64).reshape(num_beams, num_azimuths)
    tile_rows, tile_columns = _TILE
    order = [
        cells[top : top + tile_rows, left : left + tile_columns].reshape(-1)
        for top in range(0, num_beams, tile_rows)
        for left in range(0, num_azimuths, tile_columns)
    ]
    result: IntArray = np.concatenate(order)
    return result


_RENDERERS: weakref.WeakKeyDictionary[ResimModel, ModelRenderer] = weakref.WeakKeyDictionary()


def renderer_for(model: ResimModel) -> ModelRenderer:
    """The model's renderer, made on first use and kept as long as the model lives."""
    renderer = _RENDERERS.get(model)
    if renderer is None:
        renderer = ModelRenderer(model)
        _RENDERERS[model] = renderer
    return renderer


def actor_poses_at(tracks: Sequence[ActorTrack], stamp_ns: int) -> dict[str, FloatArray]:
    """T_world_box of every track observed at `stamp_ns`."""
    poses: dict[str, FloatArray] = {}
    for track in tracks:
        pose = track_pose_at(track, stamp_ns)
        if pose is not None:
            poses[track.actor_id] = pose
    return poses


def render_rays(
    model: ResimModel,
    scenario: Scenario,
    sensor_pose: FloatArray,
    actors: Sequence[ActorTrack],
    stamp_ns: int,
    rng: np.random.Generator,
    calibration: RenderCalibration | None = None,
) -> RenderedRays:
    """Every ray of the sweep seen from `sensor_pose`, actors at their poses at `stamp_ns` (see render_from_model)."""
    renderer = renderer_for(model)
    calibration = calibration if calibration is not None else renderer.calibration(scenario)
    return renderer.cast(sensor_pose, actor_poses_at(actors, stamp_ns), rng, calibration)


def render_from_model(
    model: ResimModel,
    scenario: Scenario,
    sensor_pose: FloatArray,
    actors: Sequence[ActorTrack],
    stamp_ns: int,
    rng: np.random.Generator,
    calibration: RenderCalibration | None = None,
) -> np.ndarray:
    """The sweep (the log's point fields, sensor frame) seen from `sensor_pose` (4, 4) T_world_sensor.

    `actors` are the tracks of the world to render (perturbed or logged; every id must be
    a track of the log, whose asset the model holds); those observed at `stamp_ns` are
    placed at their poses then. `calibration` defaults to the log's (``calibrate_rendering``,
    estimated on first use and kept). The same generator state gives the same sweep.
    """
    renderer = renderer_for(model)
    rays = render_rays(model, scenario, sensor_pose, actors, stamp_ns, rng, calibration)
    dtype = (
        scenario.sweeps[0].points.dtype
        if scenario.sweeps
        else np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])
    )
    return renderer.points(rays, dtype)
