"""Where vehicles may drive: a boolean raster in the world frame, from a map or estimated from the log.

With a vector map (Argoverse 2) the raster is the union of the map's drivable-area polygons.
Without one (KITTI) it is estimated from the log itself (see docs/behaviour.md):

1. driven area: every footprint of the ego and of every vehicle or cyclist track over the
   whole log (they drove or stood there, so it is road, parking lane or driveway);
2. road surface from LiDAR: a ground-height grid (lowest return per cell over a subset of
   sweeps) is grown outwards from the driven area into neighbouring cells whose height is
   continuous (steps below ``max_step``, so a kerb stops the growth), at most ``max_growth``
   metres out;
3. a morphological closing fills gaps narrower than ``closing`` metres between the two.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import shapely
from scipy import ndimage

from advsim_ros.core.geometry import box_corners
from advsim_ros.core.types import SOURCE_LOG, SOURCE_MAP, ActorClass, DrivableArea, RoadMap, Scenario, ScenarioError

AnyFloatArray = npt.NDArray[np.floating[Any]]
FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

DRIVING_CLASSES = (ActorClass.VEHICLE, ActorClass.CYCLIST)


@dataclass(frozen=True)
class DrivableConfig:
    """How the drivable raster is built (params/drivable.yaml, one setting for every node)."""

    resolution: float = 0.25  # raster cell edge [m]
    reach: float = 110.0  # raster extends this far beyond every logged position [m]
    ground_cell: float = 0.5  # cell edge of the LiDAR ground-height grid [m]
    max_step: float = 0.06  # largest height step between neighbouring road cells [m]; kerbs are ~0.1-0.15 m
    max_growth: float = 6.0  # road surface grows at most this far out of the driven area [m]
    max_sweeps: int = 20  # LiDAR sweeps used for the ground grid, spread evenly over the log
    max_point_range: float = 40.0  # LiDAR returns farther than this from the sensor are ignored [m]
    closing: float = 1.0  # gaps narrower than this between driven and grown areas are filled [m]

    def __post_init__(self) -> None:
        if float(np.float32(self.resolution)) != self.resolution:
            raise ScenarioError(
                f"DrivableConfig resolution: {self.resolution} m is not exact in float32 (the raster travels as "
                "nav_msgs/OccupancyGrid); use e.g. 0.125, 0.25 or 0.5"
            )
        for name in ("resolution", "reach", "ground_cell", "max_step", "max_point_range"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ScenarioError(f"DrivableConfig {name}: must be positive, got {value!r}")
        for name in ("max_growth", "closing"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ScenarioError(f"DrivableConfig {name}: must be >= 0, got {value!r}")
        if self.max_sweeps < 0:
            raise ScenarioError(f"DrivableConfig max_sweeps: must be >= 0, got {self.max_sweeps}")


def scenario_extent(scenario: Scenario, reach: float) -> tuple[float, float, float, float]:
    """(x_min, y_min, x_max, y_max) [m] around every ego and actor position, grown by reach [m]."""
    points = [scenario.ego.xy] + [actor.centers[:, :2] for actor in scenario.actors]
    stacked = np.concatenate(points, axis=0)
    low = stacked.min(axis=0) - reach
    high = stacked.max(axis=0) + reach
    return float(low[0]), float(low[1]), float(high[0]), float(high[1])


def _empty_grid(extent: tuple[float, float, float, float], resolution: float) -> tuple[FloatArray, tuple[int, int]]:
    x_min, y_min, x_max, y_max = extent
    width = max(1, int(np.ceil((x_max - x_min) / resolution)))
    height = max(1, int(np.ceil((y_max - y_min) / resolution)))
    return np.array([x_min, y_min]), (height, width)


def drivable_area_from_map(
    road_map: RoadMap, extent: tuple[float, float, float, float], resolution: float
) -> DrivableArea:
    """Rasterise the map's drivable-area polygons (cell centre inside any polygon) over extent [m]."""
    if not road_map.drivable_areas:
        raise ScenarioError("drivable_area_from_map: the road map has no drivable-area polygons")
    origin, shape = _empty_grid(extent, resolution)
    area = DrivableArea(origin, resolution, np.zeros(shape, dtype=bool), SOURCE_MAP)
    union = shapely.union_all([shapely.Polygon(outline).buffer(0) for outline in road_map.drivable_areas])
    shapely.prepare(union)
    grid_x, grid_y = area.cell_centers()
    mask = shapely.contains_xy(union, grid_x.ravel(), grid_y.ravel()).reshape(shape)
    return DrivableArea(origin, resolution, mask, SOURCE_MAP)


