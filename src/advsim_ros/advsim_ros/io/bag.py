"""Scenarios as rosbag2 bags: MCAP written, MCAP and sqlite3 read, with the rosbags library.

A scenario bag is a rosbag2 folder (metadata.yaml + storage file, as ``ros2 bag record``
makes them) holding, per frame, /clock, the ego pose (nav_msgs/Odometry and /tf), the
actor tracks (advsim_msgs/ActorTrackArray) and, where the log has LiDAR, the sweep
(sensor_msgs/PointCloud2 in the sensor frame); once, the sensor mount (/tf_static), the
map (advsim_msgs/RoadMap) and what else rebuilds the scenario (advsim_msgs/ScenarioInfo).
Every type's definition is stored in the bag, so it is self-describing. Topic names and
frames come from params/bag.yaml (``BagConfig``); docs/data.md documents the format.

Users' own bags need only the LiDAR topic and the ego pose (odometry or /tf): frames are
then the sweeps' stamps and the ego pose is interpolated to them.
"""

from __future__ import annotations

import functools
import os
import shutil
import struct
import tempfile
from collections import defaultdict
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.interfaces import (
    Connection,
    MessageDefinitionFormat,
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.rosbag2.errors import ReaderError
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import TypesysError
from rosbags.typesys.store import Typestore
from scipy.spatial.transform import Rotation, Slerp

from advsim_ros.core.params import config_from_mapping, load_node_params
from advsim_ros.core.types import (
    ActorClass,
    ActorTrack,
    EgoTrajectory,
    FloatArray,
    IntArray,
    RoadMap,
    Scenario,
    ScenarioError,
    SensorModel,
    Sweep,
)
from advsim_ros.io.pointcloud import cloud_to_points, points_are_bigendian, points_to_cloud_fields

MSG_DIR_ENV = "ADVSIM_MSG_DIR"  # folder of advsim_msgs/msg/*.msg, overriding the search below
BAG_PARAMS_NODE = "**"  # params/bag.yaml applies to every node that reads or writes bags
SENSOR_POSE_TOLERANCE = 1e-6  # a sweep's pose may differ from ego pose @ ego_T_sensor by this much [m, 1]

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"
ODOMETRY = "nav_msgs/msg/Odometry"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
CLOCK = "rosgraph_msgs/msg/Clock"
ACTOR_TRACK_ARRAY = "advsim_msgs/msg/ActorTrackArray"
ROAD_MAP = "advsim_msgs/msg/RoadMap"
SCENARIO_INFO = "advsim_msgs/msg/ScenarioInfo"


class BagError(ScenarioError):
    """A bag that cannot be written or read as a scenario; the message names the bag and the problem."""


@dataclass(frozen=True)
class BagConfig:
    """Topic names and frames of scenario bags (params/bag.yaml, key ``bag``)."""

    lidar_topic: str = "/sensor/lidar/points"  # sensor_msgs/PointCloud2, any field layout with x, y, z
    odom_topic: str = "/ego/odom"  # nav_msgs/Odometry: pose of ego_frame in world_frame
    tracks_topic: str = "/actors/tracks"  # advsim_msgs/ActorTrackArray, one per frame
    map_topic: str = "/map/road"  # advsim_msgs/RoadMap, once, transient-local
    info_topic: str = "/scenario/info"  # advsim_msgs/ScenarioInfo, once, transient-local
    clock_topic: str = "/clock"  # rosgraph_msgs/Clock, one per frame
    tf_topic: str = "/tf"  # tf2_msgs/TFMessage: world_frame -> ego_frame per frame
    tf_static_topic: str = "/tf_static"  # tf2_msgs/TFMessage: ego_frame -> sensor frame
    world_frame: str = "world"  # fixed frame of poses, tracks and map
    ego_frame: str = "base_link"  # vehicle base frame
    sensor_frame: str = ""  # LiDAR frame; "" means the frame_id in the PointCloud2 headers
    ego_pose_source: str = "odom"  # where users' bags carry the ego pose: "odom" or "tf"
    storage: str = "mcap"  # storage written: "mcap" (or "sqlite3"); both are read
    compress: bool = False  # zstd-compress MCAP chunks (LiDAR floats shrink little; off for speed)

    def __post_init__(self) -> None:
        for name in ("lidar_topic", "odom_topic", "tracks_topic", "map_topic", "info_topic", "clock_topic"):
            _check_topic(name, getattr(self, name))
        for name in ("tf_topic", "tf_static_topic"):
            _check_topic(name, getattr(self, name))
        for name in ("world_frame", "ego_frame"):
            frame = getattr(self, name)
            if not frame or frame.startswith("/"):
                raise BagError(f"BagConfig {name}: must be a frame name without a leading '/', got {frame!r}")
        if self.sensor_frame.startswith("/"):
            raise BagError(f"BagConfig sensor_frame: no leading '/', got {self.sensor_frame!r}")
        if self.world_frame == self.ego_frame:
            raise BagError("BagConfig: world_frame and ego_frame must differ")
        if self.ego_pose_source not in ("odom", "tf"):
            raise BagError(f"BagConfig ego_pose_source: must be 'odom' or 'tf', got {self.ego_pose_source!r}")
        if self.storage not in ("mcap", "sqlite3"):
            raise BagError(f"BagConfig storage: must be 'mcap' or 'sqlite3', got {self.storage!r}")


def _check_topic(name: str, topic: str) -> None:
    if not topic.startswith("/") or topic.endswith("/") or " " in topic:
        raise BagError(f"BagConfig {name}: must be an absolute topic name like /a/b, got {topic!r}")


def load_bag_config(path: Path) -> BagConfig:
    """The ``bag`` parameters of a params file in the ROS shape (``/**: ros__parameters: bag: ...``)."""
    parameters = load_node_params(Path(path), BAG_PARAMS_NODE)
    section = parameters.get("bag")
    if not isinstance(section, dict):
        raise BagError(f"{path}: /{BAG_PARAMS_NODE} ros__parameters needs a 'bag' mapping")
    return config_from_mapping(BagConfig, section, f"{path} bag")


# ----------------------------------------------------------------------------- message types


def msg_definitions_dir() -> Path:
    """The folder of advsim_msgs/msg/*.msg: $ADVSIM_MSG_DIR, the source tree, or the installed share."""
    override = os.environ.get(MSG_DIR_ENV)
    candidates = [Path(override)] if override else []
    candidates += [parent / "msg_defs" / "advsim_msgs" / "msg" for parent in Path(__file__).resolve().parents]
    for candidate in candidates:
        if candidate.is_dir() and any(candidate.glob("*.msg")):
            return candidate
    installed = _installed_msg_dir()
    if installed is not None:
        return installed
    raise BagError(f"advsim_msgs message definitions not found (looked in {[str(c) for c in candidates]})")


def _installed_msg_dir() -> Path | None:
    """share/advsim_msgs/msg of an installed (colcon or venv) advsim_msgs, when ament_index can find it."""
    try:
        from ament_index_python.packages import get_package_share_directory

        folder = Path(get_package_share_directory("advsim_msgs")) / "msg"
    except (ImportError, LookupError, OSError, ValueError):  # not installed, or AMENT_PREFIX_PATH unset
        return None
    return folder if folder.is_dir() and any(folder.glob("*.msg")) else None


@functools.cache
def _advsim_typesdict() -> dict[str, Any]:
    types: dict[str, Any] = {}
    for path in sorted(msg_definitions_dir().glob("*.msg")):
        types.update(get_types_from_msg(path.read_text(encoding="utf-8"), f"advsim_msgs/msg/{path.stem}"))
    return types


def scenario_typestore() -> Typestore:
    """A fresh typestore: ROS 2 Jazzy's types plus advsim_msgs, registered from the .msg files."""
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(_advsim_typesdict())
    return store


# ----------------------------------------------------------------------------- small conversions


def time_msg(store: Typestore, stamp_ns: int) -> Any:
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return store.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)


