"""Core value types shared by every part of advsim_ros.

All types are frozen dataclasses validated on construction; arrays are numpy arrays
whose shapes and units are documented beside each field. Frames: "world" is the log's
fixed frame (KITTI: the odometry frame of the first sweep; Argoverse 2: the city frame),
"ego" is the vehicle base frame (x forward, y left, z up, origin on the ground below the
rear axle when known), "sensor" is the LiDAR frame. Times are integer nanoseconds.

These types never import rclpy or ROS messages (see advsim_ros.ros for conversions).
"""

from __future__ import annotations

import functools
import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np
import numpy.typing as npt

from advsim_ros.core.errors import UserError

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


class ScenarioError(UserError, ValueError):
    """Input that cannot form a valid scenario; the message names the problem."""


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise ScenarioError(message)


def _as_float_array(name: str, value: npt.ArrayLike, shape: tuple[int | None, ...]) -> FloatArray:
    array = np.asarray(value, dtype=np.float64)
    _require(array.ndim == len(shape), f"{name}: expected {len(shape)} dimensions, got shape {array.shape}")
    for axis, (want, got) in enumerate(zip(shape, array.shape, strict=True)):
        _require(want is None or want == got, f"{name}: axis {axis} must have size {want}, got shape {array.shape}")
    _require(bool(np.all(np.isfinite(array))), f"{name}: contains NaN or infinite values")
    return array


def _as_stamps(name: str, value: npt.ArrayLike) -> IntArray:
    stamps = np.asarray(value, dtype=np.int64)
    _require(stamps.ndim == 1, f"{name}: expected a 1-D array of nanosecond stamps, got shape {stamps.shape}")
    _require(bool(np.all(np.diff(stamps) > 0)), f"{name}: stamps must be strictly increasing")
    return stamps


def _is_rigid_transform(matrix: FloatArray) -> bool:
    rotation = matrix[..., :3, :3]
    identity = np.broadcast_to(np.eye(3), rotation.shape)
    orthonormal = np.allclose(np.swapaxes(rotation, -1, -2) @ rotation, identity, atol=1e-4)
    bottom = np.allclose(matrix[..., 3, :], np.array([0.0, 0.0, 0.0, 1.0]))
    return bool(orthonormal and bottom and np.all(np.linalg.det(rotation) > 0))


class ActorClass(StrEnum):
    """Coarse actor categories shared by importers, behaviours and metrics."""

    VEHICLE = "vehicle"
    PEDESTRIAN = "pedestrian"
    CYCLIST = "cyclist"
    OTHER = "other"


@dataclass(frozen=True, eq=False)
class ActorTrack:
    """One tracked actor: an oriented 3-D box per observed frame, in the world frame."""

    actor_id: str
    actor_class: ActorClass
    size: FloatArray  # (3,) box length, width, height [m]
    stamps_ns: IntArray  # (T,) observation times [ns], strictly increasing
    centers: FloatArray  # (T, 3) box centre x, y, z in the world frame [m]
    yaws: FloatArray  # (T,) heading about world z, counter-clockwise from +x [rad]

    def __post_init__(self) -> None:
        _require(bool(self.actor_id), "ActorTrack: actor_id must not be empty")
        object.__setattr__(self, "actor_class", ActorClass(self.actor_class))
        size = _as_float_array(f"ActorTrack {self.actor_id} size", self.size, (3,))
        _require(bool(np.all(size > 0)), f"ActorTrack {self.actor_id}: box size must be positive, got {size}")
        stamps = _as_stamps(f"ActorTrack {self.actor_id} stamps_ns", self.stamps_ns)
        count = stamps.shape[0]
        _require(count >= 1, f"ActorTrack {self.actor_id}: needs at least one observation")
        object.__setattr__(self, "size", size)
        object.__setattr__(self, "stamps_ns", stamps)
        object.__setattr__(
            self, "centers", _as_float_array(f"ActorTrack {self.actor_id} centers", self.centers, (count, 3))
        )
        object.__setattr__(self, "yaws", _as_float_array(f"ActorTrack {self.actor_id} yaws", self.yaws, (count,)))

    @property
    def length(self) -> float:
        return float(self.size[0])  # [m]

    @property
    def width(self) -> float:
        return float(self.size[1])  # [m]

    @property
    def height(self) -> float:
        return float(self.size[2])  # [m]

    def between(self, first_ns: int, last_ns: int) -> ActorTrack | None:
        """The observations stamped first..last (inclusive); None when there is none."""
        inside = (self.stamps_ns >= first_ns) & (self.stamps_ns <= last_ns)
        if not np.any(inside):
            return None
        stamps, centers, yaws = self.stamps_ns[inside], self.centers[inside], self.yaws[inside]
        return ActorTrack(self.actor_id, self.actor_class, self.size, stamps, centers, yaws)


