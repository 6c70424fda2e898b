"""The scenario player's ends on the graph: the latched scenario topics, what the replay sends and what it awaits.

The player (nodes/scenario_player.py) owns /clock, the ego pose (/tf, /ego/odom) and the latched
scenario topics (/tf_static, /scenario/info, /map/road); ros.lockstep replays a query through the
``lockstep.Outputs`` and ``lockstep.Inputs`` made here from the player node's publishers and
subscriptions.
"""

from __future__ import annotations

import numpy as np
from rclpy.publisher import Publisher

from advsim_ros.contract import codec, topics
from advsim_ros.contract.protocol import episode_msg, frame_request_msg
from advsim_ros.contract.scenario import road_map_msg, scenario_info_msg
from advsim_ros.contract.spatial import odometry_msg, tf_message
from advsim_ros.core.closed_loop import ControllerConfig, yaw_rate_of
from advsim_ros.core.types import Scenario
from advsim_ros.ros import lockstep
from advsim_ros.ros.graph_node import GraphNode

# what the replay awaits, in the order of lockstep.Inputs' fields
AWAITED = (topics.RENDERED, topics.PLAN, topics.DETECTIONS, topics.PREDICTIONS, topics.RELAYED)


def latch_scenario(
    node: GraphNode, scenario: Scenario, world_frame: str, ego_frame: str, sensor_frame: str, first_ns: int
) -> list[Publisher]:
    """Publish the scenario's latched topics, stamped with the window's first frame; their publishers, kept alive."""
    latched = [
        node.latch(topics.TF_STATIC, tf_message(first_ns, ego_frame, sensor_frame, scenario.ego_T_sensor)),
        node.latch(topics.SCENARIO_INFO, scenario_info_msg(scenario, world_frame, ego_frame, sensor_frame, "")),
    ]
    if scenario.road_map is not None:
        latched.append(node.latch(topics.MAP, road_map_msg(scenario.road_map, first_ns, world_frame)))
    return latched


def player_outputs(node: GraphNode, world_frame: str, ego_frame: str, controller: ControllerConfig) -> lockstep.Outputs:
    """Where the replay sends things: the node's publishers, protocol messages with its run id."""
    publish_episode = node.publisher(topics.EPISODE)
    publish_request = node.publisher(topics.FRAME_REQUEST)
    return lockstep.Outputs(
        clock=node.publisher(topics.CLOCK),
        tf=node.publisher(topics.TF),
        odometry=node.publisher(topics.ODOM),
        lidar=node.publisher(topics.LIDAR),
        frame_request=lambda r: publish_request(frame_request_msg(r, world_frame, node.run_id)),
        episode=lambda e, d, p: publish_episode(episode_msg(e, node.run_id, d, p)),
        tf_message=lambda stamp, pose: tf_message(stamp, world_frame, ego_frame, pose),
        trace=node.trace,
        odometry_of=lambda stamp, pose, state: codec.encode(
            odometry_msg(
                stamp,
                world_frame,
                ego_frame,
                pose,
                np.array([state.speed, 0.0, 0.0]),
                yaw_rate_of(state.speed, state.steer, controller.wheelbase),
            )
        ),
    )


def player_inputs(node: GraphNode) -> lockstep.Inputs:
    """What the replay waits for, filled by the node's subscriptions (raw CDR, by stamp)."""
    arrivals = [lockstep.StampedArrivals() for _ in AWAITED]
    for topic, stream in zip(AWAITED, arrivals, strict=True):
        node.subscribe(topic, stream.add, raw=True)
    return lockstep.Inputs(*arrivals)
