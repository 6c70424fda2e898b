"""Writing a scenario as a rosbag2 bag (MCAP by default), atomically.

Per frame: /clock, the ego pose (/tf and nav_msgs/Odometry), the actor tracks
(advsim_msgs/ActorTrackArray, one state per actor) and, where the log has LiDAR, the sweep
(PointCloud2 in the sensor frame); once: the sensor mount (/tf_static), the map (RoadMap),
a stored drivable-area estimate (OccupancyGrid) and ScenarioInfo. Every type's definition
is stored in the bag and every topic records the QoS the contract offers it with.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np
from rosbags.interfaces import Connection, Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

from advsim_ros.contract import codec, names, topics
from advsim_ros.contract.codec import Msg
from advsim_ros.contract.qos import Durability, QosSpec, Reliability
from advsim_ros.contract.scenario import cloud_msg, drivable_grid_msg, road_map_msg, scenario_info_msg
from advsim_ros.contract.spatial import odometry_msgs, tf_message
from advsim_ros.contract.tracks import TrackRecord, track_array_msg
from advsim_ros.core.atomic import OutputExistsError, atomic_folder
from advsim_ros.core.types import Scenario
from advsim_ros.io.bag.config import BagConfig, BagError

SENSOR_POSE_TOLERANCE = 1e-6  # a sweep's pose may differ from ego pose @ ego_T_sensor by this much [m, 1]


def bag_qos(spec: QosSpec) -> Qos:
    """A contract QoS as the offered-QoS record rosbag2 keeps per topic."""
    zero = QosTime(sec=0, nsec=0)
    return Qos(
        history=QosHistory.KEEP_LAST,
        depth=spec.depth,
        reliability=QosReliability.RELIABLE if spec.reliability == Reliability.RELIABLE else QosReliability.BEST_EFFORT,
        durability=QosDurability.TRANSIENT_LOCAL
        if spec.durability == Durability.TRANSIENT_LOCAL
        else QosDurability.VOLATILE,
        deadline=zero,
        lifespan=zero,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=zero,
        avoid_ros_namespace_conventions=False,
    )


_QOS_BY_TOPIC = {spec.name: spec.offered for spec in topics.ALL_TOPICS}


def sensor_frame_of(scenario: Scenario, config: BagConfig) -> str:
    """The LiDAR frame's name: the scenario's, else the configured one, else "lidar"."""
    return scenario.sensor_frame or config.sensor_frame or "lidar"


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
    bytes), e.g. an attack's plan and score beside the scenario it produced. ``source`` says
    where the log came from (e.g. "kitti_tracking/0000"); it is stored in ScenarioInfo.
    Written to a hidden folder beside ``path`` and renamed into place when complete.
    """
    config = config or BagConfig()
    path = Path(path)
    _check_sensor_poses(scenario)
    sensor_frame = sensor_frame_of(scenario, config)
    if sensor_frame in (config.world_frame, config.ego_frame) and scenario.sweeps:
        raise BagError(f"sensor frame {sensor_frame!r} must differ from world_frame and ego_frame")
    if config.compress and config.storage != "mcap":
        raise BagError("BagConfig compress: only MCAP storage is compressed")

    def fill(writer: Writer) -> None:
        _write_messages(writer, scenario, config, source, sensor_frame)
        _write_extra(writer, extra)

    custom = {"advsim_ros.scenario_id": scenario.scenario_id}
    return _write_bag(path, overwrite, fill, storage=config.storage, compress=config.compress, custom=custom)


def _write_bag(
    path: Path,
    overwrite: bool,
    fill: Callable[[Writer], None],
    *,
    storage: str = "mcap",
    compress: bool = False,
    custom: Mapping[str, str] | None = None,
) -> Path:
    """A rosbag2 folder at path, staged beside it and renamed into place once fill() has written it."""
    try:
        with atomic_folder(path, overwrite) as bag_dir:
            plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
            writer = Writer(bag_dir, version=Writer.VERSION_LATEST, storage_plugin=plugin)
            if compress:
                writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
            for key, value in (custom or {}).items():
                writer.set_custom_data(key, value)
            writer.open()
            try:
                fill(writer)
            except BaseException:
                writer.abort()
                raise
            writer.close()
    except OutputExistsError as error:
        raise BagError(str(error)) from None
    return path


