"""A user's bag needs no description of its one LiDAR topic, and `advsim label` writes a bag in the contract's layout.

The labelled bag is read back with rosbags' own reader (not this project's) to see its topics and frames.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import pytest
from rosbags.highlevel import AnyReader

from advsim_ros.contract import topics
from advsim_ros.io.bag import BagConfig, BagError, read_scenario_bag
from advsim_ros.labelling.command import label_bag

POSES_ONLY = BagConfig(odom_topic="/odom", world_frame="odom")  # the user describes the poses, not the LiDAR


def test_the_bags_only_pointcloud2_topic_is_the_lidar_and_one_line_says_so(
    tmp_path: Path, user_bags: Any, caplog: pytest.LogCaptureFixture
) -> None:
    bag = user_bags.write(tmp_path / "user", user_bags.messages())
    with caplog.at_level(logging.WARNING):
        first = read_scenario_bag(bag, config=POSES_ONLY)
        read_scenario_bag(bag, config=POSES_ONLY)
    assert len(first.sweeps) == 4
    assert first.sensor_frame == "velodyne"
    said = [record.getMessage() for record in caplog.records if "only PointCloud2 topic" in record.getMessage()]
    assert said == [
        f"bag {bag}: LiDAR read from /velodyne_points, its only PointCloud2 topic (lidar_topic names another)"
    ]


def test_two_pointcloud2_topics_or_a_named_topic_that_is_missing_are_not_guessed(
    tmp_path: Path, user_bags: Any
) -> None:
    messages = user_bags.messages()
    extra = [(f"/front{topic}", *rest) for topic, *rest in messages if topic == "/velodyne_points"]
    two = user_bags.write(tmp_path / "two", messages + extra)
    with pytest.raises(BagError, match=r"has no LiDAR .* topic /sensor/lidar/points; it has .*/front/velodyne_points"):
        read_scenario_bag(two, config=POSES_ONLY)
    one = user_bags.write(tmp_path / "one", messages)
    named = BagConfig(lidar_topic="/points_raw", odom_topic="/odom", world_frame="odom")
    with pytest.raises(BagError, match="topic /points_raw"):
        read_scenario_bag(one, config=named)


def test_a_labelled_bag_has_the_contracts_topics_and_frames_and_is_read_without_a_description(
    tmp_path: Path, user_bags: Any
) -> None:
    bag = user_bags.write(tmp_path / "user", user_bags.messages())
    report = label_bag(bag, tmp_path / "labelled", bag_config=POSES_ONLY)
    with AnyReader([report.output]) as reader:
        held = {connection.topic: connection.msgtype for connection in reader.connections}
        odometry = next(c for c in reader.connections if c.topic == topics.ODOM.name)
        _, _, raw = next(reader.messages([odometry]))
        frame = reader.deserialize(raw, odometry.msgtype).header.frame_id
    assert held[topics.LIDAR.name] == "sensor_msgs/msg/PointCloud2"
    assert held[topics.ODOM.name] == "nav_msgs/msg/Odometry"
    assert "/velodyne_points" not in held
    assert "/odom" not in held
    assert frame == BagConfig().world_frame
    scenario = read_scenario_bag(report.output)  # no --bag-params
    assert scenario.num_frames == 4
    assert scenario.sensor_frame == "velodyne"
