"""scorer: scores the stack's plan of each query with the adversarial objective and the planning metrics.

When the player reports a query DONE it takes the plan stamped with the query's decision frame
(the last sweep the stack saw; the player forwards it, latched, so discovery timing between the
stack and the scorer cannot lose it), moves it from sim time back to log time through the shared
episode clock, and scores it against the human (logged ego) trajectory and the actors' futures —
the perturbed ones from the perturber, the others as logged (core.objective, core.metrics). The
player's outcome decides failures: the stack gone or replaced during the query: `stack_error`;
frames or the decision plan unanswered: `stack_timeout`; a plan that cannot be read (empty,
NaN): `stack_error`.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any

from rclpy.callback_groups import ReentrantCallbackGroup

from advsim_ros.core.drivable import DrivableConfig, drivable_area_for
from advsim_ros.core.metrics import MetricsConfig, actor_futures_at, plan_from_decision, query_metrics
from advsim_ros.core.objective import ObjectiveConfig, evaluate_objective, scorer_settings_from_params
from advsim_ros.core.types import ActorTrack, Plan, ScenarioError
from advsim_ros.ros import qos, topics
from advsim_ros.ros.graph_node import GraphNode, run_node
from advsim_ros.ros.messages import message_class
from advsim_ros.ros.params import declare_config, declare_parameters
from advsim_ros.ros.wire import (
    ACTOR_TRACK_ARRAY,
    EPISODE,
    OUTCOME_PLANS_MISSING,
    OUTCOME_STACK_LOST,
    PATH,
    PHASE_DONE,
    PHASE_START,
    QUERY_SCORE,
    STATUS_OK,
    STATUS_STACK_ERROR,
    STATUS_STACK_TIMEOUT,
    WireError,
    failed_score_msg,
    header_stamp_ns,
    plan_from_path,
    tracks_from_msg,
)


@dataclass(frozen=True)
class ScorerNodeConfig:
    """/scorer parameters besides the objective's own (params/scorer.yaml)."""

    plan_grace: float = 5.0  # wait this long after DONE for the forwarded decision plan [s, wall clock]
    plans_kept: int = 200  # plans remembered by stamp (bounds memory) [messages]

    def __post_init__(self) -> None:
        if self.plan_grace < 0.0 or self.plans_kept < 1:
            raise ScenarioError("/scorer: plan_grace must be >= 0 and plans_kept >= 1")


