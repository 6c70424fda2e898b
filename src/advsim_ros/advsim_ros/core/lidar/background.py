"""The static scene of a log: surfels of every sweep with the actors cut out, and a ground grid.

Built once per log from its own sweeps (aggregated in the world frame, see
``log_points.collect_log_points``): the ground under actors that never moved (parked cars)
was never seen, so every ground cell near seen ground gets a flat surfel at its ground
height (the height of the nearest seen ground where unseen). The ground grid also gives the
ground height under a moved actor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from advsim_ros.core.lidar.boxes import BoolArray
from advsim_ros.core.lidar.config import ResimConfig
from advsim_ros.core.lidar.sensor import BeamRows, azimuth_columns, rotate, spherical
from advsim_ros.core.lidar.surfels import PointSamples, SurfelCloud, surfels_from_samples
from advsim_ros.core.types import FloatArray, IntArray, ScenarioError, SensorModel

_GROUND_QUANTILE = 0.2  # ground height of a cell: this quantile of its ground candidates' heights
_CARVE_GAP = 0.3  # a return must lie this much beyond a surfel to show that the sensor saw through it [m]
_CARVE_RELATIVE_GAP = 0.02  # ... plus this share of the surfel's range (range noise and beam width grow with it)
_CARVE_MIN_VOTES = 2  # sweeps that must see through a surfel before it counts as moved
_GROUND_BAND = 0.05  # ground candidates this close to a cell's low level make up its ground [m]


@dataclass(frozen=True, eq=False)
class GroundGrid:
    """Ground height on a regular grid in the world xy plane."""

    origin: FloatArray  # (2,) world x, y of the corner of cell (0, 0) [m]
    cell_size: float  # [m]
    heights: FloatArray  # (H, W) ground height [m]; nan where unknown (row = y index, column = x index)

    def __post_init__(self) -> None:
        if self.cell_size <= 0:
            raise ScenarioError("GroundGrid cell_size: must be positive")
        object.__setattr__(self, "origin", np.asarray(self.origin, dtype=np.float64).reshape(2))
        object.__setattr__(self, "heights", np.asarray(self.heights, dtype=np.float64).reshape(self.heights.shape))

    def height_at(self, xy: FloatArray) -> FloatArray:
        """(N,) ground height [m] under world points xy (N, 2); nan outside the grid or where unknown."""
        cells = np.floor((np.asarray(xy, dtype=np.float64).reshape(-1, 2) - self.origin) / self.cell_size)
        column, row = cells[:, 0].astype(np.int64), cells[:, 1].astype(np.int64)
        rows, columns = self.heights.shape
        valid = (row >= 0) & (row < rows) & (column >= 0) & (column < columns)
        result = np.full(xy.reshape(-1, 2).shape[0], np.nan)
        result[valid] = self.heights[row[valid], column[valid]]
        return result


@dataclass(frozen=True, eq=False)
class BackgroundModel:
    """Surfels of the static scene in the world frame plus its ground grid."""

    surfels: SurfelCloud  # world frame; the ground fill is included
    ground: GroundGrid
    fill_count: int  # surfels added to fill ground holes

    def to_arrays(self) -> dict[str, np.ndarray]:
        arrays = self.surfels.to_arrays("background/")
        arrays["ground/origin"] = self.ground.origin
        arrays["ground/cell_size"] = np.array(self.ground.cell_size)
        arrays["ground/heights"] = self.ground.heights
        arrays["background/fill_count"] = np.array(self.fill_count)
        return arrays

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> BackgroundModel:
        return cls(
            surfels=SurfelCloud.from_arrays(arrays, "background/"),
            ground=GroundGrid(
                origin=arrays["ground/origin"],
                cell_size=float(arrays["ground/cell_size"]),
                heights=arrays["ground/heights"],
            ),
            fill_count=int(arrays["background/fill_count"]),
        )


def _ground_grid(surfels: SurfelCloud, config: ResimConfig) -> tuple[GroundGrid, FloatArray]:
    """The ground grid and each cell's mean ground intensity."""
    cell = config.ground_cell
    centers = surfels.centers.astype(np.float64)
    low = np.floor(centers[:, :2].min(axis=0) / cell) * cell - config.ground_fill_radius
    high = centers[:, :2].max(axis=0) + config.ground_fill_radius
    shape = (int(np.ceil((high[1] - low[1]) / cell)) + 1, int(np.ceil((high[0] - low[0]) / cell)) + 1)
    candidates = np.abs(surfels.normals[:, 2]) >= config.ground_normal_min_z
    cells = np.floor((centers[candidates, :2] - low) / cell).astype(np.int64)
    flat = cells[:, 1] * shape[1] + cells[:, 0]
    heights_in = centers[candidates, 2]
    order = np.lexsort((heights_in, flat))
    flat_sorted, heights_sorted = flat[order], heights_in[order]
    unique, starts, counts = np.unique(flat_sorted, return_index=True, return_counts=True)
    picks = starts + np.floor(_GROUND_QUANTILE * (counts - 1)).astype(np.int64)
    level = np.full(shape[0] * shape[1], np.nan)
    level[unique] = heights_sorted[picks]
    # The cell's ground: candidates near its low level (not a low roof, a bench or the top of a curb).
    near_ground = np.abs(heights_in - level[flat]) <= _GROUND_BAND
    total = shape[0] * shape[1]
    count = np.bincount(flat[near_ground], minlength=total)
    height_sum = np.bincount(flat[near_ground], weights=heights_in[near_ground], minlength=total)
    heights = np.divide(height_sum, count, out=np.full(total, np.nan), where=count > 0)
    intensity_sum = np.bincount(flat[near_ground], weights=surfels.intensity[candidates][near_ground], minlength=total)
    intensity = np.divide(intensity_sum, count, out=np.full(total, np.nan), where=count > 0)
    return GroundGrid(origin=low, cell_size=cell, heights=heights.reshape(shape)), intensity.reshape(shape)


