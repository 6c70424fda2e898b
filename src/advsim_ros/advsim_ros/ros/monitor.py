"""The attack's monitor: an in-process node that follows scores and records the query to keep.

It holds every QueryScore and Perturbation, and the raw messages (re-simulated sweeps, the
stack's plans, perturbed tracks) of the most recent query only, so memory stays bounded; when
the run ends, those of the last query (the replay of the best one) are what the outputs record.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from advsim_ros.core.types import Perturbation
from advsim_ros.ros import qos, topics
from advsim_ros.ros.messages import message_class
from advsim_ros.ros.wire import (
    ACTOR_SELECTION,
    ACTOR_TRACK_ARRAY,
    EPISODE,
    PATH,
    PERTURBATION,
    PHASE_DONE,
    QUERY_SCORE,
    STATUS_INFEASIBLE,
    STATUS_OK,
    Wire,
    header_stamp_ns,
    perturbation_msg,
    track_array_msg,
)

POINTCLOUD2 = "sensor_msgs/msg/PointCloud2"


@dataclass
class Recording:
    """What the monitor saw, decoded where small, raw CDR where large."""

    scores: dict[int, Any] = field(default_factory=dict)  # query id -> QueryScore
    perturbations: dict[int, Any] = field(default_factory=dict)  # query id -> Perturbation
    selection: Any = None  # ActorSelection
    episodes: dict[int, Any] = field(default_factory=dict)  # query id -> its Episode DONE
    query_id: int = -1  # the query whose raw messages are below
    sweeps: dict[int, bytes] = field(default_factory=dict)  # sim stamp -> re-simulated PointCloud2
    plans: dict[int, bytes] = field(default_factory=dict)  # header stamp -> Path
    tracks: bytes | None = None  # ActorTrackArray of the query
    original_plans: dict[int, bytes] = field(default_factory=dict)  # the plans of query 0, kept for comparison


class AttackMonitor:
    def __init__(self, replay_only: bool) -> None:
        self.replay_only = replay_only
        self.wire = Wire()
        self.record = Recording()

    def __enter__(self) -> AttackMonitor:
        rclpy.init()
        self.node = Node("advsim_monitor")
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self._subscribe(QUERY_SCORE, topics.SCORE, qos.HISTORY, self._on_score)
        self._subscribe(PERTURBATION, topics.PERTURBATION, qos.LATCHED, self._on_perturbation)
        self._subscribe(ACTOR_SELECTION, topics.ACTOR_SELECTION, qos.LATCHED, self._on_selection)
        self._subscribe(EPISODE, topics.EPISODE, qos.HISTORY, self._on_episode)
        self._subscribe(ACTOR_TRACK_ARRAY, topics.PERTURBED_TRACKS, qos.LATCHED, self._on_tracks, decode=False)
        self._subscribe(POINTCLOUD2, topics.LIDAR, qos.LIDAR_OUT, self._on_sweep, decode=False)
        self._subscribe(PATH, topics.PLAN, qos.STREAM, self._on_plan, decode=False)
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown()

    def _subscribe(self, type_name: str, topic: str, profile: Any, callback: Any, decode: bool = True) -> None:
        def on_message(raw: bytes) -> None:
            callback(self.wire.decode(raw, type_name) if decode else raw)

        self.node.create_subscription(message_class(type_name), topic, on_message, profile, raw=True)

    # ----- callbacks

    def _on_score(self, message: Any) -> None:
        self.record.scores[int(message.query_id)] = message

    def _on_perturbation(self, message: Any) -> None:
        self.record.perturbations[int(message.query_id)] = message

    def _on_episode(self, message: Any) -> None:
        if message.phase == PHASE_DONE:
            self.record.episodes[int(message.query_id)] = message

    def _on_selection(self, message: Any) -> None:
        self.record.selection = message

    def _on_tracks(self, raw: bytes) -> None:
        query_id = int(self.wire.decode(raw, ACTOR_TRACK_ARRAY).query_id)
        if query_id != self.record.query_id:  # a new query: forget the previous one's raw messages
            if self.record.query_id == 0:
                self.record.original_plans = dict(self.record.plans)
            self.record.query_id = query_id
            self.record.sweeps.clear()
            self.record.plans.clear()
        self.record.tracks = raw

    def _on_sweep(self, raw: bytes) -> None:
        self.record.sweeps[header_stamp_ns(raw)] = raw

    def _on_plan(self, raw: bytes) -> None:
        self.record.plans[header_stamp_ns(raw)] = raw

    # ----- driving

    def request_original(self) -> None:
        """Replay mode: ask for query 0 with nobody moved (the bag's own actors are the scenario)."""
        publish_tracks = self.node.create_publisher(
            message_class(ACTOR_TRACK_ARRAY), topics.PERTURBED_TRACKS, qos.LATCHED
        )
        publish_query = self.node.create_publisher(message_class(PERTURBATION), topics.PERTURBATION, qos.LATCHED)
        publish_query.publish(
            self.wire.encode(perturbation_msg(self.wire, Perturbation(0, "replay", (), np.zeros(0), "replay")))
        )
        publish_tracks.publish(self.wire.encode(track_array_msg(self.wire, 0, 0, "world", [])))

    def spin_once(self, timeout: float) -> None:
        self.executor.spin_once(timeout_sec=timeout)

    @property
    def num_scores(self) -> int:
        return len(self.record.scores)

    @property
    def current_query(self) -> int:
        return max(self.record.perturbations, default=-1)

    def progress(self) -> dict[str, Any]:
        ok = [s for s in self.record.scores.values() if s.status == STATUS_OK and s.query_id > 0]
        best = max((float(s.adversarial_loss) for s in ok), default=math.nan)
        failed = sum(1 for s in self.record.scores.values() if s.status != STATUS_OK)
        return {"scored": self.num_scores, "best_adversarial_loss": best, "failed": failed}

    def missing_episodes(self) -> list[int]:
        """Scored queries whose Episode DONE has not arrived (queries scored infeasible never had one)."""
        return [
            query
            for query, score in self.record.scores.items()
            if query not in self.record.episodes and score.status != STATUS_INFEASIBLE
        ]

    def recording(self) -> Recording:
        return self.record
