"""The coarse collision raster of the pruning: where a candidate centre could touch an obstacle at all."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from advsim_ros.core.feasibility.obstacles import WindowObstacles
from advsim_ros.core.types import FloatArray

Float32Array = npt.NDArray[np.float32]

GROUP_BITS = 31  # actors share bits 1..31 of the cull raster; bit 0 is the SDV


class CullRaster:
    """Per step, a bitmask raster of cells from which a candidate centre could touch an obstacle.

    A cell is flagged for an obstacle when its centre lies within reach (the candidate's
    circumradius) plus half a cell diagonal of the obstacle's box: a rounded rectangle, much
    tighter than a circle for cars side by side in adjacent lanes. A candidate centre in a
    flagged cell is within reach of the obstacles of the flagged bits (bit 0: the SDV; bit
    b > 0: actors j with (j - 1) % 31 == b - 1) and needs an exact test; a centre in an empty
    cell touches nothing at that step.
    """

    def __init__(
        self, obstacles: WindowObstacles, origin: FloatArray, half_size: float, cell: float, reach: float
    ) -> None:
        self.cell = cell
        self.width = math.ceil(2.0 * half_size / cell)
        self.low = origin - half_size  # world position of cell (0, 0) corner [m]
        steps, count = obstacles.present.shape
        self.steps = steps
        self.grid = np.zeros((steps, self.width, self.width), dtype=np.uint32)
        margin = reach + cell * math.sqrt(0.5)
        for j in range(count):
            times = np.nonzero(obstacles.present[:, j])[0]
            if times.size == 0:
                continue
            half_length, half_width = 0.5 * obstacles.boxes[0, j, 3], 0.5 * obstacles.boxes[0, j, 4]
            span = math.ceil((math.hypot(half_length, half_width) + margin) / cell) + 1
            offsets = np.arange(-span, span + 1)
            boxes = obstacles.boxes[times, j]
            base = np.floor((boxes[:, :2] - self.low) / cell).astype(np.int64)
            cols = base[:, 0, None, None] + offsets[None, None, :]
            rows = base[:, 1, None, None] + offsets[None, :, None]
            dx = self.low[0] + (cols + 0.5) * cell - boxes[:, 0, None, None]  # cell centre from the box centre [m]
            dy = self.low[1] + (rows + 0.5) * cell - boxes[:, 1, None, None]
            cos, sin = np.cos(boxes[:, 2])[:, None, None], np.sin(boxes[:, 2])[:, None, None]
            outside_along = np.maximum(np.abs(dx * cos + dy * sin) - half_length, 0.0)
            outside_across = np.maximum(np.abs(-dx * sin + dy * cos) - half_width, 0.0)
            near = outside_along**2 + outside_across**2 <= margin**2
            near &= (cols >= 0) & (cols < self.width) & (rows >= 0) & (rows < self.width)
            t_index = np.broadcast_to(times[:, None, None], near.shape)[near]
            row_index = np.broadcast_to(rows, near.shape)[near]
            col_index = np.broadcast_to(cols, near.shape)[near]
            bit = np.uint32(1) if j == 0 else np.uint32(1 << (1 + (j - 1) % GROUP_BITS))
            self.grid[t_index, row_index, col_index] |= bit
        self.flat = self.grid.reshape(-1)

    def lookup(self, x: Float32Array, y: Float32Array, local_low: FloatArray) -> npt.NDArray[np.uint32]:
        """Time-major (T, N) obstacle bits at candidate centres (T, N) in the local frame.

        local_low is the raster's lower corner in that frame.
        """
        scale = np.float32(1.0 / self.cell)
        cols = np.clip(((x - np.float32(local_low[0])) * scale).astype(np.int32), 0, self.width - 1)
        rows = np.clip(((y - np.float32(local_low[1])) * scale).astype(np.int32), 0, self.width - 1)
        step_offset = (np.arange(self.steps, dtype=np.int32) * np.int32(self.width * self.width))[:, None]
        index = step_offset + rows * np.int32(self.width) + cols
        result: npt.NDArray[np.uint32] = self.flat[index]
        return result
