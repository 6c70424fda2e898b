"""Every topic of the contract: default name, message type and QoS (README "The topic contract").

Names are defaults: users remap the stack's side (``advsim attack --remap``) and a bag's
topics (params/bag.yaml). ``offered`` is the QoS the attack graph publishes with (and a
bag records); stacks subscribe to the LiDAR with ``qos.SENSOR_DATA``, which matches it.
"""

from __future__ import annotations

from dataclasses import dataclass

from advsim_ros.contract import names, qos
from advsim_ros.contract.qos import QosSpec


@dataclass(frozen=True)
class TopicSpec:
    name: str  # default topic name
    msgtype: str  # ROS 2 message type name
    offered: QosSpec  # QoS of its publishers in the graph and in bags


# Inputs of the stack under test (also the per-frame topics of scenario bags)
LIDAR = TopicSpec("/sensor/lidar/points", names.POINTCLOUD2, qos.LIDAR)
ODOM = TopicSpec("/ego/odom", names.ODOMETRY, qos.STREAM)
TF = TopicSpec("/tf", names.TF_MESSAGE, qos.TF)
TF_STATIC = TopicSpec("/tf_static", names.TF_MESSAGE, qos.LATCHED)
CLOCK = TopicSpec("/clock", names.CLOCK, qos.CLOCK)
MAP = TopicSpec("/map/road", names.ROAD_MAP, qos.LATCHED)
DRIVABLE = TopicSpec("/map/drivable", names.OCCUPANCY_GRID, qos.LATCHED)
SCENARIO_INFO = TopicSpec("/scenario/info", names.SCENARIO_INFO, qos.LATCHED)
# Logged actor tracks in scenario bags (one ActorTrackArray per frame)
ACTOR_TRACKS = TopicSpec("/actors/tracks", names.ACTOR_TRACK_ARRAY, qos.STREAM)

# Outputs of the stack under test
PLAN = TopicSpec("/planning/trajectory", names.PATH, qos.STREAM)
DETECTIONS = TopicSpec("/perception/detections", names.ACTOR_TRACK_ARRAY, qos.STREAM)
PREDICTIONS = TopicSpec("/prediction/tracks", names.ACTOR_TRACK_ARRAY, qos.STREAM)

# The attack protocol (internal to the graph; every message carries the run id)
ACTOR_SELECTION = TopicSpec("/advsim/actor_selection", names.ACTOR_SELECTION, qos.LATCHED)
PERTURBATION = TopicSpec("/advsim/perturbation", names.PERTURBATION, qos.HISTORY)
PERTURBED_TRACKS = TopicSpec("/advsim/perturbed_tracks", names.ACTOR_TRACK_ARRAY, qos.HISTORY)
FRAME_REQUEST = TopicSpec("/advsim/frame_request", names.FRAME_REQUEST, qos.STREAM)
RENDERED = TopicSpec("/advsim/rendered_points", names.POINTCLOUD2, qos.STREAM)  # lidar_resim's answers, to the player
EPISODE = TopicSpec("/advsim/episode", names.EPISODE, qos.HISTORY)
SCORE = TopicSpec("/advsim/score", names.QUERY_SCORE, qos.HISTORY)
SEARCH_STATUS = TopicSpec("/advsim/search_status", names.SEARCH_STATUS, qos.LATCHED)
# stack_adapter -> player, timer-driven stacks: a frame's inputs (stamp) are in the stack's readers
RELAYED = TopicSpec("/advsim/relayed", names.HEADER, qos.STREAM)

# The stack's side of the contract: what `--remap` may name.
# What the stack under test reads (published by the graph) and what it answers (read by the graph)
STACK_INPUTS: tuple[TopicSpec, ...] = (LIDAR, ODOM, TF, TF_STATIC, CLOCK, MAP, SCENARIO_INFO)
STACK_OUTPUTS: tuple[TopicSpec, ...] = (PLAN, DETECTIONS, PREDICTIONS)
STACK_TOPICS: tuple[TopicSpec, ...] = (*STACK_INPUTS, *STACK_OUTPUTS)
ALL_TOPICS: tuple[TopicSpec, ...] = (
    *STACK_TOPICS,
    DRIVABLE,
    ACTOR_TRACKS,
    ACTOR_SELECTION,
    PERTURBATION,
    PERTURBED_TRACKS,
    FRAME_REQUEST,
    RENDERED,
    EPISODE,
    SCORE,
    SEARCH_STATUS,
    RELAYED,
)


def stack_topic(name: str) -> TopicSpec:
    """The contract topic (of those the stack shares with the graph) of that default name."""
    for spec in STACK_TOPICS:
        if spec.name == name:
            return spec
    raise KeyError(name)
