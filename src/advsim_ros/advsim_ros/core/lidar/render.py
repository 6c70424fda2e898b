"""Full-sweep rendering: every ray of a sensor model cast against placed surfaces.

Used for the synthetic logs (street meshes) and for rendering a frame from a new ego
pose with the background model and actor assets. Points come out beam after beam, each
beam one counter-clockwise turn starting at azimuth 0, like a KITTI ``.bin`` sweep, with
a ``ring`` field (0 = top beam).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from advsim_ros.core.lidar.raycast import PlacedSurface, cast_nearest
from advsim_ros.core.lidar.sensor import column_azimuths, rotate, unit_directions
from advsim_ros.core.types import FloatArray, IntArray, ScenarioError, SensorModel

RENDER_POINT_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("ring", "<u2")])


def grid_rays(sensor: SensorModel) -> tuple[FloatArray, IntArray, IntArray]:
    """Unit directions (B * A, 3) of every range-image cell centre, with their rows and columns (row-major)."""
    rows = np.repeat(np.arange(sensor.num_beams, dtype=np.int64), sensor.num_azimuths)
    columns = np.tile(np.arange(sensor.num_azimuths, dtype=np.int64), sensor.num_beams)
    directions = unit_directions(sensor.beam_elevations[rows], column_azimuths(columns, sensor))
    return directions, rows, columns


def render_sweep(
    sensor: SensorModel,
    sensor_pose: FloatArray,
    placed: Sequence[PlacedSurface],
    *,
    rng: np.random.Generator,
    range_noise_std: float = 0.0,
    drop_probabilities: Sequence[float] | None = None,
) -> np.ndarray:
    """The sweep (RENDER_POINT_DTYPE, sensor frame) seen from `sensor_pose` (4, 4) T_world_sensor.

    `placed` surfaces have their poses in the world frame. Each hit is kept with
    probability 1 - drop_probabilities[surface] (no drop when None), its range gets
    Gaussian noise of `range_noise_std` [m], and returns outside the sensor's
    [min_range, max_range] are not recorded.
    """
    if range_noise_std < 0:
        raise ScenarioError(f"render_sweep: range_noise_std must be >= 0, got {range_noise_std}")
    if drop_probabilities is not None and len(drop_probabilities) != len(placed):
        raise ScenarioError("render_sweep: need one drop probability per placed surface")
    directions, rows, _ = grid_rays(sensor)
    rotation, origin = sensor_pose[:3, :3], sensor_pose[:3, 3]
    hits = cast_nearest(origin, rotate(directions, rotation), placed)
    ranges = hits.ranges
    if range_noise_std > 0:
        ranges = ranges + rng.normal(0.0, range_noise_std, ranges.shape[0])
    keep = np.isfinite(ranges) & (ranges >= sensor.min_range) & (ranges <= sensor.max_range)
    if drop_probabilities is not None:
        chance = np.asarray(drop_probabilities, dtype=np.float64)[np.clip(hits.source, 0, None)]
        keep &= rng.random(ranges.shape[0]) >= chance
    chosen = np.flatnonzero(keep)
    points = np.zeros(chosen.shape[0], dtype=RENDER_POINT_DTYPE)
    xyz = directions[chosen] * ranges[chosen, None]
    points["x"], points["y"], points["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    points["intensity"] = hits.intensity[chosen]
    points["ring"] = rows[chosen]
    return points
