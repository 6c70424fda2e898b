"""search: owns the black-box search; proposes one perturbation at a time and waits for its score.

It waits for the perturber's actor selection (which fixes the delta's dimension), then drives
the search (core.search.driver): the original scenario as query 0, the algorithm's queries,
then re-runs of the best ones. Queries already in the attack's journal (written by `advsim
attack` as scores arrive) are replayed into the algorithm instead of recomputed. When the
search is over it says so on /advsim/search_status (latched): the orchestrator's signal to finish.
"""

from __future__ import annotations

import math
import threading
from pathlib import Path
from typing import Any

import numpy as np

from advsim_ros.contract import topics
from advsim_ros.contract.protocol import (
    SearchStatusRecord,
    perturbation_msg,
    score_from_msg,
    search_status_msg,
    selection_from_msg,
)
from advsim_ros.core.journal import read_records
from advsim_ros.core.search.driver import DriverConfig, drive_search
from advsim_ros.core.search.registry import ALGORITHM_NAMES, config_type, make_search
from advsim_ros.core.types import Perturbation, ScenarioError
from advsim_ros.ros.graph_node import GraphNode, run_node
from advsim_ros.ros.params import declare_config


class SearchNode(GraphNode):
    def __init__(self) -> None:
        super().__init__("search")
        self.config = declare_config(self, DriverConfig)
        if self.config.algorithm not in ALGORITHM_NAMES:
            raise ScenarioError(
                f"/search algorithm: {self.config.algorithm!r} is not one of {', '.join(ALGORITHM_NAMES)}"
            )
        self.algorithm_config = declare_config(self, config_type(self.config.algorithm), f"{self.config.algorithm}.")
        self.publish_perturbation = self.publisher(topics.PERTURBATION)
        self.publish_status = self.publisher(topics.SEARCH_STATUS)
        self._asked = 0
        self._condition = threading.Condition()
        self._selection: Any = None
        self._scores: dict[int, float] = {}
        self.subscribe(topics.ACTOR_SELECTION, self._on_selection)
        self.subscribe(topics.SCORE, self._on_score)
        self._stop = threading.Event()
        self._driver = threading.Thread(target=self._run, name="search", daemon=True)
        self._driver.start()

    def _on_selection(self, message: Any) -> None:
        with self._condition:
            self._selection = selection_from_msg(message)
            self._condition.notify_all()

    def _on_score(self, message: Any) -> None:
        score = score_from_msg(message)
        self.trace("score_received", score.query_id)
        with self._condition:
            self._scores[score.query_id] = score.adversarial_loss if score.ok else math.nan
            self._condition.notify_all()

    def destroy_node(self) -> None:
        self._stop.set()
        with self._condition:
            self._condition.notify_all()
        self._driver.join(timeout=5.0)
        super().destroy_node()

    def _wait(self, ready: Any, timeout: float | None) -> bool:
        with self._condition:
            return self._condition.wait_for(lambda: self._stop.is_set() or ready(), timeout) and not self._stop.is_set()

    def _evaluate(self, perturbation: Perturbation) -> float:
        """Publish a query and wait for its score: L_adv, or NaN when the query failed or timed out."""
        self.publish_perturbation(perturbation_msg(perturbation, self.run_id))
        self._asked += 1
        self.publish_status(search_status_msg(SearchStatusRecord(self._asked, finished=False), self.run_id))
        query_id = perturbation.query_id
        self.trace("perturbation_sent", query_id)
        if not self._wait(lambda: query_id in self._scores, self.config.score_timeout):
            if not self._stop.is_set():
                self.get_logger().error(f"query {query_id}: no score within {self.config.score_timeout} s")
            return math.nan
        return self._scores[query_id]

    def _run(self) -> None:
        if not self._wait(lambda: self._selection is not None, None):
            return
        selection = self._selection
        algorithm = make_search(
            self.config.algorithm, selection.dimension, np.random.default_rng(self.config.seed), self.algorithm_config
        )
        journal = read_records(Path(self.config.journal_file)) if self.config.journal_file else []
        recorded = {record.query_id: record for record in journal}
        self.get_logger().info(
            f"{self.config.algorithm}: {algorithm.config.max_queries} queries over {selection.dimension} dimensions, "
            f"actors {list(selection.actor_ids)}, {len(recorded)} finished queries in the journal"
        )
        drive_search(
            algorithm, self._evaluate, selection.scenario_id, selection.actor_ids, self.config, recorded,
            self._stop.is_set,
        )  # fmt: skip
        if not self._stop.is_set():
            self.get_logger().info("search finished")
            self.publish_status(search_status_msg(SearchStatusRecord(self._asked, finished=True), self.run_id))


def main() -> None:
    run_node(SearchNode)


if __name__ == "__main__":
    main()
