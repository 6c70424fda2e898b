"""KITTI tracking importer (Geiger et al., "Are we ready for autonomous driving?", CVPR 2012).

Standard layout under ``root``::

    velodyne/<seq>/000000.bin ...   float32 x, y, z, intensity in the Velodyne frame
      (or velodyne.tar.xz holding velodyne/<seq>/*.bin: unpacked once into the cache)
    label_02/<seq>.txt              tracks in the rectified camera frame
    calib/<seq>.txt                 P0..P3, R0_rect (R_rect), Tr_velo_to_cam (Tr_velo_cam), Tr_imu_to_velo
    poses/<seq>_*velo*.txt          T_world_velo per sweep, 3x4 row-major (e.g. from LiDAR odometry)
      or poses/<seq>_*cam0*.txt     T_world_cam0 per sweep (rectified left camera, KITTI odometry style)

Frames: "sensor" is the Velodyne frame; "ego" is the Velodyne frame moved straight down
to the ground (the HDL-64E sits 1.73 m above the road); "world" is the Velodyne frame of
the first sweep, as the poses define it. Boxes go from the rectified camera frame into
the Velodyne frame through the calibration, then into the world frame through the
sweep's pose. Sweeps are 10 Hz; label frame n is sweep n. DontCare labels are dropped.
"""

from __future__ import annotations

import hashlib
import logging
import lzma
import re
import shutil
import tarfile
import tempfile
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from advsim_ros.contract.pointcloud import DroppedPoints
from advsim_ros.core.types import (
    ActorClass,
    ActorTrack,
    EgoGeometry,
    EgoTrajectory,
    FloatArray,
    Scenario,
    ScenarioError,
    SensorModel,
    Sweep,
)
from advsim_ros.io.cache import cache_root

log = logging.getLogger(__name__)

KITTI_FRAME_PERIOD_NS = 100_000_000  # 10 Hz Velodyne [ns]
# KITTI tracking has no per-frame timestamps; frame n is stamped KITTI_START_NS + n * period.
# The start is 1 s rather than 0 because ROS treats time 0 as "not set" under simulated time.
KITTI_START_NS = 1_000_000_000
KITTI_VELODYNE_HEIGHT = 1.73  # Velodyne above the road [m] (KITTI sensor setup)
KITTI_EGO_SIZE = (4.71, 1.82, 1.47)  # VW Passat B6 estate, length, width, height [m]
KITTI_SENSOR_FRAME = "velodyne"
KITTI_BIN_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])

KITTI_CLASSES: dict[str, ActorClass] = {
    "Car": ActorClass.VEHICLE,
    "Van": ActorClass.VEHICLE,
    "Truck": ActorClass.VEHICLE,
    "Tram": ActorClass.VEHICLE,
    "Pedestrian": ActorClass.PEDESTRIAN,
    "Person_sitting": ActorClass.PEDESTRIAN,
    "Person": ActorClass.PEDESTRIAN,
    "Cyclist": ActorClass.CYCLIST,
    "Misc": ActorClass.OTHER,
}


def hdl64e_sensor_model() -> SensorModel:
    """Velodyne HDL-64E S2 as in KITTI: 64 beams from +2 to -24.33 deg, 10 Hz, 0.9..120 m."""
    upper = np.linspace(2.0, -8.33, 32)  # upper block, ~1/3 deg apart [deg]
    lower = np.linspace(-8.83, -24.33, 32)  # lower block, 1/2 deg apart [deg]
    return SensorModel(
        beam_elevations=np.deg2rad(np.concatenate([upper, lower])),
        azimuth_resolution=float(np.deg2rad(0.1728)),  # 2083 firings per turn at 10 Hz
        min_range=0.9,
        max_range=120.0,
    )


class KittiError(ScenarioError):
    """KITTI input that is missing, malformed or inconsistent; the message names the file."""


