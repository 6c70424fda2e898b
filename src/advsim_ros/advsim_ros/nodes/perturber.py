"""perturber: selects the actors to perturb, then turns each query's delta into feasible trajectories.

At start-up it builds the feasible sets of the window (core.feasibility.select_actors) and
publishes the selected actors on /advsim/actor_selection (latched; the search sizes its delta
from it). For each Perturbation it projects the delta onto the feasible sets and publishes the
perturbed actors' whole-horizon trajectories for that query (latched). A delta that cannot be
projected gets an `infeasible` QueryScore straight away, so the search goes on.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from advsim_ros.core.feasibility import InfeasibleError, PerturberConfig, Window, perturbation_names, select_actors
from advsim_ros.core.types import ScenarioError
from advsim_ros.io.bag import header_msg
from advsim_ros.ros import qos, topics
from advsim_ros.ros.graph_node import GraphNode, run_node
from advsim_ros.ros.params import declare_config
from advsim_ros.ros.wire import (
    ACTOR_SELECTION,
    ACTOR_TRACK_ARRAY,
    PERTURBATION,
    QUERY_SCORE,
    STATUS_INFEASIBLE,
    failed_score_msg,
    logged_track_msg,
    perturbation_from_msg,
    track_array_msg,
    trajectory_track_msg,
)


class Perturber(GraphNode):
    def __init__(self) -> None:
        super().__init__("perturber")
        self.config = declare_perturber_config(self)
        scenario, self.clock = self.load_scenario(load_sweeps=True)  # sweeps: drivable area of map-less logs
        self.scenario_id = scenario.scenario_id
        window = Window(start_frame=self.window.window_start_frame, num_steps=self.window.num_frames)
        self.get_logger().info(
            f"building feasible sets: {self.config.num_candidates} candidates per actor, "
            f"window frames {window.start_frame}..{window.start_frame + window.num_steps - 1}"
        )
        self.selection = select_actors(scenario, window, self.config, np.random.default_rng(self.config.seed))
        for report in self.selection.reports:
            counts = f", {report.counts}" if report.counts is not None else ""
            self.get_logger().info(f"actor {report.actor_id} ({report.actor_class}): {report.reason}{counts}")
        self.frame_id = self.bag_config.world_frame
        self.publish_selection = self.raw_publisher(ACTOR_SELECTION, topics.ACTOR_SELECTION, qos.LATCHED)
        self.publish_tracks = self.raw_publisher(ACTOR_TRACK_ARRAY, topics.PERTURBED_TRACKS, qos.LATCHED)
        self.publish_score = self.raw_publisher(QUERY_SCORE, topics.SCORE, qos.HISTORY)
        stamp = int(scenario.frame_stamps_ns[window.start_frame])
        self.publish_selection(
            self.wire.store.types[ACTOR_SELECTION](
                header=header_msg(self.wire.store, stamp, self.frame_id),
                scenario_id=scenario.scenario_id,
                actor_ids=list(self.selection.actor_ids),
                dimension=self.selection.dimension,
                delta_names=list(perturbation_names(self.config.num_knots)),
                logged_tracks=[logged_track_msg(self.wire, scenario.actor(a)) for a in self.selection.actor_ids],
                feasible_candidates=np.array([s.size for s in self.selection.sets], dtype=np.uint32),
            )
        )
        self.raw_subscription(PERTURBATION, topics.PERTURBATION, qos.LATCHED, self.on_perturbation)
        self.window_stamp = stamp

    def on_perturbation(self, message: Any) -> None:
        perturbation = perturbation_from_msg(message)
        query_id = perturbation.query_id
        try:
            if perturbation.delta.size == 0:  # the original scenario: nobody moves
                tracks = []
            else:
                if perturbation.actor_ids != self.selection.actor_ids:
                    raise InfeasibleError(
                        f"query {query_id} perturbs actors {list(perturbation.actor_ids)}, "
                        f"the feasible sets are for {list(self.selection.actor_ids)}"
                    )
                tracks = [trajectory_track_msg(self.wire, t) for t in self.selection.project(perturbation.delta)]
        except ScenarioError as error:
            self.get_logger().warning(f"query {query_id} is infeasible: {error}")
            self.publish_score(failed_score_msg(self.wire, query_id, STATUS_INFEASIBLE, str(error)))
            return
        self.publish_tracks(track_array_msg(self.wire, query_id, self.window_stamp, self.frame_id, tracks))


def declare_perturber_config(node: GraphNode) -> PerturberConfig:
    config = declare_config(node, PerturberConfig)
    if config.horizon_steps != node.window.num_frames:
        raise ScenarioError(
            f"/perturber horizon_steps ({config.horizon_steps}) must equal window.history_frames + "
            f"window.future_frames ({node.window.num_frames})"
        )
    return config


def main() -> None:
    run_node(Perturber)


if __name__ == "__main__":
    main()