def stamp_of(time: Any) -> int:
    return int(time.sec) * 1_000_000_000 + int(time.nanosec)


def header_msg(store: Typestore, stamp_ns: int, frame_id: str) -> Any:
    return store.types["std_msgs/msg/Header"](stamp=time_msg(store, stamp_ns), frame_id=frame_id)


def _quaternion(store: Typestore, rotation: FloatArray) -> Any:
    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    return store.types["geometry_msgs/msg/Quaternion"](x=float(x), y=float(y), z=float(z), w=float(w))


def _transform_msg(store: Typestore, matrix: FloatArray) -> Any:
    translation = store.types["geometry_msgs/msg/Vector3"](
        x=float(matrix[0, 3]), y=float(matrix[1, 3]), z=float(matrix[2, 3])
    )
    rotation = _quaternion(store, matrix[:3, :3])
    return store.types["geometry_msgs/msg/Transform"](translation=translation, rotation=rotation)


def pose_matrix(translation: Any, rotation: Any, what: str) -> FloatArray:
    """A 4x4 transform from ROS translation/position and quaternion; BagError for NaN or a zero quaternion."""
    values = np.array(
        [translation.x, translation.y, translation.z, rotation.x, rotation.y, rotation.z, rotation.w], dtype=np.float64
    )
    if not np.all(np.isfinite(values)):
        raise BagError(f"{what}: pose contains NaN or infinite values")
    norm = float(np.linalg.norm(values[3:]))
    if abs(norm - 1.0) > 1e-3:
        raise BagError(f"{what}: orientation quaternion has norm {norm:.6g}, not 1")
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_quat(values[3:] / norm).as_matrix()
    matrix[:3, 3] = values[:3]
    return matrix


def tf_stamped(store: Typestore, stamp_ns: int, parent: str, child: str, matrix: FloatArray) -> Any:
    return store.types["geometry_msgs/msg/TransformStamped"](
        header=header_msg(store, stamp_ns, parent), child_frame_id=child, transform=_transform_msg(store, matrix)
    )


def _gradient(values: FloatArray, times_s: FloatArray) -> FloatArray:
    """d values / dt along axis 0 [unit/s]; zeros when there is a single sample."""
    if values.shape[0] < 2:
        return np.zeros_like(values)
    result: FloatArray = np.gradient(values, times_s, axis=0)
    return result


def _qos(durability: QosDurability, depth: int, reliability: QosReliability = QosReliability.RELIABLE) -> Qos:
    zero = QosTime(sec=0, nsec=0)
    return Qos(
        history=QosHistory.KEEP_LAST,
        depth=depth,
        reliability=reliability,
        durability=durability,
        deadline=zero,
        lifespan=zero,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=zero,
        avoid_ros_namespace_conventions=False,
    )


# Offered QoS recorded per topic, as the attack graph publishes them (README, "The topic contract"),
# so that `ros2 bag play` republishes them the same way.
LATCHED_QOS = _qos(QosDurability.TRANSIENT_LOCAL, 1)  # info, map, /tf_static: late joiners still get them
STREAM_QOS = _qos(QosDurability.VOLATILE, 10)  # odometry, tracks
SENSOR_QOS = _qos(QosDurability.VOLATILE, 5, QosReliability.BEST_EFFORT)  # LiDAR as drivers publish it
CLOCK_QOS = _qos(QosDurability.VOLATILE, 1)
TF_QOS = _qos(QosDurability.VOLATILE, 100)  # as tf2's TransformBroadcaster


