"""Detections and predictions in a stack's own types become the contract's tracks (adapters.messages)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from advsim_ros.adapters.messages import detection_tracks, header_of, moved, on_grid, prediction_tracks
from advsim_ros.adapters.plans import PlanarTransform
from advsim_ros.contract import names
from advsim_ros.contract.codec import header_msg, message, typestore
from advsim_ros.core.types import ActorClass

STAMP = 7_000_000_000


def _pose(x: float, y: float, yaw: float) -> object:
    return message(
        names.POSE,
        position=message(names.POINT, x=x, y=y, z=0.5),
        orientation=message(names.QUATERNION, x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
    )


def _type(name: str) -> type:
    return typestore().types[name]  # type: ignore[no-any-return]


def _classification(label: int) -> object:
    return _type(names.AUTOWARE_OBJECT_CLASSIFICATION)(label=label, probability=1.0)


def _shape() -> object:
    polygon = _type("geometry_msgs/msg/Polygon")(points=[])
    dimensions = message("geometry_msgs/msg/Vector3", x=4.5, y=1.8, z=1.5)
    return _type(names.AUTOWARE_SHAPE)(type=0, footprint=polygon, dimensions=dimensions)


def _with_covariance(pose: object, kind: str) -> object:
    return _type(f"geometry_msgs/msg/{kind}WithCovariance")(**{kind.lower(): pose, "covariance": np.zeros(36)})


def test_autoware_detected_objects_become_boxes_with_their_class_and_confidence() -> None:
    twist = message("geometry_msgs/msg/Twist", linear=message("geometry_msgs/msg/Vector3", x=0.0, y=0.0, z=0.0),
                    angular=message("geometry_msgs/msg/Vector3", x=0.0, y=0.0, z=0.0))  # fmt: skip
    kinematics = _type("autoware_perception_msgs/msg/DetectedObjectKinematics")(
        pose_with_covariance=_with_covariance(_pose(10.0, 2.0, 0.3), "Pose"),
        has_position_covariance=False,
        orientation_availability=2,
        twist_with_covariance=_with_covariance(twist, "Twist"),
        has_twist=False,
        has_twist_covariance=False,
    )
    objects = [
        _type(names.AUTOWARE_DETECTED_OBJECT)(
            existence_probability=0.8, classification=[_classification(7)], kinematics=kinematics, shape=_shape()
        )
    ]
    msg = _type(names.AUTOWARE_DETECTED_OBJECTS)(header=header_msg(STAMP, "map"), objects=objects)
    (track,) = detection_tracks("autoware_detected_objects", msg)
    assert track.actor_class is ActorClass.PEDESTRIAN
    assert track.confidence == pytest.approx(0.8)
    np.testing.assert_allclose(track.xyz[0], [10.0, 2.0, 0.5])
    assert track.yaw[0] == pytest.approx(0.3)
    np.testing.assert_allclose(track.size, [4.5, 1.8, 1.5])
    assert track.stamps_ns.tolist() == [STAMP]


def test_marker_cubes_are_boxes_and_other_markers_are_ignored() -> None:
    def marker(kind: int, ns: str) -> object:
        return _type("visualization_msgs/msg/Marker")(
            header=header_msg(STAMP, "world"), ns=ns, id=3, type=kind, action=0, pose=_pose(1.0, 2.0, 0.0),
            scale=message("geometry_msgs/msg/Vector3", x=4.0, y=2.0, z=1.5),
            color=_type("std_msgs/msg/ColorRGBA")(r=1.0, g=0.0, b=0.0, a=1.0),
            lifetime=_type("builtin_interfaces/msg/Duration")(sec=0, nanosec=0), frame_locked=False, points=[],
            colors=[], texture_resource="", texture=_type("sensor_msgs/msg/CompressedImage")(
                header=header_msg(0, ""), format="", data=np.zeros(0, np.uint8)),
            uv_coordinates=[], text="", mesh_resource="",
            mesh_file=_type("visualization_msgs/msg/MeshFile")(filename="", data=np.zeros(0, np.uint8)),
            mesh_use_embedded_materials=False,
        )  # fmt: skip

    markers = [marker(1, "cyclist"), marker(2, "cars"), marker(1, "cars")]
    msg = _type(names.MARKER_ARRAY)(markers=markers)
    assert header_of(msg) == (STAMP, "world")
    tracks = detection_tracks("marker_array", msg)
    assert [t.actor_class for t in tracks] == [ActorClass.CYCLIST, ActorClass.VEHICLE]
    assert [t.actor_id for t in tracks] == ["cyclist/3", "cars/3"]


def test_the_most_confident_predicted_path_is_the_prediction_with_its_own_times() -> None:
    def path(confidence: float, dx: float) -> object:
        return _type(names.AUTOWARE_PREDICTED_PATH)(
            path=[_pose(dx * k, 0.0, 0.0) for k in range(4)],
            time_step=_type("builtin_interfaces/msg/Duration")(sec=0, nanosec=500_000_000),
            confidence=confidence,
        )

    kinematics = type("K", (), {"predicted_paths": [path(0.2, 1.0), path(0.7, 2.0)]})
    item = type("O", (), {"object_id": None, "classification": [_classification(1)], "existence_probability": 0.9,
                          "shape": _shape(), "kinematics": kinematics})  # fmt: skip
    msg = type("P", (), {"header": header_msg(STAMP, "map"), "objects": [item]})
    (track,) = prediction_tracks("autoware_predicted_objects", msg)
    assert track.stamps_ns.tolist() == [STAMP + k * 500_000_000 for k in range(4)]
    np.testing.assert_allclose(track.xyz[:, 0], [0.0, 2.0, 4.0, 6.0])
    grid = on_grid(track, STAMP + 100_000_000 * np.arange(0, 21))
    np.testing.assert_allclose(grid.xyz[:, 0], np.minimum(0.4 * np.arange(21), 6.0))
    world = moved(grid, PlanarTransform(100.0, 0.0, math.pi / 2))
    np.testing.assert_allclose(world.xyz[5, :2], [100.0, 2.0], atol=1e-9)
    assert world.yaw[0] == pytest.approx(math.pi / 2)
