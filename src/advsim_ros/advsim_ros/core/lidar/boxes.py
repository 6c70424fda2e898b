"""Actor boxes in 3-D for the LiDAR re-simulation: poses, regions, point and ray tests, angular windows.

A box's own frame has its origin at the box centre, x along the heading, z up. A
"region" is an axis-aligned extent (lower, upper) in that frame, e.g. the box enlarged by
a margin with the bottom raised above the ground (see ``actor_region``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from advsim_ros.core.lidar.sensor import rotate
from advsim_ros.core.types import ActorTrack, FloatArray, IntArray, ScenarioError, SensorModel

BoolArray = npt.NDArray[np.bool_]


def yaw_pose(center: npt.ArrayLike, yaw: float) -> FloatArray:
    """(4, 4) rigid transform of a box centred at `center` (3,) [m] heading `yaw` [rad] about z."""
    pose = np.eye(4)
    cos, sin = np.cos(yaw), np.sin(yaw)
    pose[:3, :3] = np.array([[cos, -sin, 0.0], [sin, cos, 0.0], [0.0, 0.0, 1.0]])
    pose[:3, 3] = np.asarray(center, dtype=np.float64)
    return pose


def invert_rigid(pose: FloatArray) -> FloatArray:
    """The inverse (4, 4) of a rigid transform."""
    inverse = np.eye(4)
    inverse[:3, :3] = pose[:3, :3].T
    inverse[:3, 3] = -pose[:3, :3].T @ pose[:3, 3]
    return inverse


def track_pose_at(track: ActorTrack, stamp_ns: int) -> FloatArray | None:
    """T_world_box at a stamp the track was observed at, or None when it was not observed then."""
    index = int(np.searchsorted(track.stamps_ns, stamp_ns))
    if index >= track.stamps_ns.shape[0] or int(track.stamps_ns[index]) != stamp_ns:
        return None
    return yaw_pose(track.centers[index], float(track.yaws[index]))


@dataclass(frozen=True, eq=False)
class Region:
    """An axis-aligned extent in a box frame [m]."""

    lower: FloatArray  # (3,) [m]
    upper: FloatArray  # (3,) [m]

    def __post_init__(self) -> None:
        if np.any(np.asarray(self.upper) <= np.asarray(self.lower)):
            raise ScenarioError(f"Region: upper {self.upper} must exceed lower {self.lower}")

    def corners(self) -> FloatArray:
        """(8, 3) corners in the box frame [m]."""
        return np.array(
            [[(self.upper if (index >> axis) & 1 else self.lower)[axis] for axis in range(3)] for index in range(8)]
        )


def actor_region(size: FloatArray, margin: float, ground_clearance: float) -> Region:
    """Where an actor's own points lie: the box grown by `margin` [m], bottom raised by `ground_clearance` [m]."""
    half = 0.5 * np.asarray(size, dtype=np.float64)
    return Region(
        lower=np.array([-half[0] - margin, -half[1] - margin, -half[2] + ground_clearance]),
        upper=np.array([half[0] + margin, half[1] + margin, half[2] + margin]),
    )


def removal_region(size: FloatArray, margin: float) -> Region:
    """What removing an actor deletes: the box grown by `margin` [m] on every side (ground is re-cast)."""
    half = 0.5 * np.asarray(size, dtype=np.float64) + margin
    return Region(lower=-half, upper=half)


def to_box_frame(xyz: FloatArray, pose: FloatArray) -> FloatArray:
    """Points (N, 3) of frame F in the frame of the box whose pose in F is `pose` (4, 4)."""
    return rotate(xyz - pose[:3, 3], pose[:3, :3].T)


def inside(local_xyz: FloatArray, region: Region) -> BoolArray:
    """(N,) whether box-frame points lie inside the region (closed)."""
    result: BoolArray = np.all((local_xyz >= region.lower) & (local_xyz <= region.upper), axis=1)
    return result