def _frame_track_arrays(scenario: Scenario, config: BagConfig) -> list[Msg]:
    """One ActorTrackArray per frame holding, for each actor seen then, its state at that frame."""
    per_frame: dict[int, list[TrackRecord]] = defaultdict(list)
    for actor in scenario.actors:
        record = TrackRecord.from_actor_track(actor)
        for index, stamp in enumerate(actor.stamps_ns.tolist()):
            per_frame[stamp].append(record.state(index))
    return [
        track_array_msg(per_frame.get(stamp, []), stamp, config.world_frame)
        for stamp in scenario.frame_stamps_ns.tolist()
    ]


def _write_messages(writer: Writer, scenario: Scenario, config: BagConfig, source: str, sensor_frame: str) -> None:
    store = codec.typestore()

    def connect(topic: str, msgtype: str, contract_topic: str) -> Connection:
        return writer.add_connection(
            topic, msgtype, typestore=store, offered_qos_profiles=[bag_qos(_QOS_BY_TOPIC[contract_topic])]
        )

    info = connect(config.info_topic, names.SCENARIO_INFO, topics.SCENARIO_INFO.name)
    tf_static = connect(config.tf_static_topic, names.TF_MESSAGE, topics.TF_STATIC.name)
    road_map = connect(config.map_topic, names.ROAD_MAP, topics.MAP.name) if scenario.road_map is not None else None
    drivable = (
        connect(config.drivable_topic, names.OCCUPANCY_GRID, topics.DRIVABLE.name)
        if scenario.drivable_area is not None
        else None
    )
    clock = connect(config.clock_topic, names.CLOCK, topics.CLOCK.name)
    tf = connect(config.tf_topic, names.TF_MESSAGE, topics.TF.name)
    odom = connect(config.odom_topic, names.ODOMETRY, topics.ODOM.name)
    tracks = connect(config.tracks_topic, names.ACTOR_TRACK_ARRAY, topics.ACTOR_TRACKS.name)
    lidar = connect(config.lidar_topic, names.POINTCLOUD2, topics.LIDAR.name)  # present even when empty

    def write(connection: Connection, stamp: int, value: Msg) -> None:
        writer.write(connection, stamp, codec.encode(value))

    first = int(scenario.frame_stamps_ns[0])
    write(info, first, scenario_info_msg(scenario, config.world_frame, config.ego_frame, sensor_frame, source))
    write(tf_static, first, tf_message(first, config.ego_frame, sensor_frame, scenario.ego_T_sensor))
    if road_map is not None and scenario.road_map is not None:
        write(road_map, first, road_map_msg(scenario.road_map, first, config.world_frame))
    if drivable is not None and scenario.drivable_area is not None:
        write(drivable, first, drivable_grid_msg(scenario.drivable_area, first, config.world_frame))
    sweeps = {sweep.stamp_ns: sweep for sweep in scenario.sweeps}
    odometry = odometry_msgs(scenario.ego, config.world_frame, config.ego_frame)
    track_arrays = _frame_track_arrays(scenario, config)
    for index, stamp in enumerate(scenario.frame_stamps_ns.tolist()):
        writer.write(clock, stamp, codec.clock_cdr(stamp))
        write(tf, stamp, tf_message(stamp, config.world_frame, config.ego_frame, scenario.ego.poses[index]))
        write(odom, stamp, odometry[index])
        write(tracks, stamp, track_arrays[index])
        if stamp in sweeps:
            write(lidar, stamp, cloud_msg(sweeps[stamp]))


def _write_extra(writer: Writer, extra: Sequence[tuple[str, str, int, bytes]]) -> None:
    store = codec.typestore()
    connections: dict[tuple[str, str], Connection] = {}
    for topic, msgtype, stamp, raw in extra:
        if (topic, msgtype) not in connections:
            qos = _QOS_BY_TOPIC.get(topic, topics.PLAN.offered)
            connections[(topic, msgtype)] = writer.add_connection(
                topic, msgtype, typestore=store, offered_qos_profiles=[bag_qos(qos)]
            )
        writer.write(connections[(topic, msgtype)], int(stamp), raw)


def write_messages_bag(path: Path, messages: Sequence[tuple[str, str, int, bytes]], overwrite: bool = False) -> Path:
    """A rosbag2 folder (MCAP) of just these (topic, message type, stamp [ns], CDR bytes), written atomically."""
    return _write_bag(Path(path), overwrite, lambda writer: _write_extra(writer, messages))