# ----------------------------------------------------------------------------- writing


def odometry_msgs(store: Typestore, scenario: Scenario, config: BagConfig) -> list[Any]:
    poses = scenario.ego.poses
    times_s = (scenario.frame_stamps_ns - scenario.frame_stamps_ns[0]) * 1e-9
    velocity_world = _gradient(poses[:, :3, 3], times_s)
    yaw_rate = _gradient(np.unwrap(scenario.ego.yaws), times_s)
    messages = []
    types = store.types
    for index, stamp in enumerate(scenario.frame_stamps_ns.tolist()):
        pose = poses[index]
        velocity = pose[:3, :3].T @ velocity_world[index]  # twist is in the child (ego) frame
        point = types["geometry_msgs/msg/Point"](x=float(pose[0, 3]), y=float(pose[1, 3]), z=float(pose[2, 3]))
        messages.append(
            types[ODOMETRY](
                header=header_msg(store, stamp, config.world_frame),
                child_frame_id=config.ego_frame,
                pose=types["geometry_msgs/msg/PoseWithCovariance"](
                    pose=types["geometry_msgs/msg/Pose"](position=point, orientation=_quaternion(store, pose[:3, :3])),
                    covariance=np.zeros(36),
                ),
                twist=types["geometry_msgs/msg/TwistWithCovariance"](
                    twist=types["geometry_msgs/msg/Twist"](
                        linear=types["geometry_msgs/msg/Vector3"](
                            x=float(velocity[0]), y=float(velocity[1]), z=float(velocity[2])
                        ),
                        angular=types["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=float(yaw_rate[index])),
                    ),
                    covariance=np.zeros(36),
                ),
            )
        )
    return messages


def actor_states(store: Typestore, actor: ActorTrack) -> list[Any]:
    """ActorState per observation; speed, curvature and acceleration are finite-difference estimates."""
    times_s = (actor.stamps_ns - actor.stamps_ns[0]) * 1e-9
    velocity = _gradient(actor.centers[:, :2], times_s)
    speed = velocity[:, 0] * np.cos(actor.yaws) + velocity[:, 1] * np.sin(actor.yaws)  # signed, along heading
    yaw_rate = _gradient(np.unwrap(actor.yaws), times_s)
    moving = np.abs(speed) > 0.5  # below ~0.5 m/s heading noise swamps the curvature estimate
    curvature = np.where(moving, yaw_rate / np.where(moving, speed, 1.0), 0.0)
    acceleration = _gradient(speed, times_s)
    state_type = store.types["advsim_msgs/msg/ActorState"]
    return [
        state_type(
            stamp=time_msg(store, stamp),
            x=float(actor.centers[index, 0]),
            y=float(actor.centers[index, 1]),
            z=float(actor.centers[index, 2]),
            yaw=float(actor.yaws[index]),
            velocity=float(speed[index]),
            curvature=float(curvature[index]),
            acceleration=float(acceleration[index]),
        )
        for index, stamp in enumerate(actor.stamps_ns.tolist())
    ]


def _track_array_msgs(store: Typestore, scenario: Scenario, config: BagConfig) -> list[Any]:
    """One ActorTrackArray per frame holding, for each actor seen then, its state at that frame."""
    per_frame: dict[int, list[Any]] = defaultdict(list)
    track_type = store.types["advsim_msgs/msg/ActorTrack"]
    for actor in scenario.actors:
        for stamp, state in zip(actor.stamps_ns.tolist(), actor_states(store, actor), strict=True):
            per_frame[stamp].append(
                track_type(
                    actor_id=actor.actor_id,
                    actor_class=actor.actor_class.value,
                    length=actor.length,
                    width=actor.width,
                    height=actor.height,
                    confidence=1.0,
                    states=[state],
                )
            )
    array_type = store.types[ACTOR_TRACK_ARRAY]
    return [
        array_type(header=header_msg(store, stamp, config.world_frame), query_id=0, tracks=per_frame.get(stamp, []))
        for stamp in scenario.frame_stamps_ns.tolist()
    ]


def _polyline(store: Typestore, points: FloatArray) -> Any:
    return store.types["advsim_msgs/msg/Polyline"](
        x=np.ascontiguousarray(points[:, 0], dtype=np.float64), y=np.ascontiguousarray(points[:, 1], dtype=np.float64)
    )


def road_map_msg(store: Typestore, road_map: RoadMap, stamp_ns: int, config: BagConfig) -> Any:
    return store.types[ROAD_MAP](
        header=header_msg(store, stamp_ns, config.world_frame),
        drivable_areas=[_polyline(store, area) for area in road_map.drivable_areas],
        lane_centerlines=[_polyline(store, lane) for lane in road_map.lane_centerlines],
    )


def sensor_frame_of(scenario: Scenario, config: BagConfig) -> str:
    frames = {sweep.frame_id for sweep in scenario.sweeps}
    if len(frames) > 1:
        raise BagError(f"scenario {scenario.scenario_id}: sweeps come in several frames {sorted(frames)}")
    if frames:
        return frames.pop()
    return config.sensor_frame or "lidar"


def info_msg(store: Typestore, scenario: Scenario, config: BagConfig, source: str) -> Any:
    sensor = scenario.sensor
    return store.types[SCENARIO_INFO](
        scenario_id=scenario.scenario_id,
        source=source,
        world_frame=config.world_frame,
        ego_frame=config.ego_frame,
        sensor_frame=sensor_frame_of(scenario, config),
        ego_to_sensor=_transform_msg(store, scenario.ego_T_sensor),
        ego_length=float(scenario.ego_size[0]),
        ego_width=float(scenario.ego_size[1]),
        ego_height=float(scenario.ego_size[2]),
        has_sensor_model=sensor is not None,
        beam_elevations=np.array(sensor.beam_elevations if sensor else [], dtype=np.float64),
        azimuth_resolution=float(sensor.azimuth_resolution) if sensor else 0.0,
        min_range=float(sensor.min_range) if sensor else 0.0,
        max_range=float(sensor.max_range) if sensor else 0.0,
    )


def cloud_msg(store: Typestore, sweep: Sweep) -> Any:
    points = np.ascontiguousarray(sweep.points)
    fields, point_step = points_to_cloud_fields(points)
    field_type = store.types["sensor_msgs/msg/PointField"]
    xyz_finite = bool(np.all(np.isfinite(sweep.xyz))) if points.shape[0] else True
    return store.types[POINTCLOUD2](
        header=header_msg(store, sweep.stamp_ns, sweep.frame_id),
        height=1,
        width=int(points.shape[0]),
        fields=[field_type(name=f.name, offset=f.offset, datatype=f.datatype, count=f.count) for f in fields],
        is_bigendian=points_are_bigendian(points),
        point_step=point_step,
        row_step=point_step * int(points.shape[0]),
        data=points.view(np.uint8).reshape(-1),
        is_dense=xyz_finite,
    )


def _check_sensor_poses(scenario: Scenario) -> None:
    """The bag carries sweep poses as ego pose @ ego_T_sensor (as TF does); refuse scenarios where that loses data."""
    frame_index = {stamp: index for index, stamp in enumerate(scenario.frame_stamps_ns.tolist())}
    for sweep in scenario.sweeps:
        expected = scenario.ego.poses[frame_index[sweep.stamp_ns]] @ scenario.ego_T_sensor
        error = float(np.abs(expected - sweep.sensor_pose).max())
        if error > SENSOR_POSE_TOLERANCE:
            raise BagError(
                f"scenario {scenario.scenario_id}: sweep at {sweep.stamp_ns} ns has a sensor pose that differs from "
                f"ego pose @ ego_T_sensor by {error:.3g}; a bag stores sweep poses only through the ego pose and TF"
            )


def _staging_dir(target: Path) -> Path:
    target.parent.mkdir(parents=True, exist_ok=True)
    return Path(tempfile.mkdtemp(prefix=f".{target.name}.partial-", dir=target.parent))


def publish_atomically(staged: Path, target: Path, overwrite: bool) -> None:
    """Move a finished file or folder into place; the old target (overwrite only) goes only after that succeeds."""
    if target.exists() or target.is_symlink():
        if not overwrite:
            raise BagError(f"{target} exists already; remove it or choose another output path")
        trash = Path(tempfile.mkdtemp(prefix=f".{target.name}.old-", dir=target.parent))
        os.replace(target, trash / target.name)
        try:
            os.replace(staged, target)
        except OSError:
            os.replace(trash / target.name, target)
            raise
        finally:
            shutil.rmtree(trash, ignore_errors=True)
    else:
        os.replace(staged, target)


def write_scenario_bag(
    scenario: Scenario,
    path: Path,
    *,
    config: BagConfig | None = None,
    source: str = "",
    overwrite: bool = False,
    extra: Sequence[tuple[str, str, int, bytes]] = (),
) -> Path:
    """Write the scenario as a rosbag2 folder at ``path`` (MCAP unless config.storage says sqlite3).

    ``extra`` adds messages beyond the scenario's own as (topic, message type, stamp [ns], CDR
    bytes), e.g. an attack's plan and score beside the scenario it produced.

    Written to a hidden folder beside ``path`` and renamed into place when complete, so
    no partial bag is ever left at ``path``. ``source`` says where the log came from
    (e.g. "kitti_tracking/0000"); it is stored in the ScenarioInfo message.
    """
    config = config or BagConfig()
    path = Path(path)
    if (path.exists() or path.is_symlink()) and not overwrite:
        raise BagError(f"{path} exists already; remove it or choose another output path")
    _check_sensor_poses(scenario)
    store = scenario_typestore()
    sensor_frame = sensor_frame_of(scenario, config)
    if sensor_frame in (config.world_frame, config.ego_frame) and scenario.sweeps:
        raise BagError(f"sensor frame {sensor_frame!r} must differ from world_frame and ego_frame")
    staging = _staging_dir(path)
    try:
        bag_dir = staging / path.name
        writer = Writer(
            bag_dir,
            version=Writer.VERSION_LATEST,
            storage_plugin=StoragePlugin.MCAP if config.storage == "mcap" else StoragePlugin.SQLITE3,
        )
        if config.compress:
            if config.storage != "mcap":
                raise BagError("BagConfig compress: only MCAP storage is compressed")
            writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        writer.set_custom_data("advsim_ros.scenario_id", scenario.scenario_id)
        writer.open()
        try:
            _write_messages(writer, store, scenario, config, source, sensor_frame)
            _write_extra(writer, store, extra)
        except BaseException:
            writer.abort()
            raise
        writer.close()
        publish_atomically(bag_dir, path, overwrite)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return path


def _write_messages(
    writer: Writer, store: Typestore, scenario: Scenario, config: BagConfig, source: str, sensor_frame: str
) -> None:
    def connect(topic: str, msgtype: str, qos: Qos) -> Connection:
        return writer.add_connection(topic, msgtype, typestore=store, offered_qos_profiles=[qos])

    info = connect(config.info_topic, SCENARIO_INFO, LATCHED_QOS)
    tf_static = connect(config.tf_static_topic, TF_MESSAGE, LATCHED_QOS)
    road_map = connect(config.map_topic, ROAD_MAP, LATCHED_QOS) if scenario.road_map is not None else None
    clock = connect(config.clock_topic, CLOCK, CLOCK_QOS)
    tf = connect(config.tf_topic, TF_MESSAGE, TF_QOS)
    odom = connect(config.odom_topic, ODOMETRY, STREAM_QOS)
    tracks = connect(config.tracks_topic, ACTOR_TRACK_ARRAY, STREAM_QOS)
    lidar = connect(config.lidar_topic, POINTCLOUD2, SENSOR_QOS)  # present even when empty: "log without LiDAR"

    def write(connection: Connection, stamp: int, message: Any, msgtype: str) -> None:
        writer.write(connection, stamp, store.serialize_cdr(message, msgtype))

    first = int(scenario.frame_stamps_ns[0])
    write(info, first, info_msg(store, scenario, config, source), SCENARIO_INFO)
    static = tf_stamped(store, first, config.ego_frame, sensor_frame, scenario.ego_T_sensor)
    write(tf_static, first, store.types[TF_MESSAGE](transforms=[static]), TF_MESSAGE)
    if road_map is not None and scenario.road_map is not None:
        write(road_map, first, road_map_msg(store, scenario.road_map, first, config), ROAD_MAP)
    sweeps = {sweep.stamp_ns: sweep for sweep in scenario.sweeps}
    odometry = odometry_msgs(store, scenario, config)
    track_arrays = _track_array_msgs(store, scenario, config)
    for index, stamp in enumerate(scenario.frame_stamps_ns.tolist()):
        write(clock, stamp, store.types[CLOCK](clock=time_msg(store, stamp)), CLOCK)
        ego_tf = tf_stamped(store, stamp, config.world_frame, config.ego_frame, scenario.ego.poses[index])
        write(tf, stamp, store.types[TF_MESSAGE](transforms=[ego_tf]), TF_MESSAGE)
        write(odom, stamp, odometry[index], ODOMETRY)
        write(tracks, stamp, track_arrays[index], ACTOR_TRACK_ARRAY)
        if stamp in sweeps:
            write(lidar, stamp, cloud_msg(store, sweeps[stamp]), POINTCLOUD2)


def _write_extra(writer: Writer, store: Typestore, extra: Sequence[tuple[str, str, int, bytes]]) -> None:
    connections: dict[tuple[str, str], Connection] = {}
    for topic, msgtype, stamp, raw in extra:
        if (topic, msgtype) not in connections:
            connections[(topic, msgtype)] = writer.add_connection(
                topic, msgtype, typestore=store, offered_qos_profiles=[STREAM_QOS]
            )
        writer.write(connections[(topic, msgtype)], int(stamp), raw)


# ----------------------------------------------------------------------------- reading


@dataclass(frozen=True)
class TopicSummary:
    """One topic of a bag as metadata.yaml lists it."""

    msgtype: str
    message_count: int


@dataclass(frozen=True)
class BagSummary:
    """What a bag holds, without decoding messages."""

    path: Path
    storage: str  # "mcap" or "sqlite3"
    topics: dict[str, TopicSummary] = field(default_factory=dict)
    start_ns: int = 0  # time of the first message [ns]
    end_ns: int = 0  # just after the last message (exclusive end) [ns]
    size_bytes: int = 0  # storage files on disk [bytes]


class _BagReader:
    """rosbags' Reader with errors turned into BagError and types from the bag and from advsim_msgs."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise BagError(f"bag not found: {self.path}")
        if self.path.is_dir() and not (self.path / "metadata.yaml").is_file():
            raise BagError(
                f"{self.path} has no metadata.yaml: not a rosbag2 folder, or a recording that was not closed "
                "(`ros2 bag reindex` rebuilds it)"
            )
        try:
            self.reader = Reader(self.path)
            self.reader.open()
        except (ReaderError, OSError, KeyError, ValueError, TypeError) as error:
            raise BagError(f"cannot open bag {self.path}, it is truncated or corrupt: {error}") from None
        self.store = self._typestore()

    def _typestore(self) -> Typestore:
        """The bag's own message definitions first (it is self-describing), then Jazzy's and advsim_msgs'."""
        store = get_typestore(Stores.EMPTY)
        for connection in self.reader.connections:
            if connection.msgdef.format != MessageDefinitionFormat.MSG or not connection.msgdef.data:
                continue  # IDL or no definition stored (older sqlite3 bags): the defaults below decode it
            try:
                store.register(get_types_from_msg(connection.msgdef.data, connection.msgtype))
            except TypesysError as error:
                raise BagError(
                    f"bag {self.path}: topic {connection.topic} type {connection.msgtype}: {error}"
                ) from None
        defaults = scenario_typestore().fielddefs
        store.register({name: value for name, value in defaults.items() if name not in store.fielddefs})
        return store

    def close(self) -> None:
        self.reader.close()

    def __enter__(self) -> _BagReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def connection(self, topic: str, msgtype: str, required: str = "") -> Connection | None:
        """The topic's connection; BagError when it has another type, or is missing and ``required`` says why."""
        matches = [c for c in self.reader.connections if c.topic == topic]
        if not matches:
            if required:
                available = sorted({f"{c.topic} ({c.msgtype})" for c in self.reader.connections})
                raise BagError(f"bag {self.path} has no {required} topic {topic}; it has {available}")
            return None
        if any(c.msgtype != msgtype for c in matches):
            raise BagError(f"bag {self.path}: topic {topic} has type {matches[0].msgtype}, expected {msgtype}")
        return matches[0]

    def messages(self, connections: list[Connection]) -> Iterator[tuple[Connection, int, Any]]:
        """Decoded messages of these connections in time order; BagError on truncated or corrupt storage."""
        counts: dict[int, int] = defaultdict(int)
        try:
            for connection, stamp, raw in self.reader.messages(connections=connections):
                counts[connection.id] += 1
                try:
                    message = self.store.deserialize_cdr(raw, connection.msgtype)
                except (SerdeError, ValueError, IndexError, AssertionError, struct.error) as error:
                    raise BagError(
                        f"bag {self.path}: message on {connection.topic} at {stamp} ns cannot be decoded "
                        f"as {connection.msgtype} (corrupt or truncated): {error}"
                    ) from None
                yield connection, stamp, message
        except (ReaderError, OSError, EOFError) as error:
            raise BagError(f"bag {self.path} is truncated or corrupt: {error}") from None
        for connection in connections:
            expected = int(connection.msgcount)
            if counts[connection.id] < expected:
                raise BagError(
                    f"bag {self.path} is truncated: metadata lists {expected} messages on {connection.topic} "
                    f"but the storage holds {counts[connection.id]}"
                )


def summarize_bag(path: Path) -> BagSummary:
    """Topics, message counts, time span and size of a bag (reads only its metadata and index)."""
    with _BagReader(Path(path)) as bag:
        reader = bag.reader
        topics = {
            name: TopicSummary(msgtype=info.msgtype or "", message_count=int(info.msgcount))
            for name, info in reader.topics.items()
        }
        root = Path(path)
        files = [p for p in root.iterdir() if p.suffix in (".mcap", ".db3")] if root.is_dir() else [root]
        storage = "sqlite3" if any(p.suffix == ".db3" for p in files) else "mcap"
        return BagSummary(
            path=Path(path),
            storage=storage,
            topics=topics,
            start_ns=int(reader.start_time) if reader.message_count else 0,
            end_ns=int(reader.end_time) if reader.message_count else 0,
            size_bytes=sum(p.stat().st_size for p in files),
        )


def iter_bag_sweeps(path: Path, config: BagConfig | None = None) -> Iterator[tuple[int, str, np.ndarray]]:
    """(stamp [ns], frame_id, structured points) of every cloud on the LiDAR topic, one at a time."""
    config = config or BagConfig()
    with _BagReader(Path(path)) as bag:
        lidar = bag.connection(config.lidar_topic, POINTCLOUD2, required="LiDAR")
        assert lidar is not None
        for _, stamp, message in bag.messages([lidar]):
            points = _cloud_points(bag, lidar.topic, message, stamp)
            yield stamp_of(message.header.stamp), str(message.header.frame_id), points


def _cloud_points(bag: _BagReader, topic: str, message: Any, stamp: int) -> np.ndarray:
    try:
        return cloud_to_points(message)
    except ScenarioError as error:
        raise BagError(f"bag {bag.path}: LiDAR topic {topic} at {stamp} ns: {error}") from None


_NO_POINTS = np.zeros(0, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])