@dataclass(frozen=True)
class KittiLabel:
    """One KITTI tracking label row, in the rectified camera frame (x right, y down, z forward)."""

    frame: int
    track_id: int
    kind: str  # KITTI class name, e.g. "Car"
    hwl: tuple[float, float, float]  # box height, width, length [m]
    location: tuple[float, float, float]  # bottom-centre of the box [m]
    rotation_y: float  # rotation about the camera y axis [rad]


def read_kitti_calibration(path: Path) -> FloatArray:
    """T_rect_velo (4, 4): Velodyne frame -> rectified camera-0 frame, R0_rect @ Tr_velo_to_cam."""
    if not path.is_file():
        raise KittiError(f"KITTI calibration file not found: {path}")
    entries: dict[str, FloatArray] = {}
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        key, _, values = line.partition(":") if ":" in line else line.partition(" ")
        try:
            entries[key.strip()] = np.array(values.split(), dtype=np.float64)
        except ValueError as error:
            raise KittiError(f"{path} line {number}: not a list of numbers ({error})") from None
    rect = entries.get("R0_rect", entries.get("R_rect"))
    velo_to_cam = entries.get("Tr_velo_to_cam", entries.get("Tr_velo_cam"))
    if rect is None or rect.size != 9:
        raise KittiError(f"{path}: needs R0_rect (or R_rect) with 9 numbers")
    if velo_to_cam is None or velo_to_cam.size != 12:
        raise KittiError(f"{path}: needs Tr_velo_to_cam (or Tr_velo_cam) with 12 numbers")
    rect_4 = np.eye(4)
    rect_4[:3, :3] = rect.reshape(3, 3)
    cam_velo = np.eye(4)
    cam_velo[:3, :] = velo_to_cam.reshape(3, 4)
    transform: FloatArray = rect_4 @ cam_velo
    if not np.all(np.isfinite(transform)):
        raise KittiError(f"{path}: calibration contains NaN or infinite values")
    return transform


def read_kitti_labels(path: Path) -> list[KittiLabel]:
    """Every non-DontCare row of a KITTI tracking label file."""
    if not path.is_file():
        raise KittiError(f"KITTI label file not found: {path}")
    labels: list[KittiLabel] = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        columns = line.split()
        if not columns:
            continue
        if len(columns) < 17:
            raise KittiError(f"{path} line {number}: expected 17 columns, got {len(columns)}")
        kind = columns[2]
        if kind == "DontCare":
            continue
        if kind not in KITTI_CLASSES:
            raise KittiError(f"{path} line {number}: unknown class {kind!r}")
        try:
            frame, track_id = int(columns[0]), int(columns[1])
            numbers = [float(value) for value in columns[10:17]]
        except ValueError as error:
            raise KittiError(f"{path} line {number}: {error}") from None
        if not np.all(np.isfinite(numbers)):
            raise KittiError(f"{path} line {number}: box contains NaN or infinite values")
        height, width, length = numbers[0:3]
        if min(height, width, length) <= 0:
            raise KittiError(f"{path} line {number}: box size must be positive, got h,w,l {height, width, length}")
        if frame < 0 or track_id < 0:
            raise KittiError(f"{path} line {number}: negative frame or track id")
        labels.append(
            KittiLabel(
                frame=frame,
                track_id=track_id,
                kind=kind,
                hwl=(height, width, length),
                location=(numbers[3], numbers[4], numbers[5]),
                rotation_y=numbers[6],
            )
        )
    return labels


def nearest_rotation(matrices: FloatArray) -> FloatArray:
    """The closest proper rotations (Frobenius norm) to (..., 3, 3) near-rotations, via SVD."""
    u, _, vt = np.linalg.svd(matrices)
    det = np.linalg.det(u @ vt)
    fix = np.ones(matrices.shape[:-1])
    fix[..., -1] = det
    rotations: FloatArray = (u * fix[..., None, :]) @ vt
    return rotations


