"""Tracks a bag already carries, and its static transforms, read with the rosbags library.

``advsim label --tracks-topic TOPIC`` takes the actors from a perception topic instead of
auto-labelling them:

- ``advsim_msgs/msg/ActorTrackArray``: each track's states (any frame in the header; moved
  into the world frame with the ego pose of the nearest frame);
- ``visualization_msgs/msg/MarkerArray``: every CUBE marker is a box (``ns`` + ``id`` name the
  track, ``scale`` x, y, z its length, width, height); the class comes from the namespace
  when it names one (car, truck, bus, pedestrian, person, cyclist, bicycle, ...), else from the size.

Boxes are assigned to the frame nearest their stamp (within half a frame period); a track
keeps its median size. Tracks seen in fewer than ``min_frames`` frames are left out.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from advsim_ros.core.types import ActorClass, ActorTrack, FloatArray, Scenario, ScenarioError
from advsim_ros.io.bag import BagConfig

ACTOR_TRACK_ARRAY = "advsim_msgs/msg/ActorTrackArray"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
_CUBE = 1  # visualization_msgs/Marker CUBE
_DELETE_ACTIONS = (2, 3)  # DELETE, DELETEALL
_CLASS_WORDS = (
    (("ped", "person", "walker"), ActorClass.PEDESTRIAN),
    (("cycl", "bicycle", "bike", "motorcycle"), ActorClass.CYCLIST),
    (("car", "vehicle", "truck", "bus", "van", "trailer"), ActorClass.VEHICLE),
)


class PerceptionTopicError(ScenarioError):
    """A perception topic that cannot give tracks; the message names the bag and the topic."""


def _reader(bag: Path) -> AnyReader:
    return AnyReader([Path(bag)], default_typestore=get_typestore(Stores.ROS2_JAZZY))


def _matrix(translation: Any, rotation: Any) -> FloatArray:
    quaternion = np.array([rotation.x, rotation.y, rotation.z, rotation.w], dtype=np.float64)
    matrix = np.eye(4)
    norm = float(np.linalg.norm(quaternion))
    matrix[:3, :3] = Rotation.from_quat(quaternion / norm).as_matrix() if norm > 0 else np.eye(3)
    matrix[:3, 3] = [translation.x, translation.y, translation.z]
    return matrix


def read_bag_static_transforms(bag: Path, topic: str) -> dict[tuple[str, str], FloatArray]:
    """(parent, child) -> T_parent_child of every transform on the static tf topic."""
    transforms: dict[tuple[str, str], FloatArray] = {}
    with _reader(bag) as reader:
        connections = [c for c in reader.connections if c.topic == topic and c.msgtype == TF_MESSAGE]
        if not connections:  # rosbags reads every topic when given none
            return transforms
        for connection, _, raw in reader.messages(connections=connections):
            message: Any = reader.deserialize(raw, connection.msgtype)
            for item in message.transforms:
                key = (str(item.header.frame_id), str(item.child_frame_id))
                transforms[key] = _matrix(item.transform.translation, item.transform.rotation)
    return transforms


def static_transform(static: dict[tuple[str, str], FloatArray], parent: str, child: str) -> FloatArray | None:
    """T_parent_child through the tree of static transforms (either direction of each edge), or None."""
    if parent == child:
        return np.eye(4)
    edges: dict[str, list[tuple[str, FloatArray]]] = defaultdict(list)
    for (a, b), matrix in static.items():
        edges[a].append((b, matrix))
        edges[b].append((a, np.asarray(np.linalg.inv(matrix), dtype=np.float64)))
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


def _class_of(name: str, length: float) -> ActorClass:
    lowered = name.lower()
    for words, actor_class in _CLASS_WORDS:
        if any(word in lowered for word in words):
            return actor_class
    if length >= 2.5:
        return ActorClass.VEHICLE
    return ActorClass.PEDESTRIAN if length < 1.2 else ActorClass.CYCLIST


def tracks_from_topic(
    bag: Path, topic: str, scenario: Scenario, config: BagConfig, min_frames: int = 2
) -> tuple[ActorTrack, ...]:
    """Actor tracks (world frame) from a perception topic of the bag (frame names from ``config``)."""
    stamps = scenario.frame_stamps_ns
    half_period = int(np.median(np.diff(stamps)) // 2) if stamps.shape[0] > 1 else 50_000_000
    mount = scenario.ego_T_sensor
    sensor_frames = {sweep.frame_id for sweep in scenario.sweeps}
    boxes: dict[str, list[tuple[int, FloatArray, float, tuple[float, float, float], ActorClass]]] = defaultdict(list)

    def to_world(frame_id: str, frame: int, pose: FloatArray) -> FloatArray:
        if frame_id == config.world_frame:
            return pose
        world_T_ego: FloatArray = scenario.ego.poses[frame]
        if frame_id == config.ego_frame:
            return world_T_ego @ pose
        if frame_id in sensor_frames:
            return world_T_ego @ mount @ pose
        raise PerceptionTopicError(
            f"bag {bag}: {topic} has boxes in frame {frame_id!r}; expected {config.world_frame!r}, "
            f"{config.ego_frame!r} or the LiDAR frame {sorted(sensor_frames)}"
        )

    def nearest_frame(stamp: int) -> int | None:
        index = int(np.clip(np.searchsorted(stamps, stamp), 1, stamps.shape[0] - 1)) if stamps.shape[0] > 1 else 0
        best = min((index - 1, index) if stamps.shape[0] > 1 else (0,), key=lambda row: abs(int(stamps[row]) - stamp))
        return best if abs(int(stamps[best]) - stamp) <= half_period else None

    def add(track_id: str, stamp: int, frame_id: str, pose: FloatArray, size: tuple[float, float, float],
            actor_class: ActorClass) -> None:  # fmt: skip
        frame = nearest_frame(stamp)
        if frame is None:
            return
        world = to_world(frame_id, frame, pose)
        boxes[track_id].append((frame, world[:3, 3], float(np.arctan2(world[1, 0], world[0, 0])), size, actor_class))

    with _reader(bag) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        if not connections:
            raise PerceptionTopicError(f"bag {bag} has no topic {topic} (it has {sorted(reader.topics)})")
        msgtype = connections[0].msgtype
        if msgtype not in (ACTOR_TRACK_ARRAY, MARKER_ARRAY):
            raise PerceptionTopicError(
                f"bag {bag}: {topic} is {msgtype}; tracks are read from {ACTOR_TRACK_ARRAY} or {MARKER_ARRAY}"
            )
        for connection, _, raw in reader.messages(connections=connections):
            message: Any = reader.deserialize(raw, connection.msgtype)
            if msgtype == ACTOR_TRACK_ARRAY:
                frame_id = str(message.header.frame_id)
                for track in message.tracks:
                    try:
                        actor_class = ActorClass(str(track.actor_class))
                    except ValueError:
                        actor_class = _class_of(str(track.actor_class), float(track.length))
                    size = (float(track.length), float(track.width), float(track.height))
                    for state in track.states:
                        pose = np.eye(4)
                        pose[:3, :3] = Rotation.from_euler("z", float(state.yaw)).as_matrix()
                        pose[:3, 3] = [state.x, state.y, state.z]
                        stamp = int(state.stamp.sec) * 1_000_000_000 + int(state.stamp.nanosec)
                        add(str(track.actor_id), stamp, frame_id, pose, size, actor_class)
            else:
                for marker in message.markers:
                    if int(marker.type) != _CUBE or int(marker.action) in _DELETE_ACTIONS:
                        continue
                    size = (float(marker.scale.x), float(marker.scale.y), float(marker.scale.z))
                    stamp = int(marker.header.stamp.sec) * 1_000_000_000 + int(marker.header.stamp.nanosec)
                    pose = _matrix(marker.pose.position, marker.pose.orientation)
                    name = f"{marker.ns}_{marker.id}" if marker.ns else str(marker.id)
                    add(name, stamp, str(marker.header.frame_id), pose, size, _class_of(str(marker.ns), size[0]))
    tracks = []
    for track_id, rows in boxes.items():
        by_frame = {frame: (centre, yaw, size, kind) for frame, centre, yaw, size, kind in rows}  # last box wins
        if len(by_frame) < min_frames:
            continue
        frames = sorted(by_frame)
        sizes = np.array([by_frame[frame][2] for frame in frames])
        if not np.all(sizes > 0):
            continue
        classes = [by_frame[frame][3] for frame in frames]
        tracks.append(
            ActorTrack(
                actor_id=track_id,
                actor_class=max(set(classes), key=classes.count),
                size=np.median(sizes, axis=0),
                stamps_ns=stamps[frames],
                centers=np.array([by_frame[frame][0] for frame in frames]),
                yaws=np.array([by_frame[frame][1] for frame in frames]),
            )
        )
    tracks.sort(key=lambda track: (int(track.stamps_ns[0]), track.actor_id))
    return tuple(tracks)
