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
from typing import Any

import numpy as np
import rclpy

from advsim_ros.contract import codec, topics
from advsim_ros.contract.protocol import episode_msg, frame_request_msg
from advsim_ros.contract.scenario import road_map_msg, scenario_info_msg
from advsim_ros.contract.spatial import odometry_msg, odometry_msgs, tf_message
from advsim_ros.contract.tracks import track_array_from_msg
from advsim_ros.core.closed_loop import ControllerConfig, initial_state, yaw_rate_of
from advsim_ros.core.reactive import IdmConfig
from advsim_ros.core.types import ActorTrack, Scenario
from advsim_ros.io.bag.write import sensor_frame_of
from advsim_ros.nodes.scenario_node import ScenarioNode
from advsim_ros.ros import lockstep
from advsim_ros.ros.closed_loop import ClosedLoopSetup, ReactiveSetup, loop_frames
from advsim_ros.ros.graph_node import run_node
from advsim_ros.ros.identity import RUN_MARKER, run_membership
from advsim_ros.ros.params import declare_config


class ScenarioPlayer(ScenarioNode):
    def __init__(self) -> None:
        super().__init__("scenario_player")
        self.config = declare_config(self, lockstep.PlayerConfig)
        self.controller = declare_config(self, ControllerConfig, "controller.")  # closed loop
        self.idm = declare_config(self, IdmConfig, "reactive.")  # closed loop, reactive_actors
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
        self.latched = [
            self.latch(topics.TF_STATIC, tf_message(first, bag.ego_frame, sensor_frame, scenario.ego_T_sensor)),
            self.latch(
                topics.SCENARIO_INFO, scenario_info_msg(scenario, bag.world_frame, bag.ego_frame, sensor_frame, "")
            ),
        ]
        if scenario.road_map is not None:
            self.latched.append(self.latch(topics.MAP, road_map_msg(scenario.road_map, first, bag.world_frame)))
        self.closed_loop = self._closed_loop_setup(scenario, frames, odometry) if self.config.loop == "closed" else None
        publish_episode = self.publisher(topics.EPISODE)
        publish_request = self.publisher(topics.FRAME_REQUEST)
        self.outputs = lockstep.Outputs(
            clock=self.publisher(topics.CLOCK),
            tf=self.publisher(topics.TF),
            odometry=self.publisher(topics.ODOM),
            lidar=self.publisher(topics.LIDAR),
            frame_request=lambda r: publish_request(frame_request_msg(r, bag.world_frame, self.run_id)),
            episode=lambda e, d, p: publish_episode(episode_msg(e, self.run_id, d, p)),
            tf_message=lambda stamp, pose: tf_message(stamp, bag.world_frame, bag.ego_frame, pose),
            trace=self.trace,
            odometry_of=lambda stamp, pose, state: codec.encode(
                odometry_msg(
                    stamp,
                    bag.world_frame,
                    bag.ego_frame,
                    pose,
                    np.array([state.speed, 0.0, 0.0]),
                    yaw_rate_of(state.speed, state.steer, self.controller.wheelbase),
                )
            ),
        )
        arrivals = [lockstep.StampedArrivals() for _ in range(5)]
        self.inputs = lockstep.Inputs(*arrivals)
        for topic, stream in zip(
            (topics.RENDERED, topics.PLAN, topics.DETECTIONS, topics.PREDICTIONS, topics.RELAYED), arrivals, strict=True
        ):
            self.subscribe(topic, stream.add, raw=True)
        names = lockstep.StackNames.from_pairs(self.config.stack_topics)
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

    def _on_tracks(self, message: Any) -> None:
        query_id = int(message.query_id)
        if self.closed_loop is not None and self.closed_loop.reactive is not None:
            # queries follow one another: older tracks (a late joiner's latched copy) are not needed again
            self.moved = {q: tracks for q, tracks in self.moved.items() if q >= query_id - 1}
            self.moved[query_id] = track_array_from_msg(message).actor_tracks()  # before the query is queued
        self.queries.put(query_id)

    def _closed_loop_setup(self, scenario: Scenario, frames: range, odometry: list[Any]) -> ClosedLoopSetup:
        """The drive after the decision: from the logged ego there, over the window's future frames."""
        decision = frames.start + self.window.decision_index
        logged = odometry[decision].twist.twist
        start = initial_state(
            scenario.ego.poses[decision], float(np.hypot(logged.linear.x, logged.linear.y)), logged.angular.z,
            self.controller,
        )  # fmt: skip
        stamps = scenario.frame_stamps_ns
        return ClosedLoopSetup(
            controller=self.controller,
            start=start,
            decision_stamp_ns=int(stamps[decision]),
            frames=loop_frames(stamps, scenario.ego.poses, range(decision + 1, frames.stop - 1)),  # 5 s
            period_s=self.window.frame_period,
            ego_size=scenario.ego_geometry.size,
            reactive=ReactiveSetup(self.idm, scenario.actors, scenario.ego, scenario.ego_geometry)
            if self.config.reactive_actors
            else None,
        )

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
                if self._stop.is_set() or not rclpy.ok():  # shutting down: the graph API is gone
                    return
                raise


def main() -> None:
    run_node(ScenarioPlayer)


if __name__ == "__main__":
    main()