def rays_hit_region(origins: FloatArray, directions: FloatArray, pose: FloatArray, region: Region) -> BoolArray:
    """(N,) whether rays from origins along unit directions (N, 3) in frame F cross the region (slab test)."""
    origin = to_box_frame(np.broadcast_to(origins, directions.shape), pose)
    local = rotate(directions, pose[:3, :3].T)
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = 1.0 / local
        first = (region.lower - origin) * inverse
        second = (region.upper - origin) * inverse
    # NaN (a ray in a slab's plane) is left out, as by nanmax / nanmin, column by column (much faster for 3).
    entry, leave = np.minimum(first, second), np.maximum(first, second)
    near = np.fmax(np.fmax(entry[:, 0], entry[:, 1]), entry[:, 2])
    far = np.fmin(np.fmin(leave[:, 0], leave[:, 1]), leave[:, 2])
    result: BoolArray = (far >= np.maximum(near, 0.0)) & np.isfinite(far)
    return result


@dataclass(frozen=True, eq=False)
class AngularWindow:
    """The directions from the sensor origin under which a region can be seen (conservative)."""

    center_azimuth: float  # [rad]
    azimuth_low: float  # lowest azimuth relative to the centre [rad], <= 0
    azimuth_high: float  # highest azimuth relative to the centre [rad], >= 0
    elevation_low: float  # [rad]
    elevation_high: float  # [rad]
    full_turn: bool  # the sensor stands inside the region's footprint: every azimuth

    @classmethod
    def of_region(cls, pose: FloatArray, region: Region, margin: float) -> AngularWindow:
        """The window of a region of the box at `pose` (in the sensor frame), widened by `margin` [rad]."""
        corners = region.corners() @ pose[:3, :3].T + pose[:3, 3]
        planar = np.hypot(corners[:, 0], corners[:, 1])
        # Nearest planar distance from the sensor to the region's footprint, in the box frame.
        origin = -pose[:3, :3].T @ pose[:3, 3]
        gap = np.maximum(np.maximum(region.lower[:2] - origin[:2], origin[:2] - region.upper[:2]), 0.0)
        nearest = float(np.hypot(gap[0], gap[1]))
        full_turn = nearest <= 1e-6
        top, bottom = float(corners[:, 2].max()), float(corners[:, 2].min())
        near_or_far_top = nearest if top > 0 else float(planar.max())
        near_or_far_bottom = nearest if bottom < 0 else float(planar.max())
        elevation_high = np.arctan2(top, max(near_or_far_top, 1e-6)) + margin
        elevation_low = np.arctan2(bottom, max(near_or_far_bottom, 1e-6)) - margin
        center = float(np.arctan2(pose[1, 3], pose[0, 3]))
        relative = np.mod(np.arctan2(corners[:, 1], corners[:, 0]) - center + np.pi, 2.0 * np.pi) - np.pi
        low, high = float(relative.min()) - margin, float(relative.max()) + margin
        if full_turn or high - low >= 2.0 * np.pi:
            full_turn, low, high = True, -np.pi, np.pi
        return cls(center, low, high, float(elevation_low), float(elevation_high), full_turn)

    def relative_azimuths(self, azimuths: FloatArray) -> FloatArray:
        """Azimuths [rad] relative to the window centre, wrapped into [-pi, pi)."""
        result: FloatArray = np.mod(azimuths - self.center_azimuth + np.pi, 2.0 * np.pi) - np.pi
        return result

    def contains(self, azimuths: FloatArray, elevations: FloatArray) -> BoolArray:
        """(N,) whether directions lie inside the window."""
        in_elevation = (elevations >= self.elevation_low) & (elevations <= self.elevation_high)
        if self.full_turn:
            return in_elevation
        relative = self.relative_azimuths(azimuths)
        result: BoolArray = in_elevation & (relative >= self.azimuth_low) & (relative <= self.azimuth_high)
        return result

    def rows(self, sensor: SensorModel) -> IntArray:
        """Beam rows whose elevation lies inside the window."""
        elevations = sensor.beam_elevations
        result: IntArray = np.flatnonzero((elevations >= self.elevation_low) & (elevations <= self.elevation_high))
        return result

    def columns(self, sensor: SensorModel) -> IntArray:
        """Range-image columns whose centre azimuth lies inside the window (each column once)."""
        step = sensor.azimuth_resolution
        if self.full_turn:
            return np.arange(sensor.num_azimuths, dtype=np.int64)
        first = int(np.ceil((self.center_azimuth + self.azimuth_low) / step - 0.5))
        last = int(np.floor((self.center_azimuth + self.azimuth_high) / step - 0.5))
        columns: IntArray = np.unique(np.mod(np.arange(first, last + 1, dtype=np.int64), sensor.num_azimuths))
        return columns
