"""search: owns the black-box search; proposes one perturbation at a time and waits for its score.

It waits for the perturber's actor selection (which fixes the delta's dimension), scores the
original scenario first (query 0, empty delta), then asks the algorithm for a point, publishes it
as a Perturbation, waits for that query's QueryScore and tells the algorithm its L_adv (NaN for a
failed query: the algorithm treats it as the worst value seen). Every finished query is appended
to the results file at once (fsync'd), and a restarted search replays those results into the
algorithm instead of recomputing them. At the end it re-runs the best query once (algorithm
"replay") so that the run's outputs can record it.
"""

from __future__ import annotations

import json
import math
import os
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from advsim_ros.core.search.base import SearchAlgorithm
from advsim_ros.core.search.registry import ALGORITHM_NAMES, config_type, make_search
from advsim_ros.core.types import Perturbation, ScenarioError
from advsim_ros.ros import qos, topics
from advsim_ros.ros.graph_node import GraphNode, run_node
from advsim_ros.ros.params import declare_config
from advsim_ros.ros.wire import ACTOR_SELECTION, PERTURBATION, QUERY_SCORE, STATUS_OK, perturbation_msg

ORIGINAL_QUERY = 0


@dataclass(frozen=True)
class SearchNodeConfig:
    """/search parameters besides the algorithm's own (params/search.yaml)."""

    algorithm: str = "bo"  # one of bo, ga, rs, nes, bandit, random
    seed: int = 0  # seeds the algorithm's generator
    score_timeout: float = 900.0  # longest wait for one query's score [s, wall clock]
    results_file: str = ""  # JSON lines of finished queries, appended as they finish; "" = keep none
    score_original: bool = True  # score the unperturbed scenario first, as query 0
    replay_best: bool = True  # re-run the best query once at the end (algorithm "replay")

    def __post_init__(self) -> None:
        if self.algorithm not in ALGORITHM_NAMES:
            raise ScenarioError(f"/search algorithm: {self.algorithm!r} is not one of {', '.join(ALGORITHM_NAMES)}")
        if not self.score_timeout > 0.0:
            raise ScenarioError(f"/search score_timeout: must be positive, got {self.score_timeout}")


class SearchNode(GraphNode):
    def __init__(self) -> None:
        super().__init__("search")
        self.config = declare_config(self, SearchNodeConfig)
        self.algorithm_config = declare_config(self, config_type(self.config.algorithm), f"{self.config.algorithm}.")
        self.publish_perturbation = self.raw_publisher(PERTURBATION, topics.PERTURBATION, qos.LATCHED)
        self._condition = threading.Condition()
        self._selection: Any = None
        self._scores: dict[int, Any] = {}
        self.raw_subscription(ACTOR_SELECTION, topics.ACTOR_SELECTION, qos.LATCHED, self._on_selection)
        self.raw_subscription(QUERY_SCORE, topics.SCORE, qos.HISTORY, self._on_score)
        self._stop = threading.Event()
        self._driver = threading.Thread(target=self._run, name="search", daemon=True)
        self._driver.start()

    def _on_selection(self, message: Any) -> None:
        with self._condition:
            self._selection = message
            self._condition.notify_all()

    def _on_score(self, message: Any) -> None:
        with self._condition:
            self._scores[int(message.query_id)] = message
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
        self.publish_perturbation(perturbation_msg(self.wire, perturbation))
        query_id = perturbation.query_id
        if not self._wait(lambda: query_id in self._scores, self.config.score_timeout):
            if not self._stop.is_set():
                self.get_logger().error(f"query {query_id}: no score within {self.config.score_timeout} s")
            value = math.nan
        else:
            score = self._scores[query_id]
            value = float(score.adversarial_loss) if score.status == STATUS_OK else math.nan
        self._record(perturbation, value)
        return value

    def _record(self, perturbation: Perturbation, value: float) -> None:
        if not self.config.results_file:
            return
        line = {
            "query_id": perturbation.query_id,
            "algorithm": perturbation.algorithm,
            "actor_ids": list(perturbation.actor_ids),
            "delta": perturbation.delta.tolist(),
            "adversarial_loss": None if math.isnan(value) else value,
        }
        with open(self.config.results_file, "a", encoding="utf-8") as results:
            results.write(json.dumps(line) + "\n")
            results.flush()
            os.fsync(results.fileno())

    def _recorded(self) -> list[dict[str, Any]]:
        path = Path(self.config.results_file)
        if not self.config.results_file or not path.exists():
            return []
        records = []
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
            if not line.strip():
                continue
            try:
                records.append(json.loads(line))
            except json.JSONDecodeError:
                # a line cut short by a crash while it was written: everything before it stands
                self.get_logger().warning(f"{path}:{number}: unreadable result line ignored")
                break
        return records

    def _run(self) -> None:
        if not self._wait(lambda: self._selection is not None, None):
            return
        selection = self._selection
        actor_ids = tuple(selection.actor_ids)
        scenario_id = str(selection.scenario_id)
        algorithm = make_search(
            self.config.algorithm,
            int(selection.dimension),
            np.random.default_rng(self.config.seed),
            self.algorithm_config,
        )
        self.get_logger().info(
            f"{self.config.algorithm}: {algorithm.config.max_queries} queries over {selection.dimension} dimensions, "
            f"actors {list(actor_ids)}"
        )
        recorded = {record["query_id"]: record for record in self._recorded()}

        if self.config.score_original and ORIGINAL_QUERY not in recorded:
            self._evaluate(Perturbation(ORIGINAL_QUERY, scenario_id, (), np.zeros(0), "original"))
        next_id = ORIGINAL_QUERY + 1
        while not algorithm.done and not self._stop.is_set():
            point = algorithm.ask(1)[0]
            record = recorded.get(next_id)
            if record is not None and np.allclose(record["delta"], point, atol=1e-9):
                loss = record["adversarial_loss"]
                value = math.nan if loss is None else float(loss)
                self.get_logger().info(f"query {next_id}: result recorded before, not recomputed")
            else:
                value = self._evaluate(Perturbation(next_id, scenario_id, actor_ids, point, self.config.algorithm))
            algorithm.tell(point[None, :], [value])
            next_id += 1
        if self.config.replay_best and not self._stop.is_set():
            self._replay_best(algorithm, scenario_id, actor_ids, next_id)
        self.get_logger().info("search finished")

    def _replay_best(
        self, algorithm: SearchAlgorithm[Any], scenario_id: str, actor_ids: tuple[str, ...], query_id: int
    ) -> None:
        best = algorithm.best
        if best is None:
            self.get_logger().warning("no query succeeded: nothing to replay")
            return
        self._evaluate(Perturbation(query_id, scenario_id, actor_ids, best.point, "replay"))


def main() -> None:
    run_node(SearchNode)


if __name__ == "__main__":
    main()