@dataclass(frozen=True, eq=False)
class EgoTrajectory:
    """The self-driving vehicle's logged poses: the human (expert) trajectory."""

    stamps_ns: IntArray  # (T,) [ns], strictly increasing
    poses: FloatArray  # (T, 4, 4) rigid transforms T_world_ego

    def __post_init__(self) -> None:
        stamps = _as_stamps("EgoTrajectory stamps_ns", self.stamps_ns)
        poses = _as_float_array("EgoTrajectory poses", self.poses, (stamps.shape[0], 4, 4))
        _require(_is_rigid_transform(poses), "EgoTrajectory poses: not all poses are rigid transforms")
        object.__setattr__(self, "stamps_ns", stamps)
        object.__setattr__(self, "poses", poses)

    @property
    def xy(self) -> FloatArray:
        """(T, 2) ego position in the world frame [m]."""
        return self.poses[:, :2, 3]

    @property
    def yaws(self) -> FloatArray:
        """(T,) ego heading about world z [rad]."""
        return np.arctan2(self.poses[:, 1, 0], self.poses[:, 0, 0])


@dataclass(frozen=True, eq=False)
class SensorModel:
    """A spinning LiDAR's geometry, estimated from the log itself or known per device."""

    beam_elevations: FloatArray  # (B,) beam elevation angles, descending [rad]
    azimuth_resolution: float  # horizontal angle between consecutive firings [rad]
    min_range: float  # returns closer than this are not recorded [m]
    max_range: float  # returns farther than this are not recorded [m]

    def __post_init__(self) -> None:
        elevations = _as_float_array("SensorModel beam_elevations", self.beam_elevations, (None,))
        _require(elevations.shape[0] >= 1, "SensorModel: needs at least one beam")
        _require(bool(np.all(np.diff(elevations) < 0)), "SensorModel beam_elevations: must be strictly descending")
        _require(0.0 < self.azimuth_resolution < np.pi, "SensorModel azimuth_resolution: must be in (0, pi) rad")
        _require(0.0 <= self.min_range < self.max_range, "SensorModel: need 0 <= min_range < max_range")
        object.__setattr__(self, "beam_elevations", elevations)

    @property
    def num_beams(self) -> int:
        return int(self.beam_elevations.shape[0])

    @property
    def num_azimuths(self) -> int:
        return round(2.0 * np.pi / self.azimuth_resolution)


POINT_XYZ_FIELDS = ("x", "y", "z")


@dataclass(frozen=True, eq=False)
class Sweep:
    """One LiDAR sweep in the sensor frame, with the sensor pose when it was taken.

    ``points`` is a structured array so that any field layout of the source survives
    (x, y, z always; intensity, ring, time or anything else are kept as they came).
    """

    stamp_ns: int  # sweep time [ns]
    frame_id: str  # sensor frame name in the source log
    points: np.ndarray  # (N,) structured array with float fields x, y, z [m] in the sensor frame
    sensor_pose: FloatArray  # (4, 4) rigid transform T_world_sensor

    def __post_init__(self) -> None:
        names = self.points.dtype.names or ()
        missing = [name for name in POINT_XYZ_FIELDS if name not in names]
        _require(not missing, f"Sweep at {self.stamp_ns} ns: point fields {missing} missing (has {list(names)})")
        _require(
            self.points.ndim == 1, f"Sweep at {self.stamp_ns} ns: points must be 1-D, got shape {self.points.shape}"
        )
        pose = _as_float_array(f"Sweep at {self.stamp_ns} ns sensor_pose", self.sensor_pose, (4, 4))
        _require(_is_rigid_transform(pose), f"Sweep at {self.stamp_ns} ns: sensor_pose is not a rigid transform")
        object.__setattr__(self, "sensor_pose", pose)

    @property
    def xyz(self) -> FloatArray:
        """(N, 3) point coordinates in the sensor frame [m]."""
        return np.stack([self.points[name].astype(np.float64) for name in POINT_XYZ_FIELDS], axis=-1)

    @property
    def num_points(self) -> int:
        return int(self.points.shape[0])


