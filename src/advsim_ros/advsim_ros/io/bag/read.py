"""Reading a scenario back from a bag: one written by ``write_scenario_bag``, or a user's own.

With a ScenarioInfo message the frames are the odometry stamps and everything is read back
exactly. Without one (a user's bag) the frames are the LiDAR stamps and the ego pose is
interpolated to them from the odometry (or /tf, per ``BagConfig.ego_pose_source``).
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypedDict

import numpy as np
from rosbags.interfaces import Connection

from advsim_ros.contract import names
from advsim_ros.contract.codec import ContractError, Msg, header_stamp_ns, stamp_ns
from advsim_ros.contract.pointcloud import DroppedPoints
from advsim_ros.contract.scenario import drivable_area_from_grid, road_map_from_msg, scenario_info_from_msg
from advsim_ros.contract.spatial import pose_matrix
from advsim_ros.contract.tracks import TrackRecord, track_from_msg
from advsim_ros.core.types import ActorTrack, EgoGeometry, EgoTrajectory, FloatArray, Scenario, ScenarioError, Sweep
from advsim_ros.io.bag.config import LAYOUT_HINT, BagConfig, BagError
from advsim_ros.io.bag.poses import interpolate_poses, static_transform
from advsim_ros.io.bag.storage import BagReader, cloud_points, log

_NO_POINTS = np.zeros(0, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])


class _Geometry(TypedDict, total=False):
    """Scenario's geometry arguments a bag gives (those it lacks keep Scenario's defaults)."""

    ego_geometry: EgoGeometry
    sensor_frame: str


@dataclass
class _Collected:
    info: Msg | None = None  # ScenarioInfo
    road_map: Msg | None = None  # RoadMap
    drivable: Msg | None = None  # OccupancyGrid
    odom: list[tuple[int, FloatArray]] = field(default_factory=list)  # (stamp, T_world_ego)
    tf: list[tuple[int, FloatArray]] = field(default_factory=list)  # (stamp, T_world_ego)
    static: dict[tuple[str, str], FloatArray] = field(default_factory=dict)  # (parent, child) -> T_parent_child
    tracks: list[tuple[int, Msg]] = field(default_factory=list)  # (stamp, ActorTrackArray)
    clouds: list[tuple[int, str, np.ndarray]] = field(default_factory=list)
    dropped: DroppedPoints = field(default_factory=DroppedPoints)  # non-finite points left out of the clouds


def _pose(translation: Msg, rotation: Msg, what: str) -> FloatArray:
    try:
        return pose_matrix(translation, rotation, what)
    except ContractError as error:
        raise BagError(str(error)) from None


def read_scenario_bag(
    path: Path,
    *,
    config: BagConfig | None = None,
    load_sweeps: bool = True,
    sweeps_between: tuple[int, int] | None = None,
) -> Scenario:
    """The scenario in a bag written by write_scenario_bag, or in a user's bag (topics from ``config``).

    ``load_sweeps=False`` skips decoding the point clouds (the sweeps come back empty);
    ``sweeps_between=(first, last)`` keeps only the sweeps stamped first..last [ns] (an attack's window).
    Points with a non-finite x, y or z are dropped, their count logged once (a warning).
    Raises BagError naming the bag and the problem: truncated storage, a missing LiDAR
    topic, a PointCloud2 without x/y/z, NaN poses, inconsistent stamps.
    """
    config = config or BagConfig()
    path = Path(path)
    with BagReader(path) as bag:
        lidar = bag.lidar_connection(config.lidar_topic, required="LiDAR (sensor_msgs/msg/PointCloud2)")
        info_conn = bag.connection(config.info_topic, names.SCENARIO_INFO)
        own_bag = info_conn is not None
        use_tf = config.ego_pose_source == "tf" and not own_bag
        pose_conn = (
            bag.connection(config.tf_topic, names.TF_MESSAGE, required="ego pose (tf2_msgs/msg/TFMessage)")
            if use_tf
            else bag.connection(config.odom_topic, names.ODOMETRY, required="ego pose (nav_msgs/msg/Odometry)")
        )
        optional = [
            bag.connection(config.tf_static_topic, names.TF_MESSAGE),
            bag.connection(config.tracks_topic, names.ACTOR_TRACK_ARRAY),
            bag.connection(config.map_topic, names.ROAD_MAP),
            bag.connection(config.drivable_topic, names.OCCUPANCY_GRID),
            info_conn,
        ]
        wanted = [c for c in [pose_conn, *optional] if c is not None]
        if lidar is not None and (load_sweeps or not own_bag):  # users' bags take their frames from the sweeps
            wanted.append(lidar)
        kept = (sweeps_between or (-(2**63), 2**63 - 1)) if load_sweeps else None
        collected = _collect(bag, wanted, config, pose_conn, lidar, kept, skim=sweeps_between is not None)
    collected.dropped.report(log, f"bag {path}", lidar.topic)
    return _assemble(path, collected, config, own_bag, kept)


def _collect(
    bag: BagReader,
    wanted: list[Connection],
    config: BagConfig,
    pose_conn: Connection | None,
    lidar: Connection | None,
    kept: tuple[int, int] | None,
    skim: bool = False,
) -> _Collected:
    """Every message the scenario needs; the points of the sweeps stamped within ``kept`` (none: no points).

    ``skim``: a sweep outside ``kept`` is not decoded at all, only its header stamp read (the first one is,
    for the sensor's frame name)."""
    collected = _Collected()
    for connection, stamp, raw in bag.raw_messages(wanted):
        if skim and connection is lidar and kept is not None and collected.clouds:
            header_ns = header_stamp_ns(raw)
            if not kept[0] <= header_ns <= kept[1]:
                collected.clouds.append((header_ns, "", _NO_POINTS))
                continue
        decoded = bag.decode(connection, stamp, raw)
        topic = connection.topic
        if connection is pose_conn and connection.msgtype == names.ODOMETRY:
            _check_frames(bag, topic, stamp, decoded.header.frame_id, decoded.child_frame_id, config)
            what = f"bag {bag.path}: {topic} at {stamp} ns"
            pose = decoded.pose.pose
            collected.odom.append((stamp_ns(decoded.header.stamp), _pose(pose.position, pose.orientation, what)))
        elif connection is pose_conn:
            for transform in decoded.transforms:
                if (transform.header.frame_id, transform.child_frame_id) == (config.world_frame, config.ego_frame):
                    what = f"bag {bag.path}: {topic} {config.world_frame}->{config.ego_frame} at {stamp} ns"
                    matrix = _pose(transform.transform.translation, transform.transform.rotation, what)
                    collected.tf.append((stamp_ns(transform.header.stamp), matrix))
        elif topic == config.tf_static_topic:
            for transform in decoded.transforms:
                what = f"bag {bag.path}: {topic} {transform.header.frame_id}->{transform.child_frame_id}"
                key = (str(transform.header.frame_id), str(transform.child_frame_id))
                collected.static[key] = _pose(transform.transform.translation, transform.transform.rotation, what)
        elif topic == config.tracks_topic:
            collected.tracks.append((stamp, decoded))
        elif topic == config.map_topic:
            collected.road_map = decoded
        elif topic == config.drivable_topic:
            collected.drivable = decoded
        elif topic == config.info_topic:
            collected.info = decoded
        elif connection is lidar:
            header_ns = stamp_ns(decoded.header.stamp)
            wanted_points = kept is not None and kept[0] <= header_ns <= kept[1]
            points = cloud_points(bag, topic, decoded, stamp, collected.dropped) if wanted_points else _NO_POINTS
            collected.clouds.append((header_ns, str(decoded.header.frame_id), points))
    return collected


def _check_frames(bag: BagReader, topic: str, stamp: int, parent: str, child: str, config: BagConfig) -> None:
    if parent != config.world_frame or child != config.ego_frame:
        raise BagError(
            f"bag {bag.path}: {topic} at {stamp} ns gives {child!r} in {parent!r}, but world_frame/ego_frame are "
            f"{config.world_frame!r}/{config.ego_frame!r}{LAYOUT_HINT}"
        )


def _assemble(
    path: Path, collected: _Collected, config: BagConfig, own_bag: bool, kept: tuple[int, int] | None
) -> Scenario:
    info = None
    if collected.info is not None:
        try:
            info = scenario_info_from_msg(collected.info, f"bag {path}: ScenarioInfo")
        except ContractError as error:
            raise BagError(str(error)) from None
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
        ego_poses = interpolate_poses(pose_stamps, pose_matrices, frames, path)
    sensor_frame = config.sensor_frame or (info.sensor_frame if info is not None else "")
    if not sensor_frame and clouds:
        sensor_frame = clouds[0][1]
    if info is not None:
        ego_T_sensor = info.ego_T_sensor
    elif clouds:
        found = static_transform(collected.static, config.ego_frame, sensor_frame)
        if found is None:
            raise BagError(
                f"bag {path}: no transform {config.ego_frame} -> {sensor_frame} on {config.tf_static_topic}"
                + LAYOUT_HINT
            )
        ego_T_sensor = found
    else:
        ego_T_sensor = np.eye(4)
    frame_index = {stamp: index for index, stamp in enumerate(frames.tolist())}
    sweeps: list[Sweep] = []
    if kept is not None:
        for stamp, frame_id, points in clouds:
            if not kept[0] <= stamp <= kept[1]:
                continue
            if stamp not in frame_index:
                raise BagError(f"bag {path}: sweep at {stamp} ns has no ego pose at that stamp")
            pose = ego_poses[frame_index[stamp]] @ ego_T_sensor
            sweeps.append(Sweep(stamp_ns=stamp, frame_id=frame_id, points=points, sensor_pose=pose))
    try:
        geometry: _Geometry = {}
        if info is not None:
            geometry = {"ego_geometry": info.ego_geometry}
        if sensor_frame:
            geometry["sensor_frame"] = sensor_frame
        return Scenario(
            scenario_id=info.scenario_id if info is not None else path.name,
            frame_stamps_ns=frames,
            ego=EgoTrajectory(stamps_ns=frames, poses=ego_poses),
            actors=_tracks_from_arrays(path, collected.tracks, config),
            sweeps=tuple(sweeps),
            ego_T_sensor=ego_T_sensor,
            sensor=info.sensor if info is not None else None,
            road_map=road_map_from_msg(collected.road_map) if collected.road_map is not None else None,
            drivable_area=drivable_area_from_grid(collected.drivable) if collected.drivable is not None else None,
            **geometry,
        )
    except BagError:
        raise
    except ScenarioError as error:
        raise BagError(f"bag {path}: {error}") from None


def _tracks_from_arrays(path: Path, arrays: list[tuple[int, Msg]], config: BagConfig) -> tuple[ActorTrack, ...]:
    """Each actor's track from the per-frame ActorTrackArrays (one state per actor and frame)."""
    states: dict[str, list[TrackRecord]] = defaultdict(list)
    shapes: dict[str, tuple[str, tuple[float, ...]]] = {}
    for stamp, array in arrays:
        if array.header.frame_id != config.world_frame:
            raise BagError(
                f"bag {path}: {config.tracks_topic} at {stamp} ns is in frame {array.header.frame_id!r}, "
                f"expected world_frame {config.world_frame!r}"
            )
        for track in array.tracks:
            try:
                record = track_from_msg(track)
            except ContractError as error:
                raise BagError(f"bag {path}: {config.tracks_topic} at {stamp} ns: {error}") from None
            shape = (record.actor_class.value, tuple(record.size.tolist()))
            if shapes.setdefault(record.actor_id, shape) != shape:
                raise BagError(f"bag {path}: actor {record.actor_id} changes class or size at {stamp} ns")
            states[record.actor_id].append(record)
    tracks = []
    for records in states.values():
        stamps = np.concatenate([r.stamps_ns for r in records])
        order = np.argsort(stamps, kind="stable")
        first = records[0]
        tracks.append(
            ActorTrack(
                actor_id=first.actor_id,
                actor_class=first.actor_class,
                size=first.size,
                stamps_ns=stamps[order],
                centers=np.concatenate([r.xyz for r in records])[order],
                yaws=np.concatenate([r.yaw for r in records])[order],
            )
        )
    return tuple(tracks)
