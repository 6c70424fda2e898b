"""The learned planner's inputs: a BEV raster of the last second of LiDAR and the ego's recent motion.

Each sweep is reduced once, when it arrives, to its returns above the local ground
(split by height band) and its ground returns, deduplicated on a fine grid and kept in
the world frame with the ego pose. At every step the remembered sweeps are drawn into
the current ego frame: one occupancy channel per band and sweep (newest first), and one
channel of the newest sweep's ground returns (where the road is). The ego's motion
features are its speed, yaw rate, acceleration and its positions over the last second in
the current ego frame. Training and inference build inputs with this same code.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from advsim_ros.core.types import FloatArray
from advsim_ros.stacks.interface import EgoMotion, transform_points
from advsim_ros.stacks.learned.config import RasterConfig
from advsim_ros.stacks.modular.config import GroundConfig
from advsim_ros.stacks.modular.ground import split_ground

Float32Array = npt.NDArray[np.float32]
UInt8Array = npt.NDArray[np.uint8]

GROUND_BAND = 255  # band code of ground returns
NUM_MOTION_FEATURES = 3  # speed, yaw rate, acceleration
SPEED_SCALE = 10.0  # features are divided by these so that they are of order one [m/s], [m], [m/s^2]
POSITION_SCALE = 10.0
ACCELERATION_SCALE = 3.0


@dataclass(frozen=True, eq=False)
class ReducedSweep:
    """One sweep reduced for the raster, in the world frame."""

    stamp_ns: int
    world_T_ego: FloatArray  # (4, 4)
    world_xy: FloatArray  # (K, 2) returns [m]
    band: UInt8Array  # (K,) height band index, or GROUND_BAND


def reduce_sweep(
    stamp_ns: int, xyz_ego: np.ndarray, world_T_ego: FloatArray, ground: GroundConfig, raster: RasterConfig
) -> ReducedSweep:
    """Band every return by its height above the local ground, keep one per fine cell and band."""
    split = split_ground(xyz_ego, ground)
    edges = np.asarray(raster.band_edges, dtype=np.float32)
    band = np.searchsorted(edges, split.height, side="right").astype(np.int64) - 1  # -1 below, num_bands above
    keep = (band >= 0) & (band < raster.num_bands) & ~split.is_ground
    band = np.where(split.is_ground, GROUND_BAND, band)
    keep |= split.is_ground
    xy = split.xyz[keep, :2]
    band = band[keep]
    # One return per (cell, band): the raster is occupancy, duplicates only cost time.
    cell = np.floor(xy / raster.dedupe_cell).astype(np.int64)
    key = (cell[:, 0] * 1_000_003 + cell[:, 1]) * 256 + band
    _, first = np.unique(key, return_index=True)
    local = xy[first].astype(np.float64)
    world = local @ world_T_ego[:2, :2].T + world_T_ego[:2, 3]
    return ReducedSweep(stamp_ns, world_T_ego, world, band[first].astype(np.uint8))


class SweepHistory:
    """The last `history` reduced sweeps; forgets them on a jump in time."""

    def __init__(self, raster: RasterConfig) -> None:
        self._raster = raster
        self._sweeps: deque[ReducedSweep] = deque(maxlen=raster.history)

    def reset(self) -> None:
        self._sweeps.clear()

    def add(self, sweep: ReducedSweep) -> None:
        if self._sweeps:
            gap_s = (sweep.stamp_ns - self._sweeps[-1].stamp_ns) * 1e-9
            if gap_s <= 0.0 or gap_s > self._raster.max_gap_s:
                self._sweeps.clear()
        self._sweeps.append(sweep)

    @property
    def newest_first(self) -> list[ReducedSweep]:
        return list(reversed(self._sweeps))


def rasterize(sweeps: list[ReducedSweep], world_T_ego: FloatArray, raster: RasterConfig) -> Float32Array:
    """(C, rows, columns) raster in the ego frame of world_T_ego: band occupancy per sweep, then ground."""
    rows, columns = raster.shape
    image = np.zeros((raster.num_channels, rows, columns), dtype=np.float32)
    ego_T_world = np.linalg.inv(world_T_ego)
    for age, sweep in enumerate(sweeps[: raster.history]):
        local = sweep.world_xy @ ego_T_world[:2, :2].T + ego_T_world[:2, 3]
        column = np.floor((local[:, 0] - raster.x_range[0]) / raster.resolution).astype(np.int64)
        row = np.floor((local[:, 1] - raster.y_range[0]) / raster.resolution).astype(np.int64)
        inside = (column >= 0) & (column < columns) & (row >= 0) & (row < rows)
        objects = inside & (sweep.band != GROUND_BAND)
        channel = age * raster.num_bands + sweep.band[objects].astype(np.int64)
        image[channel, row[objects], column[objects]] = 1.0
        if age == 0:
            ground = inside & (sweep.band == GROUND_BAND)
            image[-1, row[ground], column[ground]] = 1.0
    return image


def motion_features(
    sweeps: list[ReducedSweep], world_T_ego: FloatArray, motion: EgoMotion, history: int
) -> Float32Array:
    """(3 + 2 * history,) speed, yaw rate, acceleration and past positions in the current ego frame (scaled).

    Positions of sweeps that are not remembered (the start of a drive) repeat the oldest one known.
    """
    ego_T_world = np.asarray(np.linalg.inv(world_T_ego), dtype=np.float64)
    past = np.zeros((history, 2))
    known = [transform_points(sweep.world_T_ego[None, :3, 3], ego_T_world)[0, :2] for sweep in sweeps[:history]]
    for index in range(history):
        past[index] = known[min(index, len(known) - 1)] if known else 0.0
    head = [motion.speed / SPEED_SCALE, motion.yaw_rate, motion.acceleration / ACCELERATION_SCALE]
    return np.concatenate([np.asarray(head), past.ravel() / POSITION_SCALE]).astype(np.float32)


def motion_prior(motion: EgoMotion, num_steps: int, step_s: float) -> Float32Array:
    """(num_steps, 2) positions in the ego frame if speed and yaw rate stayed as they are [m]."""
    times = step_s * np.arange(1, num_steps + 1)
    yaw = motion.yaw_rate * times
    if abs(motion.yaw_rate) > 1e-4:
        x = motion.speed * np.sin(yaw) / motion.yaw_rate
        y = motion.speed * (1.0 - np.cos(yaw)) / motion.yaw_rate
    else:
        x, y = motion.speed * times, np.zeros_like(times)
    return np.stack([x, y], axis=1).astype(np.float32)
