"""Static obstacles for the planner: a BEV occupancy grid of the sweep's object returns.

Boxes describe vehicles well but walls, hedges and kerb stones badly, so the planner
checks its rollouts against the occupied cells themselves (through a distance transform)
and against the predicted boxes only for objects that move. Cells of moving objects are
cleared, so that a car driving ahead does not block the road where it is now.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from advsim_ros.core.geometry import box_corners
from advsim_ros.core.types import FloatArray
from advsim_ros.stacks.modular.config import GroundConfig
from advsim_ros.stacks.modular.ground import GroundSplit

BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True, eq=False)
class ObstacleGrid:
    """Occupied cells in the ego frame of one sweep."""

    occupied: BoolArray  # (rows along y, columns along x)
    origin: tuple[float, float]  # ego-frame x, y of the outer corner of cell (0, 0) [m]
    cell_size: float  # cell edge [m]
    world_T_ego: FloatArray  # (4, 4) the sweep's ego pose: world positions are mapped into the grid through it

    def to_grid_frame(self, world_xy: FloatArray) -> FloatArray:
        """(..., 2) world positions in the grid's ego frame [m]."""
        rotation = self.world_T_ego[:2, :2]
        result: FloatArray = (world_xy - self.world_T_ego[:2, 3]) @ rotation
        return result

    def clearance(self, world_xy: FloatArray, max_distance: float) -> FloatArray:
        """(...) distance from world positions to the nearest occupied cell [m], capped at max_distance.

        The distance transform runs only over the window the positions span (plus max_distance).
        Positions outside the grid are max_distance away from everything.
        """
        local = self.to_grid_frame(world_xy)
        rows, columns = self.occupied.shape
        column = (local[..., 0] - self.origin[0]) / self.cell_size
        row = (local[..., 1] - self.origin[1]) / self.cell_size
        pad = max_distance / self.cell_size + 1.0
        low_column = int(np.clip(np.floor(column.min() - pad), 0, columns))
        high_column = int(np.clip(np.ceil(column.max() + pad) + 1, 0, columns))
        low_row = int(np.clip(np.floor(row.min() - pad), 0, rows))
        high_row = int(np.clip(np.ceil(row.max() + pad) + 1, 0, rows))
        result = np.full(local.shape[:-1], max_distance)
        window = self.occupied[low_row:high_row, low_column:high_column]
        if window.size == 0 or not window.any():
            return result
        distance = ndimage.distance_transform_edt(~window, sampling=self.cell_size)
        # A cell centre stands for a whole cell: half a diagonal closer than its centre.
        distance = np.maximum(distance - 0.5 * np.sqrt(2.0) * self.cell_size, 0.0)
        column_index = np.floor(column).astype(np.int64) - low_column
        row_index = np.floor(row).astype(np.int64) - low_row
        inside = (
            (column_index >= 0) & (column_index < window.shape[1]) & (row_index >= 0) & (row_index < window.shape[0])
        )
        values = distance[np.where(inside, row_index, 0), np.where(inside, column_index, 0)]
        result = np.where(inside, np.minimum(values, max_distance), max_distance)
        return result


def obstacle_grid(
    split: GroundSplit,
    ground: GroundConfig,
    cell_size: float,
    max_height: float,
    min_points: int,
    world_T_ego: FloatArray,
) -> ObstacleGrid:
    """Cells holding at least min_points object returns no higher than max_height above the ground.

    The ego passes under higher returns; a cell with a single stray return (dust, a bump
    in the road) is not an obstacle.
    """
    x_min, y_min = ground.range_x[0], ground.range_y[0]
    columns = int(np.ceil((ground.range_x[1] - x_min) / cell_size))
    rows = int(np.ceil((ground.range_y[1] - y_min) / cell_size))
    low = split.is_object & (split.height <= max_height)
    points = split.xyz.take(np.flatnonzero(low), axis=0)  # faster than boolean indexing of an (N, 3) array
    column = np.minimum(((points[:, 0] - x_min) / cell_size).astype(np.int64), columns - 1)
    row = np.minimum(((points[:, 1] - y_min) / cell_size).astype(np.int64), rows - 1)
    counts = np.bincount(row * columns + column, minlength=rows * columns)
    occupied = (counts >= min_points).reshape(rows, columns)
    return ObstacleGrid(occupied=occupied, origin=(x_min, y_min), cell_size=cell_size, world_T_ego=world_T_ego)


def clear_boxes(grid: ObstacleGrid, world_boxes: FloatArray, grow: float) -> ObstacleGrid:
    """The grid without the cells inside the given world-frame boxes (K, 5), each grown by `grow` [m]."""
    if world_boxes.shape[0] == 0:
        return grid
    occupied = grid.occupied.copy()
    corners = grid.to_grid_frame(np.asarray(box_corners(world_boxes), dtype=np.float64))  # (K, 4, 2) ego frame
    for box, outline in zip(world_boxes, corners, strict=True):
        low = np.floor((outline.min(axis=0) - grow - np.array(grid.origin)) / grid.cell_size).astype(int)
        high = np.ceil((outline.max(axis=0) + grow - np.array(grid.origin)) / grid.cell_size).astype(int) + 1
        low = np.clip(low, 0, [occupied.shape[1], occupied.shape[0]])
        high = np.clip(high, 0, [occupied.shape[1], occupied.shape[0]])
        rows, columns = np.nonzero(occupied[low[1] : high[1], low[0] : high[0]])
        if rows.shape[0] == 0:
            continue
        centre_x = grid.origin[0] + (columns + low[0] + 0.5) * grid.cell_size
        centre_y = grid.origin[1] + (rows + low[1] + 0.5) * grid.cell_size
        ego_centre = grid.to_grid_frame(box[:2])
        yaw = box[2] - np.arctan2(grid.world_T_ego[1, 0], grid.world_T_ego[0, 0])
        along = (centre_x - ego_centre[0]) * np.cos(yaw) + (centre_y - ego_centre[1]) * np.sin(yaw)
        across = -(centre_x - ego_centre[0]) * np.sin(yaw) + (centre_y - ego_centre[1]) * np.cos(yaw)
        inside = (np.abs(along) <= 0.5 * box[3] + grow) & (np.abs(across) <= 0.5 * box[4] + grow)
        occupied[rows[inside] + low[1], columns[inside] + low[0]] = False
    return ObstacleGrid(occupied=occupied, origin=grid.origin, cell_size=grid.cell_size, world_T_ego=grid.world_T_ego)