@dataclass(frozen=True, eq=False)
class RoadMap:
    """Vector map in the world frame: where vehicles may drive and the lane centrelines."""

    drivable_areas: tuple[FloatArray, ...] = ()  # each (K, 2) polygon outline x, y [m]
    lane_centerlines: tuple[FloatArray, ...] = ()  # each (K, 2) polyline x, y [m], in driving direction

    def __post_init__(self) -> None:
        areas = tuple(_as_float_array("RoadMap drivable area", area, (None, 2)) for area in self.drivable_areas)
        lanes = tuple(_as_float_array("RoadMap lane centreline", lane, (None, 2)) for lane in self.lane_centerlines)
        _require(all(area.shape[0] >= 3 for area in areas), "RoadMap: a drivable-area polygon needs >= 3 vertices")
        _require(all(lane.shape[0] >= 2 for lane in lanes), "RoadMap: a lane centreline needs >= 2 points")
        object.__setattr__(self, "drivable_areas", areas)
        object.__setattr__(self, "lane_centerlines", lanes)


@dataclass(frozen=True, eq=False)
class EgoGeometry:
    """The SDV's box: its size and where its centre sits in the ego frame (one record, carried by the scenario)."""

    size: FloatArray = field(default_factory=lambda: np.array([4.5, 1.9, 1.7]))  # (3,) length, width, height [m]
    forward_offset: float = 1.0  # centre of the box ahead of the ego frame's origin, along its heading [m]

    def __post_init__(self) -> None:
        size = _as_float_array("EgoGeometry size", self.size, (3,))
        _require(bool(np.all(size > 0)), f"EgoGeometry size must be positive, got {size}")
        _require(bool(np.isfinite(self.forward_offset)), "EgoGeometry forward_offset must be finite")
        object.__setattr__(self, "size", size)

    @property
    def length(self) -> float:
        return float(self.size[0])  # [m]

    @property
    def width(self) -> float:
        return float(self.size[1])  # [m]

    def boxes(self, xy: FloatArray, yaws: FloatArray) -> FloatArray:
        """(..., 5) boxes [x, y, yaw, length, width] of the SDV at ego-frame poses xy (..., 2), yaws (...) [m, rad]."""
        centre = xy + self.forward_offset * np.stack([np.cos(yaws), np.sin(yaws)], axis=-1)
        sizes = np.broadcast_to(self.size[:2], (*np.shape(yaws), 2))
        result: FloatArray = np.concatenate([centre, np.asarray(yaws)[..., None], sizes], axis=-1)
        return result


SOURCE_MAP = "map"  # DrivableArea.source: rasterised from the vector map
SOURCE_LOG = "log estimate"  # estimated from the log (driven area grown over the LiDAR ground)