@dataclass
class _Collected:
    info: Any = None
    road_map: Any = None
    odom: list[tuple[int, FloatArray]] = field(default_factory=list)  # (stamp, T_world_ego)
    tf: list[tuple[int, FloatArray]] = field(default_factory=list)  # (stamp, T_world_ego)
    static: dict[tuple[str, str], FloatArray] = field(default_factory=dict)  # (parent, child) -> T_parent_child
    tracks: list[tuple[int, Any]] = field(default_factory=list)
    clouds: list[tuple[int, str, np.ndarray]] = field(default_factory=list)


def read_scenario_bag(path: Path, *, config: BagConfig | None = None, load_sweeps: bool = True) -> Scenario:
    """The scenario in a bag written by write_scenario_bag, or in a user's bag (topics from ``config``).

    With a ScenarioInfo message the frames are the odometry stamps and everything is read
    back exactly. Without one (a user's bag) the frames are the LiDAR stamps and the ego
    pose is interpolated to them from the odometry (or /tf, per config.ego_pose_source).
    ``load_sweeps=False`` skips decoding the point clouds (the sweeps come back empty).
    Raises BagError naming the bag and the problem: truncated storage, a missing LiDAR
    topic, a PointCloud2 without x/y/z, NaN poses, inconsistent stamps.
    """
    config = config or BagConfig()
    path = Path(path)
    with _BagReader(path) as bag:
        lidar = bag.connection(config.lidar_topic, POINTCLOUD2, required="LiDAR (sensor_msgs/msg/PointCloud2)")
        info_conn = bag.connection(config.info_topic, SCENARIO_INFO)
        own_bag = info_conn is not None
        use_tf = config.ego_pose_source == "tf" and not own_bag
        pose_conn = (
            bag.connection(config.tf_topic, TF_MESSAGE, required="ego pose (tf2_msgs/msg/TFMessage)")
            if use_tf
            else bag.connection(config.odom_topic, ODOMETRY, required="ego pose (nav_msgs/msg/Odometry)")
        )
        optional = [
            bag.connection(config.tf_static_topic, TF_MESSAGE),
            bag.connection(config.tracks_topic, ACTOR_TRACK_ARRAY),
            bag.connection(config.map_topic, ROAD_MAP),
            info_conn,
        ]
        wanted = [c for c in [pose_conn, *optional] if c is not None]
        if lidar is not None and (load_sweeps or not own_bag):  # users' bags take their frames from the sweeps
            wanted.append(lidar)
        collected = _collect(bag, wanted, config, pose_conn, lidar, keep_points=load_sweeps)
    return _assemble(path, collected, config, own_bag, load_sweeps)


