"""Argoverse 2 importer (Wilson et al., "Argoverse 2: Next Generation Datasets for Self-Driving
Perception and Forecasting", NeurIPS Datasets and Benchmarks 2021).

A log folder holds ``annotations.feather`` (or ``annotations_with_ego.feather``): 3-D
cuboids with track uuids in the ego-vehicle frame at each LiDAR time, 10 Hz;
``city_SE3_egovehicle.feather``: ego poses in the city frame; ``map/log_map_archive_*.json``:
the vector map (lane segments with left/right boundaries, drivable areas) in the city
frame; and, where present, ``sensors/lidar/<timestamp_ns>.feather``: sweeps of both
roof LiDARs merged in the ego-vehicle frame.

Frames: "world" is the city frame; "ego" is AV2's egovehicle frame; the sweeps stay in
the egovehicle frame they were published in, so the sensor frame is "egovehicle" with
an identity mount. Frame stamps are the annotated LiDAR times. Lane centrelines are the
midlines of each vehicle or bus lane segment's boundaries.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.feather as feather
from scipy.spatial.transform import Rotation

from advsim_ros.contract.pointcloud import DroppedPoints
from advsim_ros.core.types import (
    ActorClass,
    ActorTrack,
    EgoGeometry,
    EgoTrajectory,
    FloatArray,
    IntArray,
    RoadMap,
    Scenario,
    ScenarioError,
    Sweep,
)

log = logging.getLogger(__name__)

AV2_SENSOR_FRAME = "egovehicle"  # AV2 publishes merged sweeps in the ego-vehicle frame
AV2_EGO_CATEGORY = "EGO_VEHICLE"  # annotations_with_ego.feather labels the ego itself; used for its size
AV2_EGO_SIZE = (4.877, 2.0, 1.473)  # length, width, height [m] of the fleet's car as EGO_VEHICLE labels give it
AV2_CENTERLINE_SPACING = 1.0  # target spacing of lane-centreline points [m]

AV2_CLASSES: dict[str, ActorClass] = {
    **dict.fromkeys(
        (
            "REGULAR_VEHICLE",
            "LARGE_VEHICLE",
            "BUS",
            "SCHOOL_BUS",
            "ARTICULATED_BUS",
            "BOX_TRUCK",
            "TRUCK",
            "TRUCK_CAB",
            "VEHICULAR_TRAILER",
            "MESSAGE_BOARD_TRAILER",
            "RAILED_VEHICLE",
        ),
        ActorClass.VEHICLE,
    ),
    **dict.fromkeys(("PEDESTRIAN", "OFFICIAL_SIGNALER"), ActorClass.PEDESTRIAN),
    **dict.fromkeys(
        ("BICYCLE", "BICYCLIST", "MOTORCYCLE", "MOTORCYCLIST", "WHEELED_RIDER"),
        ActorClass.CYCLIST,
    ),
}  # every other category (bollards, cones, signs, strollers, animals, ...) is ActorClass.OTHER
AV2_LANE_TYPES = ("VEHICLE", "BUS")  # lanes a vehicle may follow; bike lanes are left out


class Av2Error(ScenarioError):
    """Argoverse 2 input that is missing, malformed or inconsistent; the message names the file."""


def _read_table(path: Path, columns: tuple[str, ...]) -> dict[str, np.ndarray]:
    if not path.is_file():
        raise Av2Error(f"Argoverse 2 file not found: {path}")
    try:
        table = feather.read_table(path)
    except (pa.ArrowInvalid, OSError) as error:
        raise Av2Error(f"{path}: not a readable feather file ({error})") from None
    missing = [name for name in columns if name not in table.column_names]
    if missing:
        raise Av2Error(f"{path}: columns {missing} missing (has {table.column_names})")
    return {name: table[name].to_numpy(zero_copy_only=False) for name in columns}


_POSE_COLUMNS = ("qw", "qx", "qy", "qz", "tx_m", "ty_m", "tz_m")


def _poses(table: dict[str, np.ndarray], path: Path) -> FloatArray:
    """(N, 4, 4) rigid transforms from the qw, qx, qy, qz, tx_m, ty_m, tz_m columns."""
    values = np.stack([table[name].astype(np.float64) for name in _POSE_COLUMNS], axis=-1)
    bad = np.flatnonzero(~np.all(np.isfinite(values), axis=1))
    if bad.size:
        raise Av2Error(f"{path}: row {bad[0]} has a NaN or infinite pose")
    norms = np.linalg.norm(values[:, :4], axis=1)
    if np.any(np.abs(norms - 1.0) > 1e-3):
        raise Av2Error(f"{path}: row {np.flatnonzero(np.abs(norms - 1.0) > 1e-3)[0]} has a non-unit quaternion")
    poses = np.tile(np.eye(4), (values.shape[0], 1, 1))
    quaternions_xyzw = values[:, [1, 2, 3, 0]] / norms[:, None]
    poses[:, :3, :3] = Rotation.from_quat(quaternions_xyzw).as_matrix()
    poses[:, :3, 3] = values[:, 4:7]
    return poses


def _annotations_path(log_dir: Path) -> Path:
    for name in ("annotations.feather", "annotations_with_ego.feather"):
        if (log_dir / name).is_file():
            return log_dir / name
    raise Av2Error(f"{log_dir}: no annotations.feather or annotations_with_ego.feather")


def _ego_poses_at(log_dir: Path, stamps: IntArray) -> FloatArray:
    path = log_dir / "city_SE3_egovehicle.feather"
    table = _read_table(path, ("timestamp_ns", *_POSE_COLUMNS))
    pose_stamps = table["timestamp_ns"].astype(np.int64)
    poses = _poses(table, path)
    index = {int(stamp): row for row, stamp in enumerate(pose_stamps.tolist())}
    missing = [int(stamp) for stamp in stamps.tolist() if int(stamp) not in index]
    if missing:
        raise Av2Error(f"{path}: no ego pose at annotated LiDAR time {missing[0]} ns ({len(missing)} such times)")
    return poses[[index[int(stamp)] for stamp in stamps.tolist()]]


def _tracks(
    annotations: dict[str, np.ndarray], path: Path, frames: IntArray, ego_poses: FloatArray
) -> tuple[tuple[ActorTrack, ...], FloatArray | None]:
    """Actor tracks in the city frame, ordered by first appearance; and the ego's (l, w, h) when labelled."""
    stamps = annotations["timestamp_ns"].astype(np.int64)
    categories = annotations["category"].astype(str)
    uuids = annotations["track_uuid"].astype(str)
    sizes = np.stack([annotations[name].astype(np.float64) for name in ("length_m", "width_m", "height_m")], axis=-1)
    boxes_ego = _poses(annotations, path)
    frame_of = np.searchsorted(frames, stamps)
    world = ego_poses[frame_of] @ boxes_ego  # T_city_box = T_city_ego @ T_ego_box
    is_ego = categories == AV2_EGO_CATEGORY
    ego_size = np.median(sizes[is_ego], axis=0) if np.any(is_ego) else None
    order = np.lexsort((uuids, stamps))  # by time, then uuid: first appearance order is deterministic
    first_seen: dict[str, int] = {}
    for row in order.tolist():
        if not is_ego[row]:
            first_seen.setdefault(uuids[row], row)
    tracks = []
    for uuid in first_seen:
        rows = np.flatnonzero(uuids == uuid)
        rows = rows[np.argsort(stamps[rows], kind="stable")]
        kinds = set(categories[rows].tolist())
        if len(kinds) != 1:
            raise Av2Error(f"{path}: track {uuid} changes category: {sorted(kinds)}")
        if np.any(np.diff(stamps[rows]) <= 0):
            raise Av2Error(f"{path}: track {uuid} is labelled twice at one time")
        transforms = world[rows]
        tracks.append(
            ActorTrack(
                actor_id=uuid,
                actor_class=AV2_CLASSES.get(categories[rows[0]], ActorClass.OTHER),
                size=np.median(sizes[rows], axis=0),  # AV2 cuboid sizes are fixed per track; median if not
                stamps_ns=stamps[rows],
                centers=transforms[:, :3, 3],
                yaws=np.arctan2(transforms[:, 1, 0], transforms[:, 0, 0]),
            )
        )
    return tuple(tracks), ego_size


