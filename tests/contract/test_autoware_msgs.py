"""The Autoware messages in the shared typestore: registered from msg_defs/, CDR round trips, bags."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer

from advsim_ros.contract import codec, names
from advsim_ros.io.bag import BagReader

REPO = Path(__file__).resolve().parents[2]


def plain(value: Any) -> Any:
    """A rosbags message as nested dicts and lists (dataclasses holding arrays do not compare with ==)."""
    if dataclasses.is_dataclass(value):  # constants and __msgtype__ are dataclass fields too: skipped
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value) if f.name[0].islower()}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, list | tuple):
        return [plain(item) for item in value]
    return value


def trajectory(points: int = 2) -> Any:
    """A Trajectory whose every field differs from its default (floats exact in float32)."""
    m = codec.message
    return m(
        names.AUTOWARE_TRAJECTORY,
        header=codec.header_msg(12 * codec.NS_PER_S + 250_000_000, "map"),
        points=[
            m(
                names.AUTOWARE_TRAJECTORY_POINT,
                time_from_start=m("builtin_interfaces/msg/Duration", sec=i, nanosec=500_000_000),
                pose=m(
                    names.POSE,
                    position=m(names.POINT, x=1.5 + i, y=-2.25, z=0.125),
                    orientation=m(names.QUATERNION, x=0.0, y=0.0, z=0.6, w=0.8),
                ),
                longitudinal_velocity_mps=8.5 + i,
                lateral_velocity_mps=-0.25,
                acceleration_mps2=1.75,
                heading_rate_rps=0.0625,
                front_wheel_angle_rad=-0.03125,
                rear_wheel_angle_rad=0.015625,
            )
            for i in range(points)
        ],
    )


def predicted_objects() -> Any:
    """PredictedObjects with one object of one predicted path, every field set."""
    m = codec.message
    pose = m(
        names.POSE, position=m(names.POINT, x=3.0, y=4.0, z=0.5), orientation=m(names.QUATERNION, x=0, y=0, z=0, w=1)
    )
    twist = m(
        "geometry_msgs/msg/Twist", linear=m(names.VECTOR3, x=2.5, y=0, z=0), angular=m(names.VECTOR3, x=0, y=0, z=0.5)
    )
    accel = m(
        "geometry_msgs/msg/Accel", linear=m(names.VECTOR3, x=0.5, y=0, z=0), angular=m(names.VECTOR3, x=0, y=0, z=0)
    )
    covariance = np.arange(36, dtype=np.float64) / 8
    kinematics = m(
        "autoware_perception_msgs/msg/PredictedObjectKinematics",
        initial_pose_with_covariance=m("geometry_msgs/msg/PoseWithCovariance", pose=pose, covariance=covariance),
        initial_twist_with_covariance=m("geometry_msgs/msg/TwistWithCovariance", twist=twist, covariance=covariance),
        initial_acceleration_with_covariance=m(
            "geometry_msgs/msg/AccelWithCovariance", accel=accel, covariance=covariance
        ),
        predicted_paths=[
            m(
                names.AUTOWARE_PREDICTED_PATH,
                path=[pose, m(names.POSE, position=m(names.POINT, x=5.5, y=4.0, z=0.5), orientation=pose.orientation)],
                time_step=m("builtin_interfaces/msg/Duration", sec=0, nanosec=100_000_000),
                confidence=0.75,
            )
        ],
    )
    shape = m(
        names.AUTOWARE_SHAPE,
        type=2,  # POLYGON
        footprint=m("geometry_msgs/msg/Polygon", points=[m("geometry_msgs/msg/Point32", x=1.0, y=-0.5, z=0.0)]),
        dimensions=m(names.VECTOR3, x=4.5, y=1.75, z=1.5),
    )
    obj = m(
        names.AUTOWARE_PREDICTED_OBJECT,
        object_id=m("unique_identifier_msgs/msg/UUID", uuid=np.arange(1, 17, dtype=np.uint8)),
        existence_probability=0.875,
        classification=[m(names.AUTOWARE_OBJECT_CLASSIFICATION, label=7, probability=0.5)],
        kinematics=kinematics,
        shape=shape,
    )
    return m(names.AUTOWARE_PREDICTED_OBJECTS, header=codec.header_msg(3 * codec.NS_PER_S, "map"), objects=[obj])


def test_every_autoware_message_and_its_constants_are_in_the_typestore_from_msg_defs() -> None:
    types = codec.typestore().types
    for package, stems in codec.AUTOWARE_MESSAGES.items():
        assert codec.msg_definitions_dir(package) == REPO / "msg_defs" / package / "msg"
        assert {p.stem for p in codec.msg_definitions_dir(package).glob("*.msg")} == set(stems)
        for stem in stems:
            assert f"{package}/msg/{stem}" in types
    constants = {n: v for n, v in vars(names).items() if n.startswith("AUTOWARE_")}
    assert len(constants) >= 4
    assert all(value in types for value in constants.values())
    classification = types[names.AUTOWARE_OBJECT_CLASSIFICATION]
    assert (classification.UNKNOWN, classification.PEDESTRIAN, classification.UNDER_DRIVABLE) == (0, 7, 11)
    assert types[names.AUTOWARE_SHAPE].POLYGON == 2
    assert types["autoware_perception_msgs/msg/TrackedObjectKinematics"].SIGN_UNKNOWN == 1
    assert [name for name, *_ in codec.typestore().fielddefs[names.AUTOWARE_TRAJECTORY_POINT][1]] == [
        "time_from_start",
        "pose",
        "longitudinal_velocity_mps",
        "lateral_velocity_mps",
        "acceleration_mps2",
        "heading_rate_rps",
        "front_wheel_angle_rad",
        "rear_wheel_angle_rad",
    ]


def test_a_trajectory_and_predicted_objects_round_trip_through_cdr() -> None:
    for message in (trajectory(), trajectory(points=0), predicted_objects()):
        raw = codec.encode(message)
        decoded = codec.decode(raw, message.__msgtype__)
        assert plain(decoded) == plain(message)
        assert codec.header_stamp_ns(raw) == codec.stamp_ns(message.header.stamp)


def test_autoware_messages_written_to_a_bag_read_back_unchanged(tmp_path: Path) -> None:
    store = codec.typestore()
    messages = {"/planning/trajectory": trajectory(), "/perception/objects": predicted_objects()}
    with Writer(tmp_path / "bag", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for index, (topic, message) in enumerate(messages.items()):
            connection = writer.add_connection(topic, message.__msgtype__, typestore=store)
            writer.write(connection, index + 1, codec.encode(message))
    with BagReader(tmp_path / "bag") as reader:
        connections = [
            reader.connection(topic, message.__msgtype__, required="test") for topic, message in messages.items()
        ]
        read = {c.topic: m for c, _, m in reader.messages([c for c in connections if c is not None])}
    assert {topic: plain(m) for topic, m in read.items()} == {topic: plain(m) for topic, m in messages.items()}