def _fill_ground(grid: GroundGrid, intensity: FloatArray, config: ResimConfig) -> tuple[GroundGrid, SurfelCloud]:
    """Heights for unseen cells near seen ground, and a flat surfel over every cell near seen ground.

    The flat surfels close the gaps that sparse or grazing returns leave between ground
    surfels, and the ground under actors that never moved.
    """
    seen = np.isfinite(grid.heights)
    if not np.any(seen):
        return grid, SurfelCloud.empty()
    distance, (near_row, near_column) = ndimage.distance_transform_edt(~seen, return_indices=True)
    reachable = distance * grid.cell_size <= config.ground_fill_radius
    heights = np.where(seen, grid.heights, np.where(reachable, grid.heights[near_row, near_column], np.nan))
    fill_intensity = intensity[near_row, near_column]
    rows, columns = np.nonzero(reachable)
    centers = np.stack(
        [
            grid.origin[0] + (columns + 0.5) * grid.cell_size,
            grid.origin[1] + (rows + 0.5) * grid.cell_size,
            heights[rows, columns],
        ],
        axis=1,
    )
    fill = SurfelCloud(
        centers=centers,
        normals=np.tile([0.0, 0.0, 1.0], (rows.shape[0], 1)),
        half_sizes=np.full(rows.shape[0], 0.5 * grid.cell_size * 1.02),
        intensity=np.nan_to_num(fill_intensity[rows, columns]),
    )
    return GroundGrid(origin=grid.origin, cell_size=grid.cell_size, heights=heights), fill


@dataclass(frozen=True, eq=False)
class SweepDepth:
    """One logged sweep as a range image, to tell static surfels from things that moved away."""

    sensor_pose: FloatArray  # (4, 4) T_world_sensor
    nearest: FloatArray  # (B, A) nearest return per cell [m]; inf where none
    nearest_around: FloatArray  # (B, A) nearest return over the cell and its eight neighbours [m]

    @classmethod
    def of_points(
        cls, sensor_pose: FloatArray, ranges: FloatArray, rows: IntArray, columns: IntArray, sensor: SensorModel
    ) -> SweepDepth:
        nearest = np.full((sensor.num_beams, sensor.num_azimuths), np.inf)
        np.minimum.at(nearest, (rows, columns), ranges)
        around = ndimage.minimum_filter(nearest, size=3, mode=("nearest", "wrap"))
        return cls(sensor_pose=sensor_pose, nearest=nearest, nearest_around=around)


def carve_moving(centers: FloatArray, depths: list[SweepDepth], beam_rows: BeamRows, config: ResimConfig) -> BoolArray:
    """(S,) True for surfels that stayed put: not seen through in more sweeps than seen.

    A surfel is seen through by a sweep when every return around its direction lies
    well beyond it, i.e. the sensor looked past the spot where it sits; things that moved
    (unlabelled cars, actors outside their labels) are seen through from other places
    and times, static surfaces are not.
    """
    sensor = beam_rows.sensor
    free = np.zeros(centers.shape[0], dtype=np.int64)
    seen = np.zeros(centers.shape[0], dtype=np.int64)
    for depth in depths:
        offset = centers - depth.sensor_pose[:3, 3]
        near = np.flatnonzero(np.einsum("ij,ij->i", offset, offset) <= config.carve_range**2)
        local = rotate(offset[near], depth.sensor_pose[:3, :3].T)
        geometry = spherical(local)
        rows = beam_rows.nearest_rows(local)
        inside_beams = (rows > 0) & (rows < sensor.num_beams - 1)  # the outermost beams have no neighbour
        near, rows, geometry_ranges = near[inside_beams], rows[inside_beams], geometry.ranges[inside_beams]
        columns = azimuth_columns(geometry.azimuths[inside_beams], sensor)
        gap = _CARVE_GAP + _CARVE_RELATIVE_GAP * geometry_ranges
        beyond = depth.nearest_around[rows, columns]
        free[near] += (np.isfinite(beyond) & (beyond > geometry_ranges + gap)).astype(np.int64)
        seen[near] += (np.abs(depth.nearest[rows, columns] - geometry_ranges) <= gap).astype(np.int64)
    result: BoolArray = ~((free >= _CARVE_MIN_VOTES) & (free > seen))
    return result


def build_background(
    samples: PointSamples, depths: list[SweepDepth], beam_rows: BeamRows, config: ResimConfig
) -> BackgroundModel:
    """The background model from the log's static points (world frame) and depth images of some of its sweeps."""
    if samples.count < 100:
        raise ScenarioError(f"background: only {samples.count} static points in the log; need at least 100")
    surfels = surfels_from_samples(
        samples, config.background_voxel, config.surfel_size_scale, config.background_max_half_size
    )
    if depths:
        keep = carve_moving(surfels.centers.astype(np.float64), depths, beam_rows, config)
        surfels = SurfelCloud(
            centers=surfels.centers[keep],
            normals=surfels.normals[keep],
            half_sizes=surfels.half_sizes[keep],
            intensity=surfels.intensity[keep],
        )
    grid, ground_intensity = _ground_grid(surfels, config)
    grid, fill = _fill_ground(grid, ground_intensity, config)
    return BackgroundModel(surfels=SurfelCloud.concatenate([surfels, fill]), ground=grid, fill_count=fill.count)