class Scorer(GraphNode):
    def __init__(self) -> None:
        super().__init__("scorer")
        self.config = declare_config(self, ScorerNodeConfig)
        objective = declare_parameters(self, ObjectiveConfig, "objective.")
        preset = self.declare_parameter("objective.preset", "").value  # M0..M5 or a baseline; "" = as given
        if preset:
            objective["preset"] = preset
        metrics = declare_parameters(self, MetricsConfig, "metrics.")
        self.settings = scorer_settings_from_params({"objective": objective, "metrics": metrics}, "/scorer")
        # sweeps: logs without a map get their drivable area estimated from the LiDAR ground
        self.scenario, self.clock = self.load_scenario(load_sweeps=True)
        self.drivable = drivable_area_for(self.scenario, DrivableConfig(), self.settings.objective.ego_forward_offset)
        frames = self.window.frame_indices(self.scenario.num_frames)
        decision = frames.start + self.window.decision_index
        self.decision_log_ns = int(self.scenario.frame_stamps_ns[decision])
        self.decision_pose = self.scenario.ego.poses[decision]
        self.publish_score = self.raw_publisher(QUERY_SCORE, topics.SCORE, qos.HISTORY)
        self._plans: dict[int, bytes] = {}
        self._tracks: dict[int, tuple[ActorTrack, ...]] = {}
        self._started: dict[int, float] = {}
        self._condition = threading.Condition()
        # decision plans as the player forwards them (latched); they may land while a DONE callback waits
        plans_group = ReentrantCallbackGroup()
        self.create_subscription(
            message_class(PATH), topics.DECISION_PLAN, self._on_plan, qos.HISTORY, raw=True, callback_group=plans_group
        )
        self.raw_subscription(ACTOR_TRACK_ARRAY, topics.PERTURBED_TRACKS, qos.LATCHED, self._on_tracks)
        self.raw_subscription(EPISODE, topics.EPISODE, qos.HISTORY, self._on_episode)
        self.get_logger().info(f"ready: scoring plans from log time {self.decision_log_ns} ns")

    def _on_plan(self, raw: bytes) -> None:
        with self._condition:
            self._plans[header_stamp_ns(raw)] = raw
            while len(self._plans) > self.config.plans_kept:
                del self._plans[min(self._plans)]
            self._condition.notify_all()

    def _on_tracks(self, message: Any) -> None:
        self._tracks[int(message.query_id)] = tracks_from_msg(message)

    def _on_episode(self, message: Any) -> None:
        query_id = int(message.query_id)
        if message.phase == PHASE_START:
            self._started[query_id] = time.monotonic()
        elif message.phase == PHASE_DONE:
            self.publish_score(self._score(query_id, message))

    def _score(self, query_id: int, done: Any) -> Any:
        wall_time = time.monotonic() - self._started.pop(query_id, time.monotonic())
        if done.outcome == OUTCOME_STACK_LOST:
            self._tracks.pop(query_id, None)
            reason = "the stack stopped during the query (its plan publisher vanished or was replaced: crash, restart)"
            return failed_score_msg(self.wire, query_id, STATUS_STACK_ERROR, reason, wall_time)
        if done.outcome == OUTCOME_PLANS_MISSING:
            self._tracks.pop(query_id, None)
            reason = (
                f"the stack answered {done.plans_received} of the frames it was waited for "
                f"({done.sweeps_delivered} of {done.num_frames} sweeps delivered)"
            )
            return failed_score_msg(self.wire, query_id, STATUS_STACK_TIMEOUT, reason, wall_time)
        decision_sim = self.clock.to_sim(query_id, self.decision_log_ns)
        with self._condition:
            self._condition.wait_for(lambda: decision_sim in self._plans, self.config.plan_grace)
            raw = self._plans.pop(decision_sim, None)
        if raw is None:
            reason = f"no plan for the decision frame (sim stamp {decision_sim} ns) before the timeout"
            return failed_score_msg(self.wire, query_id, STATUS_STACK_TIMEOUT, reason, wall_time)
        try:
            plan = plan_from_path(self.wire.decode(raw, PATH), decision_sim - self.decision_log_ns)
        except (WireError, ScenarioError) as error:
            return failed_score_msg(self.wire, query_id, STATUS_STACK_ERROR, f"unusable plan: {error}", wall_time)
        moved = {track.actor_id: track for track in self._tracks.pop(query_id, ())}
        actors = tuple(moved.get(actor.actor_id, actor) for actor in self.scenario.actors)
        try:
            return self._score_plan(
                query_id, plan_from_decision(plan, self.decision_pose, self.decision_log_ns), actors, wall_time
            )
        except ScenarioError as error:
            return failed_score_msg(self.wire, query_id, STATUS_STACK_ERROR, f"unusable plan: {error}", wall_time)

    def _score_plan(self, query_id: int, plan: Plan, actors: tuple[ActorTrack, ...], wall_time: float) -> Any:
        settings, scenario = self.settings, self.scenario
        futures = actor_futures_at(actors, plan.stamps_ns)
        terms = evaluate_objective(
            plan,
            scenario.ego,
            futures,
            scenario.ego_size,
            settings.objective,
            settings.metrics,
            self.drivable,
            scenario.road_map,
        )
        metrics = query_metrics(plan, scenario.ego, futures, scenario.ego_size, settings.metrics)
        return self.wire.store.types[QUERY_SCORE](
            query_id=query_id,
            status=STATUS_OK,
            message="",
            adversarial_loss=terms.value,
            imitation_loss=terms.imitation,
            collision_loss=terms.collision,
            comfort_loss=terms.comfort,
            collision_3s=metrics.at("collision", 3.0),
            collision_5s=metrics.at("collision", 5.0),
            l2_human_3s=metrics.at("l2_human", 3.0),
            l2_human_5s=metrics.at("l2_human", 5.0),
            lateral_acceleration=metrics.lateral_acceleration,
            jerk=metrics.jerk,
            wall_time=wall_time,
        )


def main() -> None:
    run_node(Scorer, threads=3)


if __name__ == "__main__":
    main()