def read_kitti_poses(path: Path, frame: str, T_rect_velo: FloatArray) -> FloatArray:
    """(F, 4, 4) T_world_velo, world = the Velodyne frame of the first sweep.

    ``frame`` says what the rows of the file describe: "velo" (T_world_velo) or "cam0"
    (T_world_cam0 of the rectified left camera, as KITTI odometry and stereo SLAM give).
    Rotations are snapped to the nearest rotation matrix (the files carry 9 decimals).
    """
    if not path.is_file():
        raise KittiError(f"KITTI poses file not found: {path}")
    rows: list[list[float]] = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        try:
            values = [float(value) for value in line.split()]
        except ValueError as error:
            raise KittiError(f"{path} line {number}: {error}") from None
        if len(values) != 12:
            raise KittiError(f"{path} line {number}: expected 12 numbers (3x4 row-major), got {len(values)}")
        if not np.all(np.isfinite(values)):
            raise KittiError(f"{path} line {number}: pose contains NaN or infinite values")
        rows.append(values)
    if not rows:
        raise KittiError(f"{path}: no poses")
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    poses[:, :3, :] = np.asarray(rows).reshape(-1, 3, 4)
    rotation_error = np.abs(np.swapaxes(poses[:, :3, :3], 1, 2) @ poses[:, :3, :3] - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero(rotation_error > 1e-3)
    if bad.size:
        worst = rotation_error[bad[0]]
        raise KittiError(f"{path} line {bad[0] + 1}: not a rigid transform (rotation off by {worst:.3g})")
    if frame == "cam0":
        poses = np.linalg.inv(T_rect_velo) @ poses @ T_rect_velo
    elif frame != "velo":
        raise KittiError(f"poses frame must be 'velo' or 'cam0', got {frame!r}")
    poses = np.linalg.inv(poses[0]) @ poses  # world = the first sweep's Velodyne frame
    poses[:, :3, :3] = nearest_rotation(poses[:, :3, :3])
    poses[:, 3, :] = (0.0, 0.0, 0.0, 1.0)
    result: FloatArray = poses
    return result


def find_kitti_poses(root: Path, seq: str) -> Path:
    """The sequence's poses file under root/poses: LiDAR odometry first, then camera poses."""
    folder = root / "poses"
    candidates = sorted(folder.glob(f"{seq}_*velo*.txt")) + sorted(folder.glob(f"{seq}_*cam0*.txt"))
    if (folder / f"{seq}.txt").is_file():
        candidates.append(folder / f"{seq}.txt")
    if not candidates:
        raise KittiError(
            f"no poses file for sequence {seq} under {folder} (expected {seq}_*velo*.txt or {seq}_*cam0*.txt); "
            "pass one explicitly"
        )
    return candidates[0]


def poses_frame_of(path: Path) -> str:
    """'velo' or 'cam0' from the poses file name; a bare <seq>.txt is KITTI odometry style (cam0)."""
    name = path.stem.lower()
    if "velo" in name:
        return "velo"
    if "cam" in name or re.fullmatch(r"\d+", name):
        return "cam0"
    raise KittiError(f"cannot tell the frame of poses file {path}: name it *_velo.txt or *_cam0.txt")


def _archive_cache_dir(archive: Path) -> Path:
    stat = archive.stat()
    key = hashlib.sha256(f"{archive.resolve()}|{stat.st_size}|{stat.st_mtime_ns}".encode()).hexdigest()[:16]
    return cache_root() / "kitti" / key


def _unpack_sequence(archive: Path, seq: str) -> Path:
    """Unpack velodyne/<seq>/*.bin from the archive into the cache once; returns the folder of .bin files."""
    target = _archive_cache_dir(archive) / seq
    if target.is_dir():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{seq}.", dir=target.parent))
    prefix = f"velodyne/{seq}/"
    try:
        with tarfile.open(archive, "r:*") as tar:
            for member in tar:
                name = member.name.removeprefix("./")
                if not (member.isfile() and name.startswith(prefix) and name.endswith(".bin")):
                    continue
                source = tar.extractfile(member)
                assert source is not None
                with source, (staging / Path(name).name).open("wb") as sink:
                    shutil.copyfileobj(source, sink, length=1 << 20)
        try:
            staging.rename(target)
        except OSError:
            if not target.is_dir():  # another process finished first otherwise
                raise
    except (tarfile.TarError, lzma.LZMAError, EOFError) as error:
        raise KittiError(f"Velodyne archive {archive} is unreadable or truncated: {error}") from None
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
    return target


def kitti_velodyne_dir(root: Path, seq: str) -> Path:
    """The folder holding the sequence's .bin sweeps: root/velodyne/<seq>, or unpacked from velodyne.tar.xz."""
    plain = root / "velodyne" / seq
    if plain.is_dir():
        return plain
    for archive in (root / "velodyne.tar.xz", root / "velodyne.tar"):
        if archive.is_file():
            return _unpack_sequence(archive, seq)
    raise KittiError(f"no Velodyne sweeps for sequence {seq}: neither {plain} nor {root / 'velodyne.tar.xz'} exists")


def read_velodyne_bin(path: Path) -> np.ndarray:
    """A KITTI .bin sweep as a structured float32 x, y, z, intensity array."""
    size = path.stat().st_size
    if size % KITTI_BIN_DTYPE.itemsize:
        raise KittiError(f"{path}: {size} bytes is not a whole number of 16-byte points (truncated?)")
    return np.fromfile(path, dtype=KITTI_BIN_DTYPE)


def _sweep_files(folder: Path) -> list[Path]:
    files = sorted(folder.glob("*.bin"))
    if not files:
        raise KittiError(f"no .bin sweeps in {folder}")
    for index, file in enumerate(files):
        if file.stem != f"{index:06d}":
            raise KittiError(f"{folder}: sweep files must be numbered 000000.bin upwards; {file.name} is sweep {index}")
    return files


def _box_in_velodyne(label: KittiLabel, T_velo_rect: FloatArray) -> tuple[FloatArray, float]:
    """Box centre (3,) [m] and yaw [rad] in the Velodyne frame from a label in the rectified camera frame."""
    height = label.hwl[0]
    center_rect = np.array([label.location[0], label.location[1] - height / 2.0, label.location[2], 1.0])
    heading_rect = np.array([np.cos(label.rotation_y), 0.0, -np.sin(label.rotation_y)])  # camera y points down
    center = (T_velo_rect @ center_rect)[:3]
    heading = T_velo_rect[:3, :3] @ heading_rect
    return center, float(np.arctan2(heading[1], heading[0]))


def _tracks_from_labels(
    labels: list[KittiLabel], T_velo_rect: FloatArray, T_world_velo: FloatArray, stamps_ns: np.ndarray
) -> tuple[ActorTrack, ...]:
    by_track: dict[int, list[KittiLabel]] = defaultdict(list)
    for label in labels:
        by_track[label.track_id].append(label)
    tracks: list[ActorTrack] = []
    for track_id in sorted(by_track):
        rows = sorted(by_track[track_id], key=lambda label: label.frame)
        frames = [row.frame for row in rows]
        if len(set(frames)) != len(frames):
            raise KittiError(f"KITTI track {track_id} is labelled twice in one frame")
        kinds = {row.kind for row in rows}
        if len({KITTI_CLASSES[kind] for kind in kinds}) != 1:
            raise KittiError(f"KITTI track {track_id} changes class: {sorted(kinds)}")
        centers = np.empty((len(rows), 3))
        yaws = np.empty(len(rows))
        for index, row in enumerate(rows):
            center_velo, yaw_velo = _box_in_velodyne(row, T_velo_rect)
            pose = T_world_velo[row.frame]
            centers[index] = pose[:3, :3] @ center_velo + pose[:3, 3]
            heading = pose[:3, :3] @ np.array([np.cos(yaw_velo), np.sin(yaw_velo), 0.0])
            yaws[index] = np.arctan2(heading[1], heading[0])
        hwl = np.median(np.array([row.hwl for row in rows]), axis=0)  # constant per track in KITTI; median if not
        tracks.append(
            ActorTrack(
                actor_id=str(track_id),
                actor_class=KITTI_CLASSES[rows[0].kind],
                size=np.array([hwl[2], hwl[1], hwl[0]]),
                stamps_ns=stamps_ns[frames],
                centers=centers,
                yaws=yaws,
            )
        )
    return tuple(sorted(tracks, key=lambda track: int(track.stamps_ns[0])))  # bag order: by first appearance


def load_kitti_tracking(root: Path, seq: str, poses: Path | None = None, *, poses_frame: str | None = None) -> Scenario:
    """A KITTI tracking sequence as a Scenario (sweeps, ego poses, tracks; no map).

    ``poses`` defaults to the sequence's file under root/poses; ``poses_frame`` ("velo"
    or "cam0") defaults to what the file name says. Raises KittiError (a ScenarioError)
    naming the file for missing, malformed or inconsistent input.
    """
    root = Path(root)
    if not re.fullmatch(r"\d{4}", seq):
        raise KittiError(f"KITTI sequence must be four digits like 0000, got {seq!r}")
    if not root.is_dir():
        raise KittiError(f"KITTI root folder not found: {root}")
    T_rect_velo = read_kitti_calibration(root / "calib" / f"{seq}.txt")
    T_velo_rect = np.asarray(np.linalg.inv(T_rect_velo), dtype=np.float64)
    labels = read_kitti_labels(root / "label_02" / f"{seq}.txt")
    poses_path = Path(poses) if poses is not None else find_kitti_poses(root, seq)
    T_world_velo = read_kitti_poses(poses_path, poses_frame or poses_frame_of(poses_path), T_rect_velo)
    sweep_files = _sweep_files(kitti_velodyne_dir(root, seq))
    count = len(sweep_files)
    if T_world_velo.shape[0] != count:
        raise KittiError(f"{poses_path} has {T_world_velo.shape[0]} poses but sequence {seq} has {count} sweeps")
    late = [label for label in labels if label.frame >= count]
    if late:
        raise KittiError(
            f"label file {root / 'label_02' / f'{seq}.txt'} does not match the sweeps: it labels frame "
            f"{max(label.frame for label in late)} but sequence {seq} has only {count} sweeps"
        )
    stamps = KITTI_START_NS + KITTI_FRAME_PERIOD_NS * np.arange(count, dtype=np.int64)
    ego_T_sensor = np.eye(4)
    ego_T_sensor[2, 3] = KITTI_VELODYNE_HEIGHT
    dropped = DroppedPoints()
    sweeps = tuple(
        Sweep(
            stamp_ns=int(stamps[index]),
            frame_id=KITTI_SENSOR_FRAME,
            points=dropped.keep_finite(read_velodyne_bin(file)),
            sensor_pose=T_world_velo[index],
        )
        for index, file in enumerate(sweep_files)
    )
    dropped.report(log, f"KITTI {kitti_velodyne_dir(root, seq)}")
    return Scenario(
        scenario_id=f"kitti_tracking_{seq}",
        frame_stamps_ns=stamps,
        ego=EgoTrajectory(stamps_ns=stamps, poses=T_world_velo @ np.linalg.inv(ego_T_sensor)),
        actors=_tracks_from_labels(labels, T_velo_rect, T_world_velo, stamps),
        sweeps=sweeps,
        ego_T_sensor=ego_T_sensor,
        sensor=hdl64e_sensor_model(),
        road_map=None,
        ego_geometry=EgoGeometry(np.array(KITTI_EGO_SIZE)),
    )


__all__ = [
    "KITTI_FRAME_PERIOD_NS",
    "KITTI_START_NS",
    "KittiError",
    "KittiLabel",
    "hdl64e_sensor_model",
    "kitti_velodyne_dir",
    "load_kitti_tracking",
    "read_kitti_calibration",
    "read_kitti_labels",
    "read_kitti_poses",
    "read_velodyne_bin",
]
