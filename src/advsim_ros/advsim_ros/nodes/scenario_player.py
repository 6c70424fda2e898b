"""scenario_player: replays the window's history for each query, in lock-step, on the query's sim-time segment.

It owns /clock, the ego pose (/tf, /ego/odom) and the latched scenario topics (/tf_static,
/scenario/info, /map/road). For each query whose perturbed tracks arrive it waits until the
stack and lidar_resim are connected, then replays the history frames (ros.lockstep) and
publishes Episode phases; Episode DONE carries the stack's decision-frame answers and the
digests of what it was sent and answered. In closed loop with ``reactive_actors`` it keeps each
query's perturbed tracks: the query's actors react to the ego (core.reactive).
"""

from __future__ import annotations

import queue
import threading

from rclpy.utilities import ok

from advsim_ros import graph
from advsim_ros.contract import codec, topics
from advsim_ros.contract.codec import Msg
from advsim_ros.contract.spatial import odometry_msgs
from advsim_ros.contract.tracks import track_array_from_msg
from advsim_ros.core.closed_loop import ControllerConfig
from advsim_ros.core.reactive import IdmConfig
from advsim_ros.core.types import ActorTrack
from advsim_ros.io.bag.write import sensor_frame_of
from advsim_ros.nodes.scenario_node import ScenarioNode
from advsim_ros.ros import lockstep
from advsim_ros.ros.closed_loop import closed_loop_setup
from advsim_ros.ros.graph_node import run_node
from advsim_ros.ros.identity import RUN_MARKER, run_membership
from advsim_ros.ros.player import latch_scenario, player_inputs, player_outputs


class ScenarioPlayer(ScenarioNode):
    def __init__(self) -> None:
        super().__init__(graph.SCENARIO_PLAYER)
        self.config = self.declare_section("", lockstep.PlayerConfig)
        self.controller = self.declare_section("controller", ControllerConfig)  # closed loop
        self.idm = self.declare_section("reactive", IdmConfig)  # closed loop, reactive_actors
        scenario, self.clock = self.load_scenario(load_sweeps=False)
        bag = self.bag_config
        frames = self.window.frame_indices(scenario.num_frames)
        odometry = odometry_msgs(scenario.ego, bag.world_frame, bag.ego_frame)
        self.history = [
            lockstep.HistoryFrame(i, int(scenario.frame_stamps_ns[i]), codec.encode(odometry[i]), scenario.ego.poses[i])
            for i in frames[: self.window.history_frames]
        ]
        first = int(scenario.frame_stamps_ns[frames.start])
        sensor_frame = sensor_frame_of(scenario, bag)
        self.latched = latch_scenario(self, scenario, bag.world_frame, bag.ego_frame, sensor_frame, first)
        self.closed_loop = None
        if self.config.loop == "closed":  # the drive after the decision
            idm = self.idm if self.config.reactive_actors else None
            self.closed_loop = closed_loop_setup(scenario, frames, odometry, self.window, self.controller, idm)
        self.outputs = player_outputs(self, bag.world_frame, bag.ego_frame, self.controller)
        self.inputs = player_inputs(self)
        names = lockstep.StackNames.from_pairs(graph.NAMES, self.config.stack_topics)
        self.stack_names = names
        membership = run_membership()
        if membership is None:  # started by hand or by a launch file without the marker
            self.get_logger().warning(f"no {RUN_MARKER} in the environment: publishers on the stack's topics unchecked")
        self.liveness = lockstep.StackLiveness(self, names, membership)
        self.readiness = lockstep.Readiness(self, self.latched, self.config.settle_time, names)
        self.queries: queue.Queue[int] = queue.Queue()
        self.moved: dict[int, tuple[ActorTrack, ...]] = {}  # query -> its perturbed tracks (reactive actors)
        self.subscribe(topics.PERTURBED_TRACKS, self._on_tracks)
        self._stop = threading.Event()
        self._driver = threading.Thread(target=self._drive, name="replay", daemon=True)
        self._driver.start()
        self.get_logger().info(f"ready: {len(self.history)} history frames from log frame {frames.start}")

    def _on_tracks(self, message: Msg) -> None:
        query_id = int(message.query_id)
        if self.closed_loop is not None and self.closed_loop.reactive is not None:
            # queries follow one another: older tracks (a late joiner's latched copy) are not needed again
            self.moved = {q: tracks for q, tracks in self.moved.items() if q >= query_id - 1}
            self.moved[query_id] = track_array_from_msg(message).actor_tracks()  # before the query is queued
        self.queries.put(query_id)

    def destroy_node(self) -> None:
        self._stop.set()
        self.queries.put(-1)
        self._driver.join(timeout=5.0)
        super().destroy_node()

    def _drive(self) -> None:
        done: set[int] = set()
        while not self._stop.is_set():
            query_id = self.queries.get()
            if query_id < 0:
                return
            if query_id in done:  # a late joiner's copy of the latched tracks
                continue
            done.add(query_id)
            self.get_logger().info(f"query {query_id}: replay starts")
            try:
                self.readiness.wait(self.config.ready_timeout, self._stop)
                stack_outputs = (
                    lockstep.stack_publishes(self, topics.DETECTIONS, self.stack_names),
                    lockstep.stack_publishes(self, topics.PREDICTIONS, self.stack_names),
                )
                moved = self.moved.pop(query_id, ())
                lockstep.replay_query(
                    query_id, self.history, self.clock, self.config, self.outputs, self.inputs, self.liveness,
                    stack_outputs, self._stop, self.closed_loop, moved,
                )  # fmt: skip
            except Exception:
                if self._stop.is_set() or not ok():  # shutting down: the graph API is gone
                    return
                raise


def main() -> None:
    run_node(ScenarioPlayer)


if __name__ == "__main__":
    main()
