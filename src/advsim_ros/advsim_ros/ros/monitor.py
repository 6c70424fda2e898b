"""The attack's monitor: an in-process node of the orchestrator that follows the protocol and collects queries.

It gathers, per query, the perturbation, the perturbed tracks, the Episode DONE (the stack's
decision-frame plan and the digests) and the QueryScore, in whatever order they arrive; a
query whose pieces are all there is handed out once as a finished query (``take_finished``),
to be journaled. It also reads the ROS graph to say what a stack that does not connect is
doing instead. In replay mode it asks for the queries itself (nothing is perturbed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import try_shutdown

from advsim_ros.contract import topics
from advsim_ros.contract.codec import Msg
from advsim_ros.contract.enums import Phase, Status
from advsim_ros.contract.protocol import (
    EpisodeRecord,
    ScoreRecord,
    SelectionRecord,
    episode_from_msg,
    perturbation_from_msg,
    perturbation_msg,
    score_from_msg,
    search_status_from_msg,
    selection_from_msg,
)
from advsim_ros.contract.tracks import track_array_from_msg, track_array_msg
from advsim_ros.core.types import ActorTrack, Perturbation
from advsim_ros.ros.graph_node import RUN_ID_PARAMETER, GraphNode
from advsim_ros.ros.introspect import StackNodeInfo, describe, stack_graph
from advsim_ros.ros.lockstep import StackNames, stack_endpoints


@dataclass
class FinishedQuery:
    """Everything about one query, once it is over."""

    perturbation: Perturbation
    score: ScoreRecord
    tracks: tuple[ActorTrack, ...] = ()
    episode: EpisodeRecord | None = None  # absent for queries scored infeasible (never replayed)


@dataclass
class _Pending:
    perturbation: Perturbation | None = None
    score: ScoreRecord | None = None
    tracks: tuple[ActorTrack, ...] | None = None
    episode: EpisodeRecord | None = None
    current_frame: int = 0

    def lacking(self) -> list[str]:
        """The pieces still to come; an infeasible query is never replayed, so it has no episode or tracks."""
        pieces: dict[str, object] = {"perturbation": self.perturbation, "score": self.score}
        if self.score is None or self.score.status != Status.INFEASIBLE:
            pieces |= {"episode DONE": self.episode, "perturbed tracks": self.tracks}
        return [name for name, piece in pieces.items() if piece is None]

    def finished(self) -> FinishedQuery | None:
        if self.perturbation is None or self.score is None or self.lacking():
            return None
        return FinishedQuery(self.perturbation, self.score, self.tracks or (), self.episode)


@dataclass
class Progress:
    scored: int = 0
    failed: int = 0
    best_adversarial_loss: float = math.nan
    query: int = -1
    frame: int = 0
    flags: dict[str, object] = field(default_factory=dict)


class AttackMonitor:
    """Follows one graph; ``domain_id`` None: the process's ROS_DOMAIN_ID (each lane of an attack has its own)."""

    def __init__(
        self,
        run_id: int,
        names: StackNames,
        node_name: str,  # advsim_ros.graph.MONITOR's
        skip: frozenset[int] = frozenset(),
        domain_id: int | None = None,
        lane: int = 0,
    ) -> None:
        self.run_id = run_id
        self.domain_id = domain_id
        self.node_name = node_name if lane == 0 else f"{node_name}_lane{lane}"  # loggers are per process
        self.stack_names = names
        self.skip = skip  # queries already journaled (a resumed attack): never handed out again
        self.selection: SelectionRecord | None = None
        self.progress = Progress()
        self.search_finished = False
        self.search_queries = 0  # once the search finished: how many queries it made in all
        self._pending: dict[int, _Pending] = {}

    def __enter__(self) -> AttackMonitor:
        # SIGINT/SIGTERM stay the orchestrator's; args=[]: the advsim command line (--remap A:=B) is not for rcl
        self.context = Context()
        rclpy.init(
            args=[], context=self.context, domain_id=self.domain_id, signal_handler_options=SignalHandlerOptions.NO
        )
        self.node = GraphNode(self.node_name, [Parameter(RUN_ID_PARAMETER, value=self.run_id)], context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.node.subscribe(topics.SCORE, self._on_score)
        self.node.subscribe(topics.PERTURBATION, self._on_perturbation)
        self.node.subscribe(topics.ACTOR_SELECTION, self._on_selection)
        self.node.subscribe(topics.EPISODE, self._on_episode)
        self.node.subscribe(topics.PERTURBED_TRACKS, self._on_tracks)
        self.node.subscribe(topics.SEARCH_STATUS, self._on_search_status)
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        try_shutdown(context=self.context)

    def _entry(self, query_id: int) -> _Pending:
        return self._pending.setdefault(query_id, _Pending())

    def _on_score(self, message: Msg) -> None:
        score = score_from_msg(message)
        if score.query_id in self.skip:
            return
        self._entry(score.query_id).score = score
        self.progress.scored += 1
        self.progress.failed += 0 if score.ok else 1
        if score.ok and score.query_id > 0:
            best = self.progress.best_adversarial_loss
            self.progress.best_adversarial_loss = (
                score.adversarial_loss if math.isnan(best) else max(best, score.adversarial_loss)
            )

    def _on_perturbation(self, message: Msg) -> None:
        perturbation = perturbation_from_msg(message)
        self._entry(perturbation.query_id).perturbation = perturbation
        self.progress.query = max(self.progress.query, perturbation.query_id)

    def _on_selection(self, message: Msg) -> None:
        self.selection = selection_from_msg(message)

    def _on_episode(self, message: Msg) -> None:
        episode = episode_from_msg(message)
        self.progress.frame = episode.frame_index
        if episode.phase == Phase.DONE:
            self._entry(episode.query_id).episode = episode

    def _on_search_status(self, message: Msg) -> None:
        status = search_status_from_msg(message)
        self.search_finished, self.search_queries = status.finished, status.queries_asked

    def _on_tracks(self, message: Msg) -> None:
        record = track_array_from_msg(message)
        self._entry(record.query_id).tracks = record.actor_tracks()

    def spin_once(self, timeout: float) -> None:
        self.executor.spin_once(timeout_sec=timeout)

    def idle(self) -> bool:
        """No query asked for is still unfinished (nothing pending)."""
        return not any(entry.perturbation is not None for entry in self._pending.values())

    def missing(self) -> str:
        """What the unfinished queries still lack, e.g. 'query 21: episode DONE' ('' when none is waiting)."""
        lacking = ((query_id, entry.lacking()) for query_id, entry in sorted(self._pending.items()))
        return "; ".join(f"query {query_id}: {', '.join(absent)}" for query_id, absent in lacking if absent)

    def take_finished(self) -> list[FinishedQuery]:
        """Queries whose every piece arrived since the last call, in query order."""
        done = []
        for query_id in sorted(self._pending):
            finished = self._pending[query_id].finished()
            if finished is not None and query_id not in self.skip:
                done.append(finished)
                del self._pending[query_id]
        return done

    # ----- replay mode: the orchestrator asks for the queries itself

    def request_replay(self, query_id: int, world_frame: str) -> None:
        """Ask for query ``query_id`` of the bag's own scenario, nobody moved."""
        if not hasattr(self, "_replay_publishers"):
            self._replay_publishers = (
                self.node.publisher(topics.PERTURBATION),
                self.node.publisher(topics.PERTURBED_TRACKS),
            )
        publish_perturbation, publish_tracks = self._replay_publishers
        publish_perturbation(perturbation_msg(Perturbation(query_id, "replay", (), np.zeros(0), "replay"), self.run_id))
        publish_tracks(track_array_msg([], 0, world_frame, query_id=query_id, run_id=self.run_id))

    # ----- diagnostics

    def stack_connection(self) -> tuple[bool, str]:
        """Whether the stack listens to the LiDAR and publishes plans; if not, what it does instead."""
        node = self.node
        lidar_topic, plan_topic = self.stack_names(topics.LIDAR), self.stack_names(topics.PLAN)
        lidar = bool(stack_endpoints(node, lidar_topic, False, self.stack_names))
        plans = bool(stack_endpoints(node, plan_topic, True, self.stack_names))
        if lidar and plans:
            return True, ""
        missing = []
        if not lidar:
            missing.append(f"no subscription to the LiDAR topic {lidar_topic}")
        if not plans:
            missing.append(f"no publisher of the plan topic {plan_topic}")
        seen = describe(stack_graph(node, self.stack_names.graph_nodes))
        return False, f"{' and '.join(missing)} ({seen})"

    def stack_graph(self) -> list[StackNodeInfo]:
        """The stack's nodes with their topics, types and QoS (ros.introspect)."""
        return stack_graph(self.node, self.stack_names.graph_nodes)
