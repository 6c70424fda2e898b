"""Handing a batch's queries to evaluation lanes (core.search.lanes), on a simulated clock."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from advsim_ros.core.search.lanes import evaluate_on_lanes
from advsim_ros.core.types import Perturbation


class Graphs:
    """Lanes that score each query after its duration (None: never), on a clock advanced by the waits."""

    def __init__(self, durations: dict[int, float | None], losses: dict[int, float]) -> None:
        self.durations, self.losses = durations, losses
        self.now = 0.0
        self.scores: dict[int, float] = {}
        self.due: dict[int, float] = {}  # query -> when its score arrives
        self.sent: list[tuple[float, int, int]] = []  # (time, lane, query)
        self.waits: list[float] = []

    def send(self, lane: int, perturbation: Perturbation) -> None:
        query = perturbation.query_id
        self.sent.append((self.now, lane, query))
        duration = self.durations[query]
        if duration is not None:
            self.due[query] = self.now + duration

    def wait(self, ready: Callable[[], bool], timeout: float) -> bool:
        self.waits.append(timeout)
        if not ready():
            self.now = min([self.now + timeout, *(t for t in self.due.values() if t > self.now)])
        for query, at in list(self.due.items()):
            if at <= self.now:
                self.scores[query] = self.losses[query]
                del self.due[query]
        return ready()

    def clock(self) -> float:
        return self.now


def _queries(*ids: int) -> list[Perturbation]:
    return [Perturbation(i, "scenario", ("car",), np.full(2, 0.1 * i), "ga") for i in ids]


def test_each_lane_takes_the_next_query_as_soon_as_it_is_free_and_the_scores_come_back_in_query_order() -> None:
    graphs = Graphs({1: 3.0, 2: 1.0, 3: 1.0, 4: 0.5}, {1: 10.0, 2: 20.0, 3: 30.0, 4: 40.0})
    told: list[int] = []
    values = evaluate_on_lanes(
        _queries(1, 2, 3, 4), 2, graphs.send, graphs.scores, graphs.wait, lambda: False, 100.0,
        sent=lambda p: told.append(p.query_id), clock=graphs.clock,
    )  # fmt: skip
    assert values == [10.0, 20.0, 30.0, 40.0]
    # lane 1 finishes query 2 at t=1, takes 3, then 4 at t=2; lane 0 is busy with query 1 until t=3
    assert graphs.sent == [(0.0, 0, 1), (0.0, 1, 2), (1.0, 1, 3), (2.0, 1, 4)]
    assert told == [1, 2, 3, 4]


def test_one_lane_evaluates_the_queries_one_after_the_other() -> None:
    graphs = Graphs({5: 2.0, 6: 1.0}, {5: 1.5, 6: 2.5})
    values = evaluate_on_lanes(
        _queries(5, 6), 1, graphs.send, graphs.scores, graphs.wait, lambda: False, 100.0, clock=graphs.clock
    )
    assert values == [1.5, 2.5]
    assert graphs.sent == [(0.0, 0, 5), (2.0, 0, 6)]


def test_a_query_without_a_score_within_the_timeout_is_nan_and_frees_its_lane() -> None:
    graphs = Graphs({1: None, 2: 1.0, 3: 4.0}, {2: 7.0, 3: 8.0})
    late: list[int] = []
    values = evaluate_on_lanes(
        _queries(1, 2, 3), 2, graphs.send, graphs.scores, graphs.wait, lambda: False, 10.0,
        timed_out=late.append, clock=graphs.clock,
    )  # fmt: skip
    assert math.isnan(values[0])
    assert values[1:] == [7.0, 8.0]
    assert late == [1]
    assert graphs.now == 10.0  # query 1 given up score_timeout after its sending
    assert graphs.waits[0] == 10.0  # the first wait lasts until the oldest query's timeout


def test_a_late_score_does_not_count_and_a_stop_leaves_the_queries_not_yet_scored_nan() -> None:
    graphs = Graphs({1: 12.0}, {1: 3.0})
    values = evaluate_on_lanes(
        _queries(1), 1, graphs.send, graphs.scores, graphs.wait, lambda: False, 10.0, clock=graphs.clock
    )
    assert math.isnan(values[0])
    stopped = Graphs({1: 1.0, 2: 1.0}, {1: 1.0, 2: 2.0})
    values = evaluate_on_lanes(
        _queries(1, 2), 1, stopped.send, stopped.scores, stopped.wait, lambda: bool(stopped.sent), 10.0,
        clock=stopped.clock,
    )  # fmt: skip
    assert values[0] == 1.0
    assert math.isnan(values[1])  # stopped once the first was sent: the second never is
    assert stopped.sent == [(0.0, 0, 1)]