def _collect(
    bag: _BagReader,
    wanted: list[Connection],
    config: BagConfig,
    pose_conn: Connection | None,
    lidar: Connection | None,
    keep_points: bool,
) -> _Collected:
    collected = _Collected()
    for connection, stamp, message in bag.messages(wanted):
        topic = connection.topic
        if connection is pose_conn and connection.msgtype == ODOMETRY:
            _check_frames(bag, topic, stamp, message.header.frame_id, message.child_frame_id, config)
            what = f"bag {bag.path}: {topic} at {stamp} ns"
            pose = message.pose.pose
            collected.odom.append((stamp_of(message.header.stamp), pose_matrix(pose.position, pose.orientation, what)))
        elif connection is pose_conn:
            for transform in message.transforms:
                if (transform.header.frame_id, transform.child_frame_id) == (config.world_frame, config.ego_frame):
                    what = f"bag {bag.path}: {topic} {config.world_frame}->{config.ego_frame} at {stamp} ns"
                    matrix = pose_matrix(transform.transform.translation, transform.transform.rotation, what)
                    collected.tf.append((stamp_of(transform.header.stamp), matrix))
        elif topic == config.tf_static_topic:
            for transform in message.transforms:
                what = f"bag {bag.path}: {topic} {transform.header.frame_id}->{transform.child_frame_id}"
                key = (str(transform.header.frame_id), str(transform.child_frame_id))
                collected.static[key] = pose_matrix(transform.transform.translation, transform.transform.rotation, what)
        elif topic == config.tracks_topic:
            collected.tracks.append((stamp, message))
        elif topic == config.map_topic:
            collected.road_map = message
        elif topic == config.info_topic:
            collected.info = message
        elif connection is lidar:
            points = _cloud_points(bag, topic, message, stamp) if keep_points else _NO_POINTS
            collected.clouds.append((stamp_of(message.header.stamp), str(message.header.frame_id), points))
    return collected


