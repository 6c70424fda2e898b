"""Ground removal: crop to the metric range, estimate the ground height per coarse cell, split the points.

The ground height of a cell is its lowest return; cells without returns take the nearest
cell's value, and a cell that differs from the median of its 3x3 neighbourhood by more
than ``ground_outlier`` takes that median (a return below the road, or a cell entirely
under a vehicle). Works on sloped roads, unlike a single plane.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from advsim_ros.stacks.modular.config import GroundConfig

Float32Array = npt.NDArray[np.float32]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True, eq=False)
class GroundSplit:
    """The cropped sweep in the ego frame, each point's height above the local ground."""

    xyz: Float32Array  # (N, 3) points inside the range, ego frame [m]
    height: Float32Array  # (N,) height above the estimated ground [m]
    is_ground: BoolArray  # (N,) ground returns
    is_object: BoolArray  # (N,) returns between the ground tolerance and the maximum object height
    grid_origin: tuple[float, float]  # x, y of the ground grid's outer corner [m]
    cell_size: float  # ground grid cell edge [m]
    ground_heights: Float32Array  # (rows along y, columns along x) ground height per cell [m]

    def ground_height_at(self, x: npt.ArrayLike, y: npt.ArrayLike) -> Float32Array:
        """Ground height [m] under ego-frame positions (clamped to the grid's border cells)."""
        rows, columns = self.ground_heights.shape
        column = np.clip(((np.asarray(x) - self.grid_origin[0]) / self.cell_size).astype(np.int64), 0, columns - 1)
        row = np.clip(((np.asarray(y) - self.grid_origin[1]) / self.cell_size).astype(np.int64), 0, rows - 1)
        result: Float32Array = self.ground_heights[row, column]
        return result


def crop_points(xyz: npt.NDArray[np.floating], config: GroundConfig) -> Float32Array:
    """Points (ego frame) inside the configured x, y, z range and off the ego vehicle, as float32."""
    points = np.asarray(xyz, dtype=np.float32)
    # Contiguous copies of the columns: ten comparisons on strided views cost more than the copies.
    x, y, z = (np.ascontiguousarray(points[:, axis]) for axis in range(3))
    keep = (x >= config.range_x[0]) & (x < config.range_x[1])
    keep &= (y >= config.range_y[0]) & (y < config.range_y[1])
    keep &= (z >= config.range_z[0]) & (z < config.range_z[1])
    x_low, x_high, y_low, y_high = config.self_filter
    keep &= ~((x > x_low) & (x < x_high) & (y > y_low) & (y < y_high))  # returns off the ego vehicle itself
    # take() of the kept rows: boolean indexing of an (N, 3) array is several times slower.
    result: Float32Array = points.take(np.flatnonzero(keep), axis=0)
    return result


def split_ground(xyz_ego: npt.NDArray[np.floating], config: GroundConfig) -> GroundSplit:
    """Crop the points (ego frame) and split them into ground and object returns."""
    xyz = crop_points(xyz_ego, config)
    cell = config.cell_size
    x_min, y_min = config.range_x[0], config.range_y[0]
    columns = int(np.ceil((config.range_x[1] - x_min) / cell))
    rows = int(np.ceil((config.range_y[1] - y_min) / cell))
    column = np.minimum(((xyz[:, 0] - x_min) / cell).astype(np.int64), columns - 1)
    row = np.minimum(((xyz[:, 1] - y_min) / cell).astype(np.int64), rows - 1)
    flat = row * columns + column
    lowest = np.full(rows * columns, np.inf, dtype=np.float32)
    np.minimum.at(lowest, flat, xyz[:, 2])
    grid = lowest.reshape(rows, columns)
    observed = np.isfinite(grid)
    if not observed.any():
        grid = np.zeros_like(grid)
    elif not observed.all():
        nearest = ndimage.distance_transform_edt(~observed, return_distances=False, return_indices=True)
        grid = grid[nearest[0], nearest[1]]
    median = ndimage.median_filter(grid, size=3, mode="nearest")
    grid = np.where(np.abs(grid - median) > config.ground_outlier, median, grid).astype(np.float32)
    height = (xyz[:, 2] - grid.ravel()[flat]).astype(np.float32)
    is_ground = height < config.ground_tolerance
    is_object = ~is_ground & (height <= config.max_object_height)
    return GroundSplit(
        xyz=xyz,
        height=height,
        is_ground=is_ground,
        is_object=is_object,
        grid_origin=(x_min, y_min),
        cell_size=cell,
        ground_heights=grid,
    )
