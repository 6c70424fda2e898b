"""Test process: a stray graph on the same ROS domain (another run id) that floods the attack protocol.

It publishes perturbations, perturbed tracks, episodes, frame requests and scores of its own run
id, as an orphaned graph of an earlier attack would, until it is stopped.
"""

import sys

import numpy as np
import rclpy
from rclpy.executors import ExternalShutdownException

from advsim_ros.contract import codec, topics
from advsim_ros.contract.enums import Outcome, Phase, Status
from advsim_ros.contract.protocol import (
    EpisodeRecord,
    FrameRequestRecord,
    ScoreRecord,
    episode_msg,
    frame_request_msg,
    perturbation_msg,
    score_msg,
)
from advsim_ros.contract.tracks import track_array_msg
from advsim_ros.core.types import Perturbation
from advsim_ros.ros.graph_node import GraphNode

STRAY_RUN = 424242


def main() -> None:
    rclpy.init()
    node = GraphNode("stray_graph")
    publish = {spec.name: node.publisher(spec) for spec in (
        topics.PERTURBATION, topics.PERTURBED_TRACKS, topics.EPISODE, topics.FRAME_REQUEST, topics.SCORE,
    )}  # fmt: skip
    counter = [0]

    def flood() -> None:
        query = counter[0] % 20
        counter[0] += 1
        delta = np.full(12, 0.9)
        publish[topics.PERTURBATION.name](perturbation_msg(Perturbation(query, "x", ("0",), delta, "bo"), STRAY_RUN))
        publish[topics.PERTURBED_TRACKS.name](track_array_msg([], 0, "world", query_id=query, run_id=STRAY_RUN))
        done = EpisodeRecord(query, Phase.DONE, 9, 10, (0, 1), 10, 10, Outcome.COMPLETE, "stray", "stray")
        publish[topics.EPISODE.name](episode_msg(done, STRAY_RUN))
        request = FrameRequestRecord(query, 0, 0, 1_000_000_000, np.eye(4))
        publish[topics.FRAME_REQUEST.name](frame_request_msg(request, "world", STRAY_RUN))
        score = ScoreRecord(query, Status.OK, adversarial_loss=1e6, collision_5s=1.0, input_digest="stray")
        publish[topics.SCORE.name](codec.encode(score_msg(score, STRAY_RUN)))
        if counter[0] == 1:
            print("stray graph publishing", flush=True)

    node.create_timer(0.05, flood)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    sys.exit(0)


if __name__ == "__main__":
    main()