def rasterize_boxes(mask: BoolArray, origin: FloatArray, resolution: float, boxes: AnyFloatArray) -> None:
    """Set the cells of mask (H, W) whose centre lies inside any of boxes (B, 5) [x, y, yaw, length, width]."""
    height, width = mask.shape
    for box in np.asarray(boxes, dtype=np.float64):
        corners = box_corners(box)
        low = np.floor((corners.min(axis=0) - origin) / resolution).astype(int)
        high = np.ceil((corners.max(axis=0) - origin) / resolution).astype(int)
        col_lo, row_lo = max(low[0], 0), max(low[1], 0)
        col_hi, row_hi = min(high[0], width), min(high[1], height)
        if col_lo >= col_hi or row_lo >= row_hi:
            continue
        xs = origin[0] + (np.arange(col_lo, col_hi) + 0.5) * resolution - box[0]
        ys = origin[1] + (np.arange(row_lo, row_hi) + 0.5) * resolution - box[1]
        cos, sin = np.cos(box[2]), np.sin(box[2])
        along = xs[None, :] * cos + ys[:, None] * sin
        across = -xs[None, :] * sin + ys[:, None] * cos
        inside = (np.abs(along) <= box[3] / 2) & (np.abs(across) <= box[4] / 2)
        mask[row_lo:row_hi, col_lo:col_hi] |= inside


def driven_boxes(scenario: Scenario) -> FloatArray:
    """(B, 5) footprints of the ego and of every vehicle and cyclist at every logged frame [m, rad]."""
    parts = [scenario.ego_geometry.boxes(scenario.ego.xy, scenario.ego.yaws)]
    for actor in scenario.actors:
        if actor.actor_class not in DRIVING_CLASSES:
            continue
        count = actor.yaws.shape[0]
        parts.append(
            np.column_stack(
                [actor.centers[:, :2], actor.yaws, np.full(count, actor.length), np.full(count, actor.width)]
            )
        )
    return np.concatenate(parts, axis=0)


def ground_height_grid(
    scenario: Scenario, origin: FloatArray, shape: tuple[int, int], cell: float, config: DrivableConfig
) -> FloatArray:
    """(H, W) lowest LiDAR return per cell in the world frame [m]; NaN where no return fell."""
    heights = np.full(shape[0] * shape[1], np.inf)
    sweeps = scenario.sweeps
    if not sweeps or config.max_sweeps == 0:
        return np.full(shape, np.nan)
    picks = np.unique(np.linspace(0, len(sweeps) - 1, min(config.max_sweeps, len(sweeps))).round().astype(int))
    for index in picks:
        sweep = sweeps[int(index)]
        xyz = sweep.xyz
        near = np.hypot(xyz[:, 0], xyz[:, 1]) <= config.max_point_range
        world = xyz[near] @ sweep.sensor_pose[:3, :3].T + sweep.sensor_pose[:3, 3]
        column = np.floor((world[:, 0] - origin[0]) / cell).astype(np.int64)
        row = np.floor((world[:, 1] - origin[1]) / cell).astype(np.int64)
        inside = (column >= 0) & (column < shape[1]) & (row >= 0) & (row < shape[0])
        np.minimum.at(heights, row[inside] * shape[1] + column[inside], world[inside, 2])
    grid = heights.reshape(shape)
    return np.where(np.isfinite(grid), grid, np.nan)


