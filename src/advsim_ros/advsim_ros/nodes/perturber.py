"""perturber: selects the actors to perturb, then turns each query's delta into feasible trajectories.

At start-up it builds the feasible sets of the window (core.feasibility.select_actors) and
publishes the selection on /advsim/actor_selection (latched; the search sizes its delta from
it). For each Perturbation it projects the delta onto the feasible sets and publishes the
perturbed actors' whole-horizon trajectories for that query (latched); for the identity control,
their logged tracks over the window. A delta that cannot be projected gets an `infeasible`
QueryScore straight away, so the search goes on.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from advsim_ros import graph
from advsim_ros.contract import topics
from advsim_ros.contract.codec import Msg
from advsim_ros.contract.enums import Status
from advsim_ros.contract.protocol import (
    ScoreRecord,
    SelectionRecord,
    perturbation_from_msg,
    score_msg,
    selection_msg,
)
from advsim_ros.contract.tracks import TrackRecord, track_array_msg
from advsim_ros.core.feasibility import PerturberConfig, Window, perturbation_names, select_actors
from advsim_ros.core.search.driver import IDENTITY
from advsim_ros.core.types import ScenarioError
from advsim_ros.nodes.scenario_node import ScenarioNode
from advsim_ros.ros.graph_node import run_node


class Perturber(ScenarioNode):
    def __init__(self) -> None:
        super().__init__(graph.PERTURBER)
        self.config = self.declare_section("", PerturberConfig)
        if self.config.horizon_steps != self.window.num_frames:
            raise ScenarioError(
                f"/perturber horizon_steps ({self.config.horizon_steps}) must equal window.history_frames + "
                f"window.future_frames ({self.window.num_frames})"
            )
        scenario, _ = self.load_scenario(load_sweeps=False)
        scenario = dataclasses.replace(scenario, drivable_area=self.drivable_area(scenario))
        window = Window(start_frame=self.window.window_start_frame, num_steps=self.window.num_frames)
        self.get_logger().info(f"building feasible sets: {self.config.num_candidates} candidates per actor")
        self.selection = select_actors(scenario, window, self.config, np.random.default_rng(self.config.seed))
        for report in self.selection.reports:
            counts = f", {report.counts}" if report.counts is not None else ""
            self.get_logger().info(f"actor {report.actor_id} ({report.actor_class}): {report.reason}{counts}")
        self.frame_id = self.bag_config.world_frame
        self.stamp = int(scenario.frame_stamps_ns[window.start_frame])
        record = SelectionRecord(
            scenario_id=scenario.scenario_id,
            actor_ids=tuple(self.selection.actor_ids),
            dimension=self.selection.dimension,
            delta_names=tuple(perturbation_names(self.config.num_knots)),
            logged_tracks=tuple(TrackRecord.from_actor_track(scenario.actor(a)) for a in self.selection.actor_ids),
            feasible_candidates=tuple(int(s.size) for s in self.selection.sets),
        )
        self.selection_publisher = self.latch(
            topics.ACTOR_SELECTION, selection_msg(record, self.stamp, self.frame_id, self.run_id)
        )
        self.identity = tuple(TrackRecord.from_actor_track(t) for t in self.selection.logged_tracks(scenario))
        self.publish_tracks = self.publisher(topics.PERTURBED_TRACKS)
        self.publish_score = self.publisher(topics.SCORE)
        self.subscribe(topics.PERTURBATION, self.on_perturbation)

    def on_perturbation(self, message: Msg) -> None:
        perturbation = perturbation_from_msg(message)
        query_id = perturbation.query_id
        self.trace("perturbation_received", query_id)
        try:
            moved = () if perturbation.algorithm == IDENTITY else self.selection.project_perturbation(perturbation)
        except ScenarioError as error:
            self.get_logger().warning(f"query {query_id} is infeasible: {error}")
            self.publish_score(score_msg(ScoreRecord(query_id, Status.INFEASIBLE, str(error)), self.run_id))
            return
        tracks = [TrackRecord.from_perturbed(trajectory) for trajectory in moved]
        if perturbation.algorithm == IDENTITY:
            tracks = list(self.identity)
        self.publish_tracks(track_array_msg(tracks, self.stamp, self.frame_id, query_id=query_id, run_id=self.run_id))
        self.trace("tracks_sent", query_id)


def main() -> None:
    run_node(Perturber)


if __name__ == "__main__":
    main()
