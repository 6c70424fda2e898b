"""scenario_player: replays the window's history for each query, in lock-step, on the query's sim-time segment.

For every query whose perturbed tracks arrive it publishes Episode START, then for each history
frame: /clock, the ego pose (/tf, /ego/odom) and the logged sweep (to lidar_resim), and waits
until the re-simulated sweep is on the LiDAR topic and, when configured, the stack's plan for
that frame has arrived; after the decision frame, Episode DONE with how many sweeps went out and
how many plans came back. No frame is skipped: the replay runs as fast as its slowest participant.
A stack that is gone (nobody publishes the plan topic) or silent past the timeout ends the query early.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from advsim_ros.core.types import ScenarioError
from advsim_ros.io.bag import (
    CLOCK,
    ODOMETRY,
    POINTCLOUD2,
    ROAD_MAP,
    SCENARIO_INFO,
    TF_MESSAGE,
    cloud_msg,
    info_msg,
    odometry_msgs,
    road_map_msg,
    sensor_frame_of,
    tf_stamped,
)
from advsim_ros.ros import qos, topics
from advsim_ros.ros.graph_node import GraphNode, run_node
from advsim_ros.ros.params import declare_config
from advsim_ros.ros.wire import (
    ACTOR_TRACK_ARRAY,
    EPISODE,
    OUTCOME_COMPLETE,
    OUTCOME_PLANS_MISSING,
    OUTCOME_STACK_LOST,
    PATH,
    PHASE_DECISION,
    PHASE_DONE,
    PHASE_REPLAY,
    PHASE_START,
    episode_msg,
    header_stamp_ns,
    restamp,
)

_GRAPH_POLL = 0.2  # how often a wait re-checks that the stack is still there [s]
_PLANS_KEPT = 50  # plans remembered by stamp [messages]


@dataclass(frozen=True)
class PlayerConfig:
    """/scenario_player parameters (params/scenario_player.yaml)."""

    plan_timeout: float = 10.0  # longest wait for the stack's plan of one frame [s, wall clock]
    sweep_timeout: float = 30.0  # longest wait for the re-simulated sweep of one frame [s, wall clock]
    ready_timeout: float = 600.0  # longest wait, per query, for the stack and lidar_resim to be up [s]
    wait_for_every_plan: bool = True  # wait for a plan at every frame (stacks planning per sweep), else only the last
    publish_lidar_directly: bool = False  # replay the bag's sweeps straight to the LiDAR topic (no lidar_resim)

    def __post_init__(self) -> None:
        for name in ("plan_timeout", "sweep_timeout", "ready_timeout"):
            if not getattr(self, name) > 0.0:
                raise ScenarioError(f"/scenario_player {name}: must be positive, got {getattr(self, name)}")


@dataclass(frozen=True)
class _Frame:
    log_stamp_ns: int
    cloud: bytes  # CDR of the logged sweep
    odometry: bytes  # CDR of the ego odometry
    ego_pose: Any  # (4, 4) T_world_ego


class _Seen:
    """Stamps seen on a topic, with a wait that wakes on arrival (no busy waiting)."""

    def __init__(self) -> None:
        self._stamps: set[int] = set()
        self._condition = threading.Condition()

    def add(self, stamp_ns: int) -> None:
        with self._condition:
            self._stamps.add(stamp_ns)
            self._condition.notify_all()

    def wait(self, stamp_ns: int, timeout: float, give_up: Callable[[], bool]) -> bool:
        deadline = time.monotonic() + timeout
        with self._condition:
            while stamp_ns not in self._stamps:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or give_up():
                    return False
                self._condition.wait(min(remaining, _GRAPH_POLL))
            self._stamps.discard(stamp_ns)
            return True


class ScenarioPlayer(GraphNode):
    def __init__(self) -> None:
        super().__init__("scenario_player")
        self.config = declare_config(self, PlayerConfig)
        scenario, self.clock = self.load_scenario(load_sweeps=True)
        store, bag = self.wire.store, self.bag_config
        frames = self.window.frame_indices(scenario.num_frames)
        history = frames[: self.window.history_frames]
        sweeps = {sweep.stamp_ns: sweep for sweep in scenario.sweeps}
        odometry = odometry_msgs(store, scenario, bag)
        self.frames: list[_Frame] = []
        for index in history:
            stamp = int(scenario.frame_stamps_ns[index])
            if stamp not in sweeps:
                raise ScenarioError(f"scenario {scenario.scenario_id}: no LiDAR sweep at history frame {index}")
            self.frames.append(
                _Frame(
                    stamp,
                    self.wire.encode(cloud_msg(store, sweeps[stamp])),
                    self.wire.encode(odometry[index]),
                    scenario.ego.poses[index],
                )
            )
        lidar_topic = topics.LIDAR if self.config.publish_lidar_directly else topics.ORIGINAL_POINTS
        self.publish_cloud = self.raw_publisher(
            POINTCLOUD2, lidar_topic, qos.LIDAR_OUT if self.config.publish_lidar_directly else qos.STREAM
        )
        self.publish_clock = self.raw_publisher(CLOCK, topics.CLOCK, qos.CLOCK)
        self.publish_tf = self.raw_publisher(TF_MESSAGE, topics.TF, qos.STREAM)
        self.publish_odom = self.raw_publisher(ODOMETRY, topics.ODOM, qos.STREAM)
        self.publish_episode = self.raw_publisher(EPISODE, topics.EPISODE, qos.HISTORY)
        first = int(scenario.frame_stamps_ns[frames.start])
        sensor_frame = sensor_frame_of(scenario, bag)
        static = tf_stamped(store, first, bag.ego_frame, sensor_frame, scenario.ego_T_sensor)
        self.raw_publisher(TF_MESSAGE, topics.TF_STATIC, qos.LATCHED)(store.types[TF_MESSAGE](transforms=[static]))
        self.raw_publisher(SCENARIO_INFO, topics.SCENARIO_INFO, qos.LATCHED)(info_msg(store, scenario, bag, ""))
        if scenario.road_map is not None:
            road_map = road_map_msg(store, scenario.road_map, first, bag)
            self.raw_publisher(ROAD_MAP, topics.MAP, qos.LATCHED)(road_map)

        self.sweeps_seen = _Seen()
        self.plans_seen = _Seen()
        self._plans: dict[int, bytes] = {}  # recent plans by header stamp, to forward the decision frame's
        self.publish_decision_plan = self.raw_publisher(PATH, topics.DECISION_PLAN, qos.HISTORY)
        self.queries: queue.Queue[int] = queue.Queue()
        self.raw_subscription(POINTCLOUD2, topics.LIDAR, qos.LIDAR_OUT, self._on_sweep, decode=False)
        self.raw_subscription(PATH, topics.PLAN, qos.STREAM, self._on_plan, decode=False)
        self.raw_subscription(ACTOR_TRACK_ARRAY, topics.PERTURBED_TRACKS, qos.LATCHED, self._on_tracks)
        self._stop = threading.Event()
        self._stack_lost = False
        self._publishers_at_start: frozenset[bytes] = frozenset()
        self._driver = threading.Thread(target=self._drive, name="replay", daemon=True)
        self._driver.start()
        self.get_logger().info(
            f"ready: {len(self.frames)} history frames from log frame {frames.start}, "
            f"sim segment {self.clock.segment_ns / 1e9:.1f} s per query"
        )

    def _on_sweep(self, raw: bytes) -> None:
        self.sweeps_seen.add(header_stamp_ns(raw))

    def _on_plan(self, raw: bytes) -> None:
        stamp = header_stamp_ns(raw)
        self._plans[stamp] = raw
        while len(self._plans) > _PLANS_KEPT:
            del self._plans[min(self._plans)]
        self.plans_seen.add(stamp)

    def _on_tracks(self, message: Any) -> None:
        self.queries.put(int(message.query_id))

    def destroy_node(self) -> None:
        self._stop.set()
        self.queries.put(-1)
        self._driver.join(timeout=5.0)
        super().destroy_node()

    def _plan_publishers(self) -> frozenset[bytes]:
        return frozenset(bytes(info.endpoint_gid) for info in self.get_publishers_info_by_topic(topics.PLAN))

    def _stack_gone(self) -> bool:
        """Whether the stack's plan publisher changed since the query began (exit, crash, restart).

        A process that crashed stays in the DDS graph until its lease expires, but a restarted
        one brings a new publisher: no publisher, or one that was not there when the query began,
        counts (an old one expiring does not), and is remembered for the rest of the query.
        """
        current = self._plan_publishers()
        if not current or current - self._publishers_at_start:
            self._stack_lost = True
        return self._stop.is_set() or self._stack_lost

    def _watch_stack(self) -> bool:
        """While waiting for a sweep: note whether the stack is gone, give up only when shutting down."""
        self._stack_gone()
        return self._stop.is_set()

    def _graph_ready(self) -> bool:
        """The stack listens and answers, and (unless we feed the LiDAR ourselves) lidar_resim is up."""
        # our own LiDAR subscription counts too: the stack makes it two
        stack = self.count_subscribers(topics.LIDAR) >= 2 and self.count_publishers(topics.PLAN) >= 1
        resim = self.config.publish_lidar_directly or (
            self.count_subscribers(topics.ORIGINAL_POINTS) >= 1 and self.count_publishers(topics.LIDAR) >= 1
        )
        return stack and resim

    def _drive(self) -> None:
        done: set[int] = set()
        while not self._stop.is_set():
            query_id = self.queries.get()
            if query_id < 0:
                return
            if query_id in done:  # a late joiner's copy of the latched tracks
                continue
            done.add(query_id)
            try:
                self._replay(query_id)
            except Exception:
                if self._stop.is_set():
                    return
                raise

    def _replay(self, query_id: int) -> None:
        segment = self.clock.segment(query_id)
        count = len(self.frames)
        deadline = time.monotonic() + self.config.ready_timeout
        while not self._graph_ready() and time.monotonic() < deadline and not self._stop.is_set():
            self._stop.wait(_GRAPH_POLL)
        self.publish_episode(episode_msg(self.wire, query_id, PHASE_START, 0, count, segment))
        delivered = received = awaited = 0
        plans_flowing = True
        self._stack_lost = False
        self._publishers_at_start = self._plan_publishers()
        for index, frame in enumerate(self.frames):
            sim_stamp = self.clock.to_sim(query_id, frame.log_stamp_ns)
            self.publish_clock(self.wire.clock(sim_stamp))
            ego_tf = tf_stamped(
                self.wire.store, sim_stamp, self.bag_config.world_frame, self.bag_config.ego_frame, frame.ego_pose
            )
            self.publish_tf(self.wire.store.types[TF_MESSAGE](transforms=[ego_tf]))
            self.publish_odom(restamp(frame.odometry, sim_stamp))
            self.publish_cloud(restamp(frame.cloud, sim_stamp))
            if self.sweeps_seen.wait(sim_stamp, self.config.sweep_timeout, self._watch_stack):
                delivered += 1
            else:
                self.get_logger().error(f"query {query_id} frame {index}: re-simulated sweep did not arrive")
            decision = index == count - 1
            if decision or (self.config.wait_for_every_plan and plans_flowing):
                awaited += 1
                if self.plans_seen.wait(sim_stamp, self.config.plan_timeout, self._stack_gone):
                    received += 1
                    if decision:  # the scorer takes it from us: we know it arrived, latched it cannot be missed
                        self.publish_decision_plan(self._plans[sim_stamp])
                else:
                    plans_flowing = False  # do not wait at every frame for a stack that has stopped answering
                    self.get_logger().warning(f"query {query_id} frame {index}: no plan from the stack")
            phase = PHASE_DECISION if decision else PHASE_REPLAY
            self.publish_episode(episode_msg(self.wire, query_id, phase, index, count, segment, delivered, received))
        self._stack_gone()
        if self._stack_lost:
            outcome = OUTCOME_STACK_LOST
        elif received < awaited or delivered < count:
            outcome = OUTCOME_PLANS_MISSING
        else:
            outcome = OUTCOME_COMPLETE
        self.publish_episode(
            episode_msg(self.wire, query_id, PHASE_DONE, count - 1, count, segment, delivered, received, outcome)
        )


def main() -> None:
    run_node(ScenarioPlayer)


if __name__ == "__main__":
    main()
