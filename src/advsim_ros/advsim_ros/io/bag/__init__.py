"""Scenarios as rosbag2 bags (rosbags library): MCAP written, MCAP and sqlite3 read.

A scenario bag is a rosbag2 folder (metadata.yaml + storage file, as ``ros2 bag record``
makes them); docs/data.md documents its topics. Users' own bags need only the LiDAR topic
and the ego pose (odometry or /tf); a bag whose one PointCloud2 topic is not the contract's is
read from it. Modules: ``config`` (topics and frames), ``storage``
(opening bags), ``read`` and ``write`` (scenarios), ``poses`` (users' ego poses).
"""

from advsim_ros.io.bag.config import (
    BagConfig,
    BagError,
    add_bag_params_option,
    bag_layout_json,
    bag_layout_of,
    bag_params_config,
    load_bag_config,
)
from advsim_ros.io.bag.read import read_scenario_bag
from advsim_ros.io.bag.storage import (
    BagReader,
    BagSummary,
    TopicSummary,
    check_lidar_sweeps,
    iter_bag_sweeps,
    lidar_topic_of,
    summarize_bag,
)
from advsim_ros.io.bag.write import write_scenario_bag

__all__ = [
    "BagConfig",
    "BagError",
    "BagReader",
    "BagSummary",
    "TopicSummary",
    "add_bag_params_option",
    "bag_layout_json",
    "bag_layout_of",
    "bag_params_config",
    "check_lidar_sweeps",
    "iter_bag_sweeps",
    "lidar_topic_of",
    "load_bag_config",
    "read_scenario_bag",
    "summarize_bag",
    "write_scenario_bag",
]