@dataclass(frozen=True, eq=False)
class DrivableArea:
    """A drivable-area raster: cell (row i, column j) covers x in origin_x + [j, j + 1) res, y likewise with i."""

    origin: FloatArray  # (2,) world x, y of the outer corner of cell (0, 0) [m]
    resolution: float  # cell edge [m]
    mask: BoolArray  # (H, W) True where drivable; rows go along y, columns along x
    source: str  # SOURCE_MAP or SOURCE_LOG

    def __post_init__(self) -> None:
        origin = np.asarray(self.origin, dtype=np.float64)
        mask = np.asarray(self.mask, dtype=bool)
        if origin.shape != (2,) or not np.all(np.isfinite(origin)):
            raise ScenarioError(f"DrivableArea origin: expected 2 finite numbers, got {self.origin!r}")
        if not (np.isfinite(self.resolution) and self.resolution > 0):
            raise ScenarioError(f"DrivableArea resolution: must be positive, got {self.resolution}")
        if mask.ndim != 2 or mask.size == 0:
            raise ScenarioError(f"DrivableArea mask: expected a non-empty 2-D array, got shape {mask.shape}")
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "mask", mask)

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.mask.shape[0]), int(self.mask.shape[1]))

    def contains(self, x: npt.ArrayLike, y: npt.ArrayLike, offset: npt.ArrayLike = (0.0, 0.0)) -> BoolArray:
        """Whether world points (x + offset_x, y + offset_y) [m] are drivable; outside the raster is not.

        ``offset`` lets callers keep coordinates in a local float32 frame around ``offset``.
        """
        x_values, y_values = np.asarray(x), np.asarray(y)
        dtype = x_values.dtype if np.issubdtype(x_values.dtype, np.floating) else np.dtype(np.float64)
        # Index the raster padded by one undrivable cell: points outside clip onto the padding.
        shift = np.asarray(offset, dtype=np.float64) - self.origin + self.resolution
        scale = dtype.type(1.0 / self.resolution)
        padded = self._padded
        height, width = padded.shape
        column = np.clip((x_values + dtype.type(shift[0])) * scale, 0, width - 1).astype(np.int32)
        row = np.clip((y_values + dtype.type(shift[1])) * scale, 0, height - 1).astype(np.int32)
        row *= np.int32(width)
        row += column
        result: BoolArray = padded.ravel()[row]
        return result

    @functools.cached_property
    def _padded(self) -> BoolArray:
        padded = np.zeros((self.mask.shape[0] + 2, self.mask.shape[1] + 2), dtype=bool)
        padded[1:-1, 1:-1] = self.mask
        return padded

    def eroded(self, margin: float) -> DrivableArea:
        """The area shrunk by margin [m]: cells whose centre is at least margin from every undrivable cell."""
        if margin <= 0.0:
            return self
        from scipy import ndimage  # only here: core.types stays light to import

        distance = ndimage.distance_transform_edt(self.mask, sampling=self.resolution)
        return DrivableArea(self.origin, self.resolution, np.asarray(distance > margin), self.source)

    def cell_centers(self) -> tuple[FloatArray, FloatArray]:
        """(H, W) world x and y of every cell centre [m]."""
        height, width = self.shape
        columns = self.origin[0] + (np.arange(width) + 0.5) * self.resolution
        rows = self.origin[1] + (np.arange(height) + 0.5) * self.resolution
        grid_x, grid_y = np.meshgrid(columns, rows)
        return grid_x, grid_y


