"""Tracks taken from a perception topic already in the bag (advsim label --tracks-topic)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from advsim_ros.core.types import ActorClass, Scenario
from advsim_ros.io.bag import BagConfig, read_scenario_bag, write_scenario_bag
from advsim_ros.labelling.command import label_bag
from advsim_ros.labelling.perception import PerceptionTopicError


@pytest.fixture(scope="module")
def few(kitti_scenario: Scenario, crop_frames: Callable[..., Scenario]) -> Scenario:
    return crop_frames(kitti_scenario, 4, 100)


def test_tracks_from_an_actor_track_array_topic_come_back_as_logged(few: Scenario, tmp_path: Path) -> None:
    bag = write_scenario_bag(few, tmp_path / "perceived", config=BagConfig(tracks_topic="/perception/objects"))
    label_bag(bag, tmp_path / "out", tracks_topic="/perception/objects")
    actors = {actor.actor_id: actor for actor in read_scenario_bag(tmp_path / "out", load_sweeps=False).actors}
    expected = [actor for actor in few.actors if actor.stamps_ns.shape[0] >= 2]
    assert sorted(actors) == sorted(actor.actor_id for actor in expected)
    for actor in expected:
        assert np.allclose(actors[actor.actor_id].centers, actor.centers)
        assert actors[actor.actor_id].actor_class is actor.actor_class


def _marker_array(store: object, stamp: int, boxes: list[tuple[int, np.ndarray, float]]) -> bytes:
    types = store.types  # type: ignore[attr-defined]
    time = types["builtin_interfaces/msg/Time"](sec=stamp // 1_000_000_000, nanosec=stamp % 1_000_000_000)
    header = types["std_msgs/msg/Header"](stamp=time, frame_id="world")
    markers = []
    for marker_id, centre, yaw in boxes:
        x, y, z, w = Rotation.from_euler("z", yaw).as_quat()
        markers.append(
            types["visualization_msgs/msg/Marker"](
                header=header, ns="car", id=marker_id, type=1, action=0,
                pose=types["geometry_msgs/msg/Pose"](
                    position=types["geometry_msgs/msg/Point"](x=centre[0], y=centre[1], z=centre[2]),
                    orientation=types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w),
                ),
                scale=types["geometry_msgs/msg/Vector3"](x=4.0, y=1.8, z=1.5),
                color=types["std_msgs/msg/ColorRGBA"](r=1.0, g=0.0, b=0.0, a=1.0),
                lifetime=types["builtin_interfaces/msg/Duration"](sec=0, nanosec=0), frame_locked=False,
                points=[], colors=[], texture_resource="", texture=types["sensor_msgs/msg/CompressedImage"](
                    header=header, format="", data=np.zeros(0, np.uint8)),
                uv_coordinates=[], text="", mesh_resource="",
                mesh_file=types["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
                mesh_use_embedded_materials=False,
            )
        )  # fmt: skip
    message = types["visualization_msgs/msg/MarkerArray"](markers=markers)
    return bytes(store.serialize_cdr(message, "visualization_msgs/msg/MarkerArray"))  # type: ignore[attr-defined]


def test_tracks_from_marker_array_cubes(few: Scenario, tmp_path: Path) -> None:
    store = get_typestore(Stores.ROS2_JAZZY)
    centre = np.array([12.0, 3.0, 0.8])
    extra = [
        ("/viz/objects", "visualization_msgs/msg/MarkerArray", stamp,
         _marker_array(store, stamp, [(7, centre + np.array([index, 0.0, 0.0]), 0.3)]))
        for index, stamp in enumerate(few.frame_stamps_ns.tolist())
    ]  # fmt: skip
    bag = write_scenario_bag(dataclasses.replace(few, actors=()), tmp_path / "markers", extra=extra)
    label_bag(bag, tmp_path / "out", tracks_topic="/viz/objects")
    (actor,) = read_scenario_bag(tmp_path / "out", load_sweeps=False).actors
    assert actor.actor_id == "car_7"
    assert actor.actor_class is ActorClass.VEHICLE
    assert np.allclose(actor.size, [4.0, 1.8, 1.5])
    assert np.allclose(actor.centers[:, 0], 12.0 + np.arange(4))
    assert np.allclose(actor.yaws, 0.3)


def test_a_missing_or_wrong_perception_topic_is_named(few: Scenario, tmp_path: Path) -> None:
    bag = write_scenario_bag(few, tmp_path / "plain")
    with pytest.raises(PerceptionTopicError, match="no topic /nope"):
        label_bag(bag, tmp_path / "out", tracks_topic="/nope")
    with pytest.raises(PerceptionTopicError, match="sensor_msgs/msg/PointCloud2"):
        label_bag(bag, tmp_path / "out", tracks_topic="/sensor/lidar/points")
    assert not (tmp_path / "out").exists()