def _grow_road_surface(seed: BoolArray, heights: FloatArray, max_step: float, iterations: int) -> BoolArray:
    """Cells reachable from seed through 4-neighbours with |height step| <= max_step (heights NaN: unknown)."""
    known = np.isfinite(heights)
    if not np.any(known & seed):
        return seed.copy()
    # Seed cells under parked cars see no ground: give them the nearest known height.
    nearest = ndimage.distance_transform_edt(~known, return_distances=False, return_indices=True)
    filled = heights[tuple(nearest)]
    region = seed.copy()
    for _ in range(iterations):
        grown = region.copy()
        for axis, shift in ((0, 1), (0, -1), (1, 1), (1, -1)):
            neighbour_in = np.roll(region, shift, axis=axis)
            neighbour_height = np.roll(filled, shift, axis=axis)
            # np.roll wraps around; the wrapped border row/column must not count as a neighbour.
            edge = [slice(None), slice(None)]
            edge[axis] = slice(0, 1) if shift == 1 else slice(-1, None)
            neighbour_in[tuple(edge)] = False
            grown |= neighbour_in & known & (np.abs(heights - neighbour_height) <= max_step)
        if np.array_equal(grown, region):
            break
        region = grown
        filled = np.where(region & known, heights, filled)
    return region


def _disk(radius_cells: int) -> BoolArray:
    offsets = np.arange(-radius_cells, radius_cells + 1)
    result: BoolArray = offsets[None, :] ** 2 + offsets[:, None] ** 2 <= radius_cells**2
    return result


def estimate_drivable_area(
    scenario: Scenario, config: DrivableConfig, extent: tuple[float, float, float, float]
) -> DrivableArea:
    """Drivable area of a log without a map: driven footprints, grown over LiDAR ground, then closed."""
    origin, shape = _empty_grid(extent, config.resolution)
    driven = np.zeros(shape, dtype=bool)
    rasterize_boxes(driven, origin, config.resolution, driven_boxes(scenario))
    mask = driven
    if scenario.sweeps and config.max_growth > 0 and config.max_sweeps > 0:
        factor = max(1, round(config.ground_cell / config.resolution))
        coarse_shape = (-(-shape[0] // factor), -(-shape[1] // factor))
        coarse_cell = config.resolution * factor
        heights = ground_height_grid(scenario, origin, coarse_shape, coarse_cell, config)
        padded = np.zeros((coarse_shape[0] * factor, coarse_shape[1] * factor), dtype=bool)
        padded[: shape[0], : shape[1]] = driven
        coarse_seed: BoolArray = np.asarray(
            padded.reshape(coarse_shape[0], factor, coarse_shape[1], factor).any(axis=(1, 3))
        )
        iterations = int(np.ceil(config.max_growth / coarse_cell))
        grown = _grow_road_surface(coarse_seed, heights, config.max_step, iterations)
        mask = driven | np.repeat(np.repeat(grown, factor, axis=0), factor, axis=1)[: shape[0], : shape[1]]
    radius = round(config.closing / (2 * config.resolution))
    if radius > 0:
        mask = ndimage.binary_closing(mask, structure=_disk(radius), border_value=0) | mask
    return DrivableArea(origin, config.resolution, np.asarray(mask, dtype=bool), SOURCE_LOG)


def drivable_area_for(scenario: Scenario, config: DrivableConfig) -> DrivableArea:
    """The scenario's stored drivable area, else its map's, else the estimate from the log."""
    if scenario.drivable_area is not None:
        return scenario.drivable_area
    extent = scenario_extent(scenario, config.reach)
    if scenario.road_map is not None and scenario.road_map.drivable_areas:
        return drivable_area_from_map(scenario.road_map, extent, config.resolution)
    return estimate_drivable_area(scenario, config, extent)
