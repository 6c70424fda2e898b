"""scorer: scores the stack's plan of each query with the adversarial objective and the planning metrics.

When the player reports a query DONE (which carries the stack's decision-frame plan, detections
and predictions) and the query's perturbed tracks are there, in either order, it moves the plan
from sim time back to log time through the shared episode clock and scores it (core.scoring)
against the human (logged ego) trajectory and the actors' futures. The player's outcome
decides failures: the stack gone or replaced during the query: `stack_error`; frames or the
decision plan unanswered: `stack_timeout`; a plan that cannot be read: `stack_error`.
"""

from __future__ import annotations

import time

from advsim_ros import graph
from advsim_ros.contract import topics
from advsim_ros.contract.codec import Msg
from advsim_ros.contract.enums import Outcome, Phase
from advsim_ros.contract.protocol import EpisodeRecord, episode_from_msg, score_msg
from advsim_ros.contract.tracks import track_array_from_msg
from advsim_ros.core.metrics import MetricsConfig
from advsim_ros.core.objective import ObjectiveConfig, scorer_settings_from_params
from advsim_ros.core.types import ActorTrack
from advsim_ros.nodes.scenario_node import ScenarioNode
from advsim_ros.ros.graph_node import run_node
from advsim_ros.ros.params import declare_parameters
from advsim_ros.ros.scoring import score_episode


class Scorer(ScenarioNode):
    def __init__(self) -> None:
        super().__init__(graph.SCORER)
        objective = declare_parameters(self, ObjectiveConfig, "objective.")
        preset = self.declare_parameter("objective.preset", "").value  # M0..M5 or a baseline; "" = as given
        if preset:
            objective["preset"] = preset
        metrics = declare_parameters(self, MetricsConfig, "metrics.")
        self.settings = scorer_settings_from_params({"objective": objective, "metrics": metrics}, f"/{self.spec.name}")
        self.scenario, self.clock = self.load_scenario(load_sweeps=False)
        self.drivable = self.drivable_area(self.scenario)
        frames = self.window.frame_indices(self.scenario.num_frames)
        self.decision_frame = frames.start + self.window.decision_index
        self.publish_score = self.publisher(topics.SCORE)
        self.tracks: dict[int, tuple[ActorTrack, ...]] = {}
        self.done: dict[int, EpisodeRecord] = {}
        self.started: dict[int, float] = {}
        self.subscribe(topics.PERTURBED_TRACKS, self._on_tracks)
        self.subscribe(topics.EPISODE, self._on_episode)
        self.get_logger().info(f"ready: scoring plans of log frame {self.decision_frame}")

    def _on_tracks(self, message: Msg) -> None:
        record = track_array_from_msg(message)
        self.tracks[record.query_id] = record.actor_tracks()
        self._score_ready()

    def _on_episode(self, message: Msg) -> None:
        episode = episode_from_msg(message)
        if episode.phase == Phase.START:
            self.started[episode.query_id] = time.monotonic()
        elif episode.phase == Phase.DONE:
            self.trace("done_received", episode.query_id)
            self.done[episode.query_id] = episode
            self._score_ready()

    def _score_ready(self) -> None:
        for query_id in [q for q in self.done if q in self.tracks or self.done[q].outcome != Outcome.COMPLETE]:
            episode = self.done.pop(query_id)
            moved = self.tracks.pop(query_id, ())
            wall_time = time.monotonic() - self.started.pop(query_id, time.monotonic())
            score = score_episode(
                episode, moved, self.scenario, self.clock, self.decision_frame, self.settings, self.drivable, wall_time,
                self.bag_config.world_frame,
            )  # fmt: skip
            self.publish_score(score_msg(score, self.run_id))
            self.trace("score_sent", query_id)


def main() -> None:
    run_node(Scorer)


if __name__ == "__main__":
    main()