def _check_frames(bag: _BagReader, topic: str, stamp: int, parent: str, child: str, config: BagConfig) -> None:
    if parent != config.world_frame or child != config.ego_frame:
        raise BagError(
            f"bag {bag.path}: {topic} at {stamp} ns gives {child!r} in {parent!r}, but world_frame/ego_frame are "
            f"{config.world_frame!r}/{config.ego_frame!r} (set them in params/bag.yaml)"
        )


def _static_transform(static: dict[tuple[str, str], FloatArray], parent: str, child: str) -> FloatArray | None:
    """T_parent_child through the static transform tree (either direction of each edge), or None."""
    if parent == child:
        return np.eye(4)
    edges: dict[str, list[tuple[str, FloatArray]]] = defaultdict(list)
    for (a, b), matrix in static.items():
        edges[a].append((b, matrix))
        inverse = np.asarray(np.linalg.inv(matrix), dtype=np.float64)
        edges[b].append((a, inverse))
    frontier: list[tuple[str, FloatArray]] = [(parent, np.eye(4))]
    seen = {parent}
    while frontier:
        frame, transform = frontier.pop()
        for neighbour, step in edges[frame]:
            if neighbour in seen:
                continue
            composed: FloatArray = transform @ step
            if neighbour == child:
                return composed
            seen.add(neighbour)
            frontier.append((neighbour, composed))
    return None