def _xy(points: list[dict[str, float]], where: str) -> FloatArray:
    try:
        array = np.array([[point["x"], point["y"]] for point in points], dtype=np.float64)
    except (KeyError, TypeError) as error:
        raise Av2Error(f"{where}: points need x and y ({error})") from None
    if array.ndim != 2 or not np.all(np.isfinite(array)):
        raise Av2Error(f"{where}: NaN, infinite or missing coordinates")
    return array


def _resample(polyline: FloatArray, count: int) -> FloatArray:
    """``count`` points evenly spaced by arc length along the polyline."""
    steps = np.linalg.norm(np.diff(polyline, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    if arc[-1] <= 0.0:
        return np.repeat(polyline[:1], count, axis=0)
    targets = np.linspace(0.0, arc[-1], count)
    return np.stack([np.interp(targets, arc, polyline[:, axis]) for axis in range(2)], axis=-1)


def lane_centerline(left: FloatArray, right: FloatArray) -> FloatArray:
    """The midline of a lane from its left and right boundaries (both in driving direction) [m]."""
    length = max(float(np.linalg.norm(np.diff(boundary, axis=0), axis=1).sum()) for boundary in (left, right))
    count = max(2, len(left), len(right), int(np.ceil(length / AV2_CENTERLINE_SPACING)) + 1)
    return 0.5 * (_resample(left, count) + _resample(right, count))


def load_av2_map(log_dir: Path) -> RoadMap:
    """Drivable areas and vehicle/bus lane centrelines from the log's map/log_map_archive_*.json."""
    archives = sorted((log_dir / "map").glob("log_map_archive_*.json"))
    if not archives:
        raise Av2Error(f"{log_dir / 'map'}: no log_map_archive_*.json vector map")
    path = archives[0]
    try:
        # The dataset's JSON as parsed (untyped like any JSON document): every value is checked where it is read
        data: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as error:
        raise Av2Error(f"{path}: not a readable JSON map ({error})") from None
    areas = []
    for key, area in sorted(data.get("drivable_areas", {}).items()):
        outline = _xy(area.get("area_boundary", []), f"{path} drivable area {key}")
        if len(outline) > 3 and np.array_equal(outline[0], outline[-1]):
            outline = outline[:-1]  # closed outline: RoadMap polygons do not repeat the first vertex
        if len(outline) >= 3:
            areas.append(outline)
    lanes = []
    for key, lane in sorted(data.get("lane_segments", {}).items()):
        if lane.get("lane_type") not in AV2_LANE_TYPES:
            continue
        left = _xy(lane.get("left_lane_boundary", []), f"{path} lane segment {key} left boundary")
        right = _xy(lane.get("right_lane_boundary", []), f"{path} lane segment {key} right boundary")
        if len(left) < 2 or len(right) < 2:
            raise Av2Error(f"{path}: lane segment {key} has a boundary with fewer than 2 points")
        lanes.append(lane_centerline(left, right))
    return RoadMap(drivable_areas=tuple(areas), lane_centerlines=tuple(lanes))


def _read_sweep(path: Path) -> np.ndarray:
    """An AV2 LiDAR feather as a structured array; float16 coordinates widen exactly to float32."""
    try:
        table = feather.read_table(path)
    except (pa.ArrowInvalid, OSError) as error:
        raise Av2Error(f"{path}: not a readable feather file ({error})") from None
    missing = [name for name in ("x", "y", "z") if name not in table.column_names]
    if missing:
        raise Av2Error(f"{path}: LiDAR sweep without {missing} column(s) (has {table.column_names})")
    columns = {name: table[name].to_numpy(zero_copy_only=False) for name in table.column_names}
    dtype = []
    for name, values in columns.items():
        kind = np.dtype(np.float32) if values.dtype == np.float16 else values.dtype
        if kind.kind not in "iuf" or kind.itemsize > 8 or (kind.kind in "iu" and kind.itemsize == 8):
            raise Av2Error(f"{path}: column {name} of type {values.dtype} cannot go into a PointCloud2")
        dtype.append((name, kind.newbyteorder("<")))
    points = np.empty(table.num_rows, dtype=dtype)
    for name, values in columns.items():
        points[name] = values
    return points


def load_av2_log(log_dir: Path) -> Scenario:
    """An Argoverse 2 log as a Scenario: tracks, ego poses and map in the city frame; sweeps where present."""
    log_dir = Path(log_dir)
    if not log_dir.is_dir():
        raise Av2Error(f"Argoverse 2 log folder not found: {log_dir}")
    annotations_path = _annotations_path(log_dir)
    annotations = _read_table(
        annotations_path,
        ("timestamp_ns", "track_uuid", "category", "length_m", "width_m", "height_m", *_POSE_COLUMNS),
    )
    frames = np.unique(annotations["timestamp_ns"].astype(np.int64))
    if frames.size == 0:
        raise Av2Error(f"{annotations_path}: no annotations")
    ego_poses = _ego_poses_at(log_dir, frames)
    actors, ego_size = _tracks(annotations, annotations_path, frames, ego_poses)
    frame_index = {int(stamp): index for index, stamp in enumerate(frames.tolist())}
    sweeps = []
    dropped = DroppedPoints()
    for path in sorted((log_dir / "sensors" / "lidar").glob("*.feather")):
        try:
            stamp = int(path.stem)
        except ValueError:
            raise Av2Error(f"{path}: LiDAR files are named <timestamp_ns>.feather") from None
        if stamp not in frame_index:
            raise Av2Error(f"{path}: sweep at {stamp} ns is not an annotated frame of this log")
        sweeps.append(
            Sweep(
                stamp_ns=stamp,
                frame_id=AV2_SENSOR_FRAME,
                points=dropped.keep_finite(_read_sweep(path)),
                sensor_pose=ego_poses[frame_index[stamp]],
            )
        )
    dropped.report(log, f"Argoverse 2 log {log_dir}")
    return Scenario(
        scenario_id=f"av2_{log_dir.name}",
        frame_stamps_ns=frames,
        ego=EgoTrajectory(stamps_ns=frames, poses=ego_poses),
        actors=actors,
        sweeps=tuple(sweeps),
        ego_T_sensor=np.eye(4),
        sensor=None,
        road_map=load_av2_map(log_dir),
        ego_geometry=EgoGeometry(np.array(AV2_EGO_SIZE) if ego_size is None else ego_size),
    )
