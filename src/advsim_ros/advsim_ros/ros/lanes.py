"""The search node's evaluation lanes on the ROS graph, and what its search thread waits for.

Evaluation lanes (`advsim attack --lanes K`): the further lanes are whole graphs (perturber,
player, lidar_resim, stack, scorer) on ROS domains of their own, listed in the search's
``lane_domains``. The search node joins each of them with a context of its own (``Lane``) and
hands the queries of the algorithm's batch out in order, each lane the next one as soon as it is
free (core.search.lanes), so up to K queries run at once; every lane's perturber must have made
the same actor selection as this graph's before it gets a query (``Lanes.ready``). The
subscriptions' callbacks, on every lane's executor, fill one ``Board`` the search thread waits on.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.utilities import try_shutdown

from advsim_ros.contract import topics
from advsim_ros.contract.codec import Msg
from advsim_ros.contract.protocol import SelectionRecord, perturbation_msg, selection_from_msg
from advsim_ros.core.search.driver import DriverConfig
from advsim_ros.core.search.lanes import evaluate_on_lanes
from advsim_ros.core.types import Perturbation, ScenarioError
from advsim_ros.ros.graph_node import RUN_ID_PARAMETER, GraphNode, Publish

READER_POLL = 0.02  # how often the first query re-checks its readers [s]
READER_REPORT = 10.0  # how often a wait for readers says whom it waits for [s]


class Board:
    """The actor selection and the scores, filled by the callbacks, and the stop: the search thread waits on them."""

    def __init__(self) -> None:
        self.condition = threading.Condition()
        self.selection: SelectionRecord | None = None
        self.scores: dict[int, float] = {}  # query id -> L_adv (NaN: the query failed)
        self.stop = threading.Event()

    def select(self, selection: SelectionRecord) -> None:
        with self.condition:
            self.selection = selection
            self.condition.notify_all()

    def score(self, query_id: int, loss: float) -> None:
        with self.condition:
            self.scores[query_id] = loss
            self.condition.notify_all()

    def notify(self) -> None:
        with self.condition:
            self.condition.notify_all()

    def wait(self, ready: Callable[[], bool], timeout: float | None) -> bool:
        """Whether ``ready()`` came true within ``timeout`` (None: no limit) and the search was not stopped."""
        with self.condition:
            return self.condition.wait_for(lambda: self.stop.is_set() or ready(), timeout) and not self.stop.is_set()

    def close(self) -> None:
        self.stop.set()
        self.notify()


class Lane:
    """Another evaluation lane's graph, joined from this process: its own context on its own ROS domain."""

    def __init__(
        self, index: int, domain_id: int, run_id: int, on_score: Callable[[Msg], None], notify: Callable[[], None]
    ) -> None:
        self.index, self.domain_id, self._notify = index, domain_id, notify
        self.selection: SelectionRecord | None = None
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

    def _on_selection(self, message: Msg) -> None:
        self.selection = selection_from_msg(message)
        self._notify()  # the search waits for every lane's selection

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        try_shutdown(context=self.context)
        self._spinner.join(timeout=5.0)


class Lanes:
    """This graph's lane and the further ones: the waits before the first query, the hand-out of each batch."""

    def __init__(self, node: GraphNode, publish_perturbation: Publish, config: DriverConfig) -> None:
        self.node, self.config = node, config
        self.publishers = [publish_perturbation]  # lane 0: this graph
        self.board = Board()
        self.further: list[Lane] = []

    def join(self, on_score: Callable[[Msg], None]) -> None:
        """Join the further lanes' graphs (``lane_domains``); their scores go to ``on_score`` as this graph's do."""
        self.further = [
            Lane(index, domain_id, self.node.run_id, on_score, self.board.notify)
            for index, domain_id in enumerate(self.config.lane_domains, start=1)
        ]
        self.publishers.extend(lane.publish_perturbation for lane in self.further)

    @property
    def count(self) -> int:
        return 1 + len(self.further)

    def close(self) -> None:
        for lane in self.further:
            lane.close()

    def ready(self) -> SelectionRecord | None:
        """This graph's actor selection once every lane made the same and has its readers; None when stopped."""
        board = self.board
        if not board.wait(lambda: board.selection is not None, None):
            return None
        selection = board.selection
        assert selection is not None  # the wait above saw it
        if not self._same_selection(selection) or not self._readers_matched():
            return None
        return selection

    def evaluate(self, perturbations: Sequence[Perturbation], sent: Callable[[Perturbation], None]) -> list[float]:
        """Hand the queries to the lanes, each lane the next one as soon as it is free; wait for every score.

        Returns L_adv per query, NaN when it failed or no score came within ``score_timeout`` of its sending.
        """
        board, run_id = self.board, self.node.run_id
        return evaluate_on_lanes(
            perturbations, self.count, lambda lane, p: self.publishers[lane](perturbation_msg(p, run_id)),
            board.scores, board.wait, board.stop.is_set, self.config.score_timeout, sent=sent,
            timed_out=self._timed_out,
        )  # fmt: skip

    def _timed_out(self, query_id: int) -> None:
        self.node.get_logger().error(f"query {query_id}: no score within {self.config.score_timeout} s")

    def _same_selection(self, selection: SelectionRecord) -> bool:
        """Wait until every further lane's perturber selected the same actors as this graph's."""
        if self.further:
            self.node.get_logger().info(
                f"waiting for the actor selection of {len(self.further)} more evaluation lane(s)"
            )
        if not self.board.wait(lambda: all(lane.selection is not None for lane in self.further), None):
            return False

        def layout(record: SelectionRecord) -> tuple[object, ...]:
            return record.scenario_id, record.actor_ids, record.dimension, record.feasible_candidates

        for lane in self.further:
            theirs = lane.selection
            assert theirs is not None  # the wait above saw every lane's
            if layout(theirs) != layout(selection):
                raise ScenarioError(
                    f"evaluation lane {lane.index} (ROS domain {lane.domain_id}) selected actors "
                    f"{list(theirs.actor_ids)}, this graph {list(selection.actor_ids)}: lanes must be identical"
                )
        return True

    def _readers_matched(self) -> bool:
        """Wait until every lane's perturbation topic has its readers: a reader matched later (the attack's
        monitor, whose process starts first but discovers this one last) would get only the latest query."""
        nodes = [self.node, *(lane.node for lane in self.further)]
        readers = self.config.perturbation_readers
        report_at = time.monotonic() + READER_REPORT
        while not all(node.matched_readers(topics.PERTURBATION) >= readers for node in nodes):
            if self.board.stop.wait(READER_POLL):
                return False
            if time.monotonic() >= report_at:
                report_at += READER_REPORT
                counts = [node.matched_readers(topics.PERTURBATION) for node in nodes]
                self.node.get_logger().info(f"waiting for {readers} readers of the perturbations per lane: {counts}")
        return True