def _interpolate_poses(stamps: IntArray, poses: FloatArray, targets: IntArray, path: Path) -> FloatArray:
    """Poses at the target stamps: linear in position, slerp in rotation; BagError outside the covered span."""
    order = np.argsort(stamps, kind="stable")
    stamps, poses = stamps[order], poses[order]
    unique = np.concatenate([[True], np.diff(stamps) > 0])
    stamps, poses = stamps[unique], poses[unique]
    outside = (targets < stamps[0]) | (targets > stamps[-1])
    if np.any(outside):
        first = int(targets[np.flatnonzero(outside)[0]])
        raise BagError(
            f"bag {path}: no ego pose covers the sweep at {first} ns (poses span {stamps[0]}..{stamps[-1]} ns)"
        )
    if stamps.shape[0] == 1:
        return np.repeat(poses, targets.shape[0], axis=0)
    times = (stamps - stamps[0]).astype(np.float64)
    query = (targets - stamps[0]).astype(np.float64)
    result = np.tile(np.eye(4), (targets.shape[0], 1, 1))
    for axis in range(3):
        result[:, axis, 3] = np.interp(query, times, poses[:, axis, 3])
    result[:, :3, :3] = Slerp(times, Rotation.from_matrix(poses[:, :3, :3]))(query).as_matrix()
    return result