@dataclass(frozen=True, eq=False)
class Scenario:
    """A driving log: frames at a fixed rate, the ego's logged trajectory, actors, LiDAR, map."""

    scenario_id: str
    frame_stamps_ns: IntArray  # (F,) frame times [ns], strictly increasing (10 Hz for KITTI / AV2)
    ego: EgoTrajectory  # one pose per frame (stamps equal frame_stamps_ns)
    actors: tuple[ActorTrack, ...]  # every labelled actor except the ego
    sweeps: tuple[Sweep, ...] = ()  # LiDAR sweeps, stamps a subset of frame_stamps_ns; empty when the log has none
    ego_T_sensor: FloatArray = field(default_factory=lambda: np.eye(4))  # (4, 4) rigid transform T_ego_sensor
    sensor: SensorModel | None = None  # LiDAR geometry when known
    road_map: RoadMap | None = None  # vector map when the log has one
    ego_geometry: EgoGeometry = field(default_factory=EgoGeometry)  # the SDV's box
    sensor_frame: str = ""  # name of the LiDAR frame ("" = the sweeps' frame_id, or unknown)
    drivable_area: DrivableArea | None = None  # a stored drivable raster (e.g. the estimate an attack used)

    def __post_init__(self) -> None:
        _require(bool(self.scenario_id), "Scenario: scenario_id must not be empty")
        frames = _as_stamps(f"Scenario {self.scenario_id} frame_stamps_ns", self.frame_stamps_ns)
        _require(frames.shape[0] >= 1, f"Scenario {self.scenario_id}: needs at least one frame")
        object.__setattr__(self, "frame_stamps_ns", frames)
        _require(
            np.array_equal(self.ego.stamps_ns, frames),
            f"Scenario {self.scenario_id}: ego poses must be given at exactly the frame stamps",
        )
        ids = [actor.actor_id for actor in self.actors]
        _require(len(ids) == len(set(ids)), f"Scenario {self.scenario_id}: duplicate actor ids")
        frame_set = set(frames.tolist())
        for actor in self.actors:
            _require(
                set(actor.stamps_ns.tolist()) <= frame_set,
                f"Scenario {self.scenario_id}: actor {actor.actor_id} has stamps that are not frame stamps",
            )
        sweep_stamps = [sweep.stamp_ns for sweep in self.sweeps]
        _require(
            all(b > a for a, b in itertools.pairwise(sweep_stamps)),
            f"Scenario {self.scenario_id}: sweeps must be in strictly increasing time order",
        )
        _require(
            set(sweep_stamps) <= frame_set,
            f"Scenario {self.scenario_id}: sweeps have stamps that are not frame stamps",
        )
        ego_T_sensor = _as_float_array(f"Scenario {self.scenario_id} ego_T_sensor", self.ego_T_sensor, (4, 4))
        _require(_is_rigid_transform(ego_T_sensor), f"Scenario {self.scenario_id}: ego_T_sensor is not rigid")
        object.__setattr__(self, "ego_T_sensor", ego_T_sensor)
        sweep_frames = {sweep.frame_id for sweep in self.sweeps}
        _require(
            len(sweep_frames) <= 1, f"Scenario {self.scenario_id}: sweeps in several frames {sorted(sweep_frames)}"
        )
        if not self.sensor_frame and sweep_frames:
            object.__setattr__(self, "sensor_frame", next(iter(sweep_frames)))
        _require(
            sweep_frames <= {self.sensor_frame},
            f"Scenario {self.scenario_id}: sweeps in frame {sorted(sweep_frames)}, sensor_frame {self.sensor_frame!r}",
        )

    @property
    def num_frames(self) -> int:
        return int(self.frame_stamps_ns.shape[0])

    def actor(self, actor_id: str) -> ActorTrack:
        for actor in self.actors:
            if actor.actor_id == actor_id:
                return actor
        raise KeyError(f"scenario {self.scenario_id} has no actor {actor_id!r}")


def replace_actors(actors: Sequence[ActorTrack], moved: Sequence[ActorTrack]) -> tuple[ActorTrack, ...]:
    """The actors with those in ``moved`` (matched by id) swapped in: a query's perturbed world."""
    by_id = {track.actor_id: track for track in moved}
    return tuple(by_id.get(actor.actor_id, actor) for actor in actors)


@dataclass(frozen=True, eq=False)
class Plan:
    """A planned ego trajectory in the world frame, as published by the stack under test."""

    stamps_ns: IntArray  # (H,) [ns], strictly increasing (5 s at 10 Hz by default)
    xy: FloatArray  # (H, 2) planned ego positions in the world frame [m]
    yaws: FloatArray  # (H,) planned ego headings [rad]

    def __post_init__(self) -> None:
        stamps = _as_stamps("Plan stamps_ns", self.stamps_ns)
        count = stamps.shape[0]
        _require(count >= 1, "Plan: needs at least one pose")
        object.__setattr__(self, "stamps_ns", stamps)
        object.__setattr__(self, "xy", _as_float_array("Plan xy", self.xy, (count, 2)))
        object.__setattr__(self, "yaws", _as_float_array("Plan yaws", self.yaws, (count,)))


@dataclass(frozen=True, eq=False)
class Perturbation:
    """One search query: which actors to perturb and the normalised perturbation vector."""

    query_id: int  # monotonically increasing within one attack
    scenario_id: str
    actor_ids: tuple[str, ...]  # perturbed actors, in the order their blocks appear in delta
    delta: FloatArray  # (D,) concatenated per-actor perturbations, each entry in [-1, 1] (l_inf ball)
    algorithm: str  # name of the search algorithm that proposed it

    def __post_init__(self) -> None:
        _require(self.query_id >= 0, "Perturbation: query_id must be non-negative")
        delta = _as_float_array("Perturbation delta", self.delta, (None,))
        _require(bool(np.all(np.abs(delta) <= 1.0 + 1e-9)), "Perturbation delta: entries must lie in [-1, 1]")
        object.__setattr__(self, "delta", delta)
        object.__setattr__(self, "actor_ids", tuple(self.actor_ids))
