"""search: owns the black-box search; proposes perturbations and waits for their scores.

It waits for the perturber's actor selection (which fixes the delta's dimension), then drives
the search (core.search.driver): the original scenario as query 0, the algorithm's queries,
then re-runs of the best ones. Queries already in the attack's journal (written by `advsim
attack` as scores arrive) are replayed into the algorithm instead of recomputed. When the
search is over it says so on /advsim/search_status (latched): the orchestrator's signal to finish.

Evaluation lanes (`advsim attack --lanes K`): the further lanes are whole graphs (perturber,
player, lidar_resim, stack, scorer) on ROS domains of their own, listed in ``lane_domains``.
The node joins each of them with a context of its own and hands the queries of the algorithm's
batch out in order, each lane the next one as soon as it is free, so up to K queries run at once;
every lane's perturber must have made the same actor selection as this graph's before it gets a query.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter

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
from advsim_ros.ros.graph_node import RUN_ID_PARAMETER, GraphNode, run_node
from advsim_ros.ros.params import declare_config

_READER_POLL = 0.02  # how often the first query re-checks its readers [s]


class _Lane:
    """Another evaluation lane's graph, joined from this process: its own context on its own ROS domain."""

    def __init__(
        self, index: int, domain_id: int, run_id: int, on_score: Callable[[Any], None], notify: Callable[[], None]
    ) -> None:
        self.index, self.domain_id, self._notify = index, domain_id, notify
        self.selection: Any = None
        self.context = Context()
        rclpy.init(args=[], context=self.context, domain_id=domain_id)
        self.node = GraphNode(f"search_lane{index}", [Parameter(RUN_ID_PARAMETER, value=run_id)], context=self.context)
        self.publish_perturbation = self.node.publisher(topics.PERTURBATION)
        self.node.subscribe(topics.SCORE, on_score)
        self.node.subscribe(topics.ACTOR_SELECTION, self._on_selection)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._spinner = threading.Thread(target=self.executor.spin, name=f"lane{index}", daemon=True)
        self._spinner.start()

    def _on_selection(self, message: Any) -> None:
        self.selection = selection_from_msg(message)
        self._notify()  # the search waits for every lane's selection

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        self._spinner.join(timeout=5.0)


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
        self._lanes = [
            _Lane(index, domain_id, self.run_id, self._on_score, self._notify)
            for index, domain_id in enumerate(self.config.lane_domains, start=1)
        ]
        self._stop = threading.Event()
        self._driver = threading.Thread(target=self._run, name="search", daemon=True)
        self._driver.start()

    def _on_selection(self, message: Any) -> None:
        with self._condition:
            self._selection = selection_from_msg(message)
            self._condition.notify_all()

    def _notify(self) -> None:
        with self._condition:
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
        for lane in self._lanes:
            lane.close()
        super().destroy_node()

    def _wait(self, ready: Any, timeout: float | None) -> bool:
        with self._condition:
            return self._condition.wait_for(lambda: self._stop.is_set() or ready(), timeout) and not self._stop.is_set()

    def _evaluate(self, perturbations: Sequence[Perturbation]) -> list[float]:
        """Hand the queries to the lanes, each lane the next one as soon as it is free; wait for every score.

        Returns L_adv per query, NaN when it failed or no score came within ``score_timeout`` of its sending.
        """
        publishers = [self.publish_perturbation, *(lane.publish_perturbation for lane in self._lanes)]
        waiting = list(perturbations)
        busy: dict[int, tuple[int, float]] = {}  # lane -> (query id, sent at [monotonic s])
        timed_out: set[int] = set()
        while (waiting or busy) and not self._stop.is_set():
            for lane in range(len(publishers)):
                if lane not in busy and waiting:
                    perturbation = waiting.pop(0)
                    publishers[lane](perturbation_msg(perturbation, self.run_id))
                    busy[lane] = (perturbation.query_id, time.monotonic())
                    self._asked += 1
                    self.trace("perturbation_sent", perturbation.query_id)
                    self.publish_status(search_status_msg(SearchStatusRecord(self._asked, finished=False), self.run_id))
            deadline = min(sent for _, sent in busy.values()) + self.config.score_timeout
            self._wait(
                lambda: any(query_id in self._scores for query_id, _ in busy.values()),
                max(0.0, deadline - time.monotonic()),
            )
            for lane, (query_id, sent) in list(busy.items()):
                if query_id in self._scores:
                    del busy[lane]
                elif time.monotonic() - sent >= self.config.score_timeout:
                    self.get_logger().error(f"query {query_id}: no score within {self.config.score_timeout} s")
                    timed_out.add(query_id)
                    del busy[lane]
        return [math.nan if p.query_id in timed_out else self._scores.get(p.query_id, math.nan) for p in perturbations]

    def _lanes_ready(self, selection: Any) -> bool:
        """Wait until every further lane's perturber selected the same actors as this graph's."""
        if self._lanes:
            self.get_logger().info(f"waiting for the actor selection of {len(self._lanes)} more evaluation lane(s)")
        if not self._wait(lambda: all(lane.selection is not None for lane in self._lanes), None):
            return False

        def layout(record: Any) -> tuple[Any, ...]:
            return record.scenario_id, record.actor_ids, record.dimension, record.feasible_candidates

        for lane in self._lanes:
            if layout(lane.selection) != layout(selection):
                raise ScenarioError(
                    f"evaluation lane {lane.index} (ROS domain {lane.domain_id}) selected actors "
                    f"{list(lane.selection.actor_ids)}, this graph {list(selection.actor_ids)}: lanes must be identical"
                )
        return True

    def _readers_matched(self) -> bool:
        """Wait until every lane's perturbation topic has its readers: a reader matched later (the attack's
        monitor, whose process starts first but discovers this one last) would get only the latest query."""
        nodes = [self, *(lane.node for lane in self._lanes)]
        report_at = time.monotonic() + 10.0
        while not all(node.matched_readers(topics.PERTURBATION) >= self.config.perturbation_readers for node in nodes):
            if self._stop.wait(_READER_POLL):
                return False
            if time.monotonic() >= report_at:
                report_at += 10.0
                counts = [node.matched_readers(topics.PERTURBATION) for node in nodes]
                self.get_logger().info(
                    f"waiting for {self.config.perturbation_readers} readers of the perturbations per lane: {counts}"
                )
        return True

    def _run(self) -> None:
        if not self._wait(lambda: self._selection is not None, None):
            return
        selection = self._selection
        if not self._lanes_ready(selection):
            return
        if not self._readers_matched():
            return
        algorithm = make_search(
            self.config.algorithm, selection.dimension, np.random.default_rng(self.config.seed), self.algorithm_config
        )
        journal = read_records(Path(self.config.journal_file)) if self.config.journal_file else []
        recorded = {record.query_id: record for record in journal}
        self.get_logger().info(
            f"{self.config.algorithm}: {algorithm.config.max_queries} queries over {selection.dimension} dimensions, "
            f"actors {list(selection.actor_ids)}, {len(recorded)} finished queries in the journal, "
            f"{1 + len(self._lanes)} evaluation lane(s)"
        )
        made = drive_search(
            algorithm, self._evaluate, selection.scenario_id, selection.actor_ids, self.config, recorded,
            self._stop.is_set, lanes=1 + len(self._lanes),
        )  # fmt: skip
        if not self._stop.is_set():
            self.get_logger().info(f"search finished: {made} queries")
            # the whole count, journal replays included: the monitor ends the attack when it has journaled them all
            self.publish_status(search_status_msg(SearchStatusRecord(made, finished=True), self.run_id))


def main() -> None:
    run_node(SearchNode)


if __name__ == "__main__":
    main()
