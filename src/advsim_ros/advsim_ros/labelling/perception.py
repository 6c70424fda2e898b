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
from scipy.spatial.transform import Rotation

from advsim_ros.contract import names
from advsim_ros.contract.codec import ContractError, stamp_ns
from advsim_ros.contract.spatial import pose_matrix, transforms_of
from advsim_ros.core.types import ActorClass, ActorTrack, FloatArray, Scenario, ScenarioError
from advsim_ros.io.bag import BagConfig, BagReader

_CUBE = 1  # visualization_msgs/Marker CUBE
_DELETE_ACTIONS = (2, 3)  # DELETE, DELETEALL
_CLASS_WORDS = (
    (("ped", "person", "walker"), ActorClass.PEDESTRIAN),
    (("cycl", "bicycle", "bike", "motorcycle"), ActorClass.CYCLIST),
    (("car", "vehicle", "truck", "bus", "van", "trailer"), ActorClass.VEHICLE),
)


class PerceptionTopicError(ScenarioError):
    """A perception topic that cannot give tracks; the message names the bag and the topic."""


def _matrix(translation: Any, rotation: Any, what: str) -> FloatArray:
    """A pose; an all-zero quaternion (what some marker publishers leave) counts as no rotation."""
    if (rotation.x, rotation.y, rotation.z, rotation.w) == (0.0, 0.0, 0.0, 0.0):
        matrix = np.eye(4)
        matrix[:3, 3] = [translation.x, translation.y, translation.z]
        return matrix
    try:
        return pose_matrix(translation, rotation, what)
    except ContractError as error:
        raise PerceptionTopicError(str(error)) from None


def read_bag_static_transforms(bag: Path, topic: str) -> dict[tuple[str, str], FloatArray]:
    """(parent, child) -> T_parent_child of every valid transform on the static tf topic."""
    transforms: dict[tuple[str, str], FloatArray] = {}
    with BagReader(Path(bag)) as reader:
        connection = reader.connection(topic, names.TF_MESSAGE)
        if connection is not None:
            for _, _, message in reader.messages([connection]):
                transforms.update(transforms_of(message))
    return transforms


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

    with BagReader(Path(bag)) as reader:
        connections = [c for c in reader.reader.connections if c.topic == topic]
        if not connections:
            raise PerceptionTopicError(f"bag {bag} has no topic {topic} (it has {sorted(reader.reader.topics)})")
        msgtype = connections[0].msgtype
        if msgtype not in (names.ACTOR_TRACK_ARRAY, names.MARKER_ARRAY):
            raise PerceptionTopicError(
                f"bag {bag}: {topic} is {msgtype}; "
                f"tracks are read from {names.ACTOR_TRACK_ARRAY} or {names.MARKER_ARRAY}"
            )
        for _, _, message in reader.messages(connections):
            if msgtype == names.ACTOR_TRACK_ARRAY:
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
                        add(str(track.actor_id), stamp_ns(state.stamp), frame_id, pose, size, actor_class)
            else:
                for marker in message.markers:
                    if int(marker.type) != _CUBE or int(marker.action) in _DELETE_ACTIONS:
                        continue
                    size = (float(marker.scale.x), float(marker.scale.y), float(marker.scale.z))
                    name = f"{marker.ns}_{marker.id}" if marker.ns else str(marker.id)
                    pose = _matrix(marker.pose.position, marker.pose.orientation, f"bag {bag}: {topic} marker {name}")
                    stamp = stamp_ns(marker.header.stamp)
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
