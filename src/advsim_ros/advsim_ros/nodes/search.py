"""search: owns the black-box search; proposes perturbations and waits for their scores.

It waits for the perturber's actor selection (which fixes the delta's dimension), then drives
the search (core.search.driver): the original scenario as query 0, the algorithm's queries,
then re-runs of the best ones. Queries already in the attack's journal (written by `advsim
attack` as scores arrive) are replayed into the algorithm instead of recomputed. When the
search is over it says so on /advsim/search_status (latched): the orchestrator's signal to finish.

Evaluation lanes (`advsim attack --lanes K`): the further lanes are whole graphs on ROS domains
of their own, listed in ``lane_domains``, joined from this node (ros.lanes); the queries of the
algorithm's batch are handed out in order, each lane the next one as soon as it is free
(core.search.lanes), so up to K queries run at once.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from advsim_ros import graph
from advsim_ros.contract import topics
from advsim_ros.contract.codec import Msg
from advsim_ros.contract.protocol import (
    SearchStatusRecord,
    score_from_msg,
    search_status_msg,
    selection_from_msg,
)
from advsim_ros.core.journal import read_records
from advsim_ros.core.search.driver import DriverConfig, drive_search
from advsim_ros.core.search.registry import ALGORITHM_NAMES, config_type, make_search
from advsim_ros.core.types import Perturbation, ScenarioError
from advsim_ros.nodes.scenario_node import declare_section
from advsim_ros.ros.graph_node import GraphNode, run_node
from advsim_ros.ros.lanes import Lanes
from advsim_ros.ros.params import declare_config


class SearchNode(GraphNode):
    def __init__(self) -> None:
        super().__init__(graph.SEARCH.name)
        self.config = declare_section(self, graph.SEARCH, "", DriverConfig)
        if self.config.algorithm not in ALGORITHM_NAMES:
            raise ScenarioError(
                f"/search algorithm: {self.config.algorithm!r} is not one of {', '.join(ALGORITHM_NAMES)}"
            )
        self.algorithm_config = declare_config(self, config_type(self.config.algorithm), f"{self.config.algorithm}.")
        self.publish_perturbation = self.publisher(topics.PERTURBATION)
        self.publish_status = self.publisher(topics.SEARCH_STATUS)
        self._asked = 0
        self._lanes = Lanes(self, self.publish_perturbation, self.config)  # its board: what the search waits for
        self._board = self._lanes.board
        self.subscribe(topics.ACTOR_SELECTION, self._on_selection)
        self.subscribe(topics.SCORE, self._on_score)
        self._lanes.join(self._on_score)
        self._driver = threading.Thread(target=self._run, name="search", daemon=True)
        self._driver.start()

    def _on_selection(self, message: Msg) -> None:
        self._board.select(selection_from_msg(message))

    def _on_score(self, message: Msg) -> None:
        score = score_from_msg(message)
        self.trace("score_received", score.query_id)
        self._board.score(score.query_id, score.adversarial_loss if score.ok else math.nan)

    def destroy_node(self) -> None:
        self._board.close()
        self._driver.join(timeout=5.0)
        self._lanes.close()
        super().destroy_node()

    def _evaluate(self, perturbations: Sequence[Perturbation]) -> list[float]:
        return self._lanes.evaluate(perturbations, self._sent)

    def _sent(self, perturbation: Perturbation) -> None:
        self._asked += 1
        self.trace("perturbation_sent", perturbation.query_id)
        self.publish_status(search_status_msg(SearchStatusRecord(self._asked, finished=False), self.run_id))

    def _run(self) -> None:
        selection = self._lanes.ready()  # every lane's selection the same, and read
        if selection is None:
            return
        algorithm = make_search(
            self.config.algorithm, selection.dimension, np.random.default_rng(self.config.seed), self.algorithm_config
        )
        journal = read_records(Path(self.config.journal_file)) if self.config.journal_file else []
        recorded = {record.query_id: record for record in journal}
        self.get_logger().info(
            f"{self.config.algorithm}: {algorithm.config.max_queries} queries over {selection.dimension} dimensions, "
            f"actors {list(selection.actor_ids)}, {len(recorded)} finished queries in the journal, "
            f"{self._lanes.count} evaluation lane(s)"
        )
        made = drive_search(
            algorithm, self._evaluate, selection.scenario_id, selection.actor_ids, self.config, recorded,
            self._board.stop.is_set, lanes=self._lanes.count,
        )  # fmt: skip
        if not self._board.stop.is_set():
            self.get_logger().info(f"search finished: {made} queries")
            # the whole count, journal replays included: the monitor ends the attack when it has journaled them all
            self.publish_status(search_status_msg(SearchStatusRecord(made, finished=True), self.run_id))


def main() -> None:
    run_node(SearchNode)


if __name__ == "__main__":
    main()
