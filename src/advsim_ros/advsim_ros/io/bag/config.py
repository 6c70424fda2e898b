"""Topic names and frames of scenario bags (params/bag.yaml, key ``bag``)."""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from advsim_ros.contract import topics
from advsim_ros.core.params import config_from_mapping, load_node_params
from advsim_ros.core.types import ScenarioError

BAG_PARAMS_NODE = "**"  # params/bag.yaml applies to every node that reads or writes bags
# ends the messages of a bag whose topics or frames are not the ones read: how to name them
LAYOUT_HINT = " (a bag recorded with other names: describe its layout with --bag-params FILE.yaml, docs/data.md)"


class BagError(ScenarioError):
    """A bag that cannot be written or read as a scenario; the message names the bag and the problem."""


@dataclass(frozen=True)
class BagConfig:
    """Topic names and frames of scenario bags (params/bag.yaml, key ``bag``); defaults are the contract's."""

    lidar_topic: str = topics.LIDAR.name  # sensor_msgs/PointCloud2, any field layout with x, y, z
    odom_topic: str = topics.ODOM.name  # nav_msgs/Odometry: pose of ego_frame in world_frame
    tracks_topic: str = topics.ACTOR_TRACKS.name  # advsim_msgs/ActorTrackArray, one per frame
    map_topic: str = topics.MAP.name  # advsim_msgs/RoadMap, once, transient-local
    drivable_topic: str = topics.DRIVABLE.name  # nav_msgs/OccupancyGrid, once: a stored drivable-area estimate
    info_topic: str = topics.SCENARIO_INFO.name  # advsim_msgs/ScenarioInfo, once, transient-local
    clock_topic: str = topics.CLOCK.name  # rosgraph_msgs/Clock, one per frame
    tf_topic: str = topics.TF.name  # tf2_msgs/TFMessage: world_frame -> ego_frame per frame
    tf_static_topic: str = topics.TF_STATIC.name  # tf2_msgs/TFMessage: ego_frame -> sensor frame
    world_frame: str = "world"  # fixed frame of poses, tracks and map
    ego_frame: str = "base_link"  # vehicle base frame
    sensor_frame: str = ""  # LiDAR frame; "" means the frame_id in the PointCloud2 headers
    ego_pose_source: str = "odom"  # where users' bags carry the ego pose: "odom" or "tf"
    storage: str = "mcap"  # storage written: "mcap" (or "sqlite3"); both are read
    compress: bool = False  # zstd-compress MCAP chunks (LiDAR floats shrink little; off for speed)

    def __post_init__(self) -> None:
        for name in (
            "lidar_topic", "odom_topic", "tracks_topic", "map_topic", "drivable_topic", "info_topic", "clock_topic",
            "tf_topic", "tf_static_topic",
        ):  # fmt: skip
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
    try:
        return config_from_mapping(BagConfig, section, f"{path}: bag")
    except BagError as error:  # BagConfig's own checks do not know the file
        if str(path) in str(error):
            raise
        raise BagError(f"{path}: {error}") from None


# --------------------------------------------------------------------------- --bag-params, one option for all

BAG_PARAMS_HELP = (
    "the layout of a bag recorded with names of its own: LiDAR, odometry, tf and track topics, frame names, "
    "ego-pose source (a file shaped like params/bag.yaml, docs/data.md); without it the contract's names "
    "(report: the layout its summary.json recorded)"
)


def add_bag_params_option(parser: argparse.ArgumentParser, help_text: str = BAG_PARAMS_HELP) -> None:
    """``--bag-params FILE.yaml``, the same on every command that reads a bag (load it with ``bag_params_config``)."""
    parser.add_argument("--bag-params", type=Path, default=None, metavar="FILE.yaml", help=help_text)


def bag_params_config(path: Path | None) -> BagConfig | None:
    """The layout ``--bag-params FILE`` describes (None without one); BagError '--bag-params FILE: problem'."""
    if path is None:
        return None
    try:
        return load_bag_config(Path(path))
    except ScenarioError as error:
        raise BagError(f"--bag-params {error}") from None


def bag_layout_json(config: BagConfig | None) -> dict[str, object] | None:
    """A layout as JSON (summary.json, campaign jobs, suite indexes); None stays None."""
    return None if config is None else dataclasses.asdict(config)


def bag_layout_of(values: Mapping[str, object] | None, context: str) -> BagConfig | None:
    """The layout ``bag_layout_json`` wrote; None for None (no layout recorded: the contract's)."""
    if values is None:
        return None
    return config_from_mapping(BagConfig, dict(values), context)