def _assemble(path: Path, collected: _Collected, config: BagConfig, own_bag: bool, load_sweeps: bool) -> Scenario:
    info = collected.info
    pose_samples = collected.tf if config.ego_pose_source == "tf" and not own_bag else collected.odom
    if not pose_samples:
        raise BagError(f"bag {path}: no ego poses on {config.tf_topic if collected.tf else config.odom_topic}")
    pose_stamps = np.array([stamp for stamp, _ in pose_samples], dtype=np.int64)
    pose_matrices = np.stack([matrix for _, matrix in pose_samples])
    clouds = sorted(collected.clouds, key=lambda cloud: cloud[0])
    if own_bag:
        frames = pose_stamps
        if np.any(np.diff(frames) <= 0):
            raise BagError(f"bag {path}: odometry stamps are not strictly increasing")
        ego_poses = pose_matrices
    else:
        if not clouds:
            raise BagError(f"bag {path}: the LiDAR topic {config.lidar_topic} holds no messages")
        frames = np.array([stamp for stamp, _, _ in clouds], dtype=np.int64)
        if np.any(np.diff(frames) <= 0):
            raise BagError(f"bag {path}: two sweeps on {config.lidar_topic} share a header stamp")
        ego_poses = _interpolate_poses(pose_stamps, pose_matrices, frames, path)
    sensor_frame = config.sensor_frame or (str(info.sensor_frame) if info is not None else "")
    if not sensor_frame and clouds:
        sensor_frame = clouds[0][1]
    if info is not None:
        ego_T_sensor = pose_matrix(
            info.ego_to_sensor.translation, info.ego_to_sensor.rotation, f"bag {path}: ScenarioInfo"
        )
    elif clouds:
        found = _static_transform(collected.static, config.ego_frame, sensor_frame)
        if found is None:
            raise BagError(
                f"bag {path}: no transform {config.ego_frame} -> {sensor_frame} on {config.tf_static_topic} "
                "(set ego_frame / sensor_frame in params/bag.yaml)"
            )
        ego_T_sensor = found
    else:
        ego_T_sensor = np.eye(4)
    frame_index = {stamp: index for index, stamp in enumerate(frames.tolist())}
    sweeps: list[Sweep] = []
    if load_sweeps:
        for stamp, frame_id, points in clouds:
            if stamp not in frame_index:
                raise BagError(f"bag {path}: sweep at {stamp} ns has no ego pose at that stamp")
            pose = ego_poses[frame_index[stamp]] @ ego_T_sensor
            sweeps.append(Sweep(stamp_ns=stamp, frame_id=frame_id, points=points, sensor_pose=pose))
    try:
        return Scenario(
            scenario_id=str(info.scenario_id) if info is not None else path.name,
            frame_stamps_ns=frames,
            ego=EgoTrajectory(stamps_ns=frames, poses=ego_poses),
            actors=_tracks_from_msgs(path, collected.tracks, config),
            sweeps=tuple(sweeps),
            ego_T_sensor=ego_T_sensor,
            sensor=_sensor_model(info),
            road_map=_road_map(collected.road_map),
            **({} if info is None else {"ego_size": np.array([info.ego_length, info.ego_width, info.ego_height])}),
        )
    except BagError:
        raise
    except ScenarioError as error:
        raise BagError(f"bag {path}: {error}") from None


def _sensor_model(info: Any) -> SensorModel | None:
    if info is None or not info.has_sensor_model:
        return None
    return SensorModel(
        beam_elevations=np.array(info.beam_elevations, dtype=np.float64),
        azimuth_resolution=float(info.azimuth_resolution),
        min_range=float(info.min_range),
        max_range=float(info.max_range),
    )


def _road_map(message: Any) -> RoadMap | None:
    if message is None:
        return None

    def outline(polyline: Any) -> FloatArray:
        return np.stack([np.asarray(polyline.x, dtype=np.float64), np.asarray(polyline.y, dtype=np.float64)], axis=-1)

    return RoadMap(
        drivable_areas=tuple(outline(area) for area in message.drivable_areas),
        lane_centerlines=tuple(outline(lane) for lane in message.lane_centerlines),
    )


def _tracks_from_msgs(path: Path, arrays: list[tuple[int, Any]], config: BagConfig) -> tuple[ActorTrack, ...]:
    states: dict[str, list[tuple[int, float, float, float, float]]] = defaultdict(list)
    shapes: dict[str, tuple[str, tuple[float, float, float]]] = {}
    order: list[str] = []
    for stamp, array in arrays:
        if array.header.frame_id != config.world_frame:
            raise BagError(
                f"bag {path}: {config.tracks_topic} at {stamp} ns is in frame {array.header.frame_id!r}, "
                f"expected world_frame {config.world_frame!r}"
            )
        for track in array.tracks:
            actor_id = str(track.actor_id)
            shape = (str(track.actor_class), (float(track.length), float(track.width), float(track.height)))
            if actor_id not in shapes:
                shapes[actor_id] = shape
                order.append(actor_id)
            elif shapes[actor_id] != shape:
                raise BagError(f"bag {path}: actor {actor_id} changes class or size at {stamp} ns")
            for state in track.states:
                pose = (float(state.x), float(state.y), float(state.z), float(state.yaw))
                if not np.all(np.isfinite(pose)):
                    raise BagError(f"bag {path}: actor {actor_id} has a NaN or infinite state at {stamp} ns")
                states[actor_id].append((stamp_of(state.stamp), *pose))
    tracks = []
    for actor_id in order:
        if not states[actor_id]:
            continue
        rows = sorted(states[actor_id])
        stamps = np.array([row[0] for row in rows], dtype=np.int64)
        values = np.array([row[1:] for row in rows], dtype=np.float64)
        actor_class, size = shapes[actor_id]
        try:
            actor_kind = ActorClass(actor_class)
        except ValueError:
            raise BagError(f"bag {path}: actor {actor_id} has unknown class {actor_class!r}") from None
        tracks.append(
            ActorTrack(
                actor_id=actor_id,
                actor_class=actor_kind,
                size=np.array(size),
                stamps_ns=stamps,
                centers=values[:, :3],
                yaws=values[:, 3],
            )
        )
    return tuple(tracks)
