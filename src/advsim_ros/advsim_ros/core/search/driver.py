"""Driving one attack's search: the original scenario, the algorithm's queries, then re-runs of the best.

``drive_search`` asks the algorithm one point at a time and evaluates it through a callback
(the search node publishes it and waits for its score). Queries already in the journal are
not evaluated again: their recorded values are told instead, which reproduces the run up to
where it stopped because the algorithm is deterministic for its seed. After the budget, each
of the ``rerun_top`` best queries is evaluated ``reruns`` more times (the best last), so the
outputs can say whether a found failure reproduces.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from advsim_ros.core.journal import JournalError, QueryRecord, ranked_queries
from advsim_ros.core.search.base import SearchAlgorithm
from advsim_ros.core.types import FloatArray, Perturbation, ScenarioError

ORIGINAL_QUERY = 0
ORIGINAL, RERUN = "original", "rerun"  # algorithm names of the non-search queries

Evaluate = Callable[[Perturbation], float]  # L_adv of a query, NaN when it failed


@dataclass(frozen=True)
class DriverConfig:
    """/search parameters besides the algorithm's own (params/search.yaml)."""

    algorithm: str = "bo"  # one of core.search.registry.ALGORITHM_NAMES
    seed: int = 0  # seeds the algorithm's generator
    score_timeout: float = 900.0  # longest wait for one query's score [s, wall clock]
    journal_file: str = ""  # the attack's journal: finished queries to replay instead of recompute ("" = none)
    score_original: bool = True  # evaluate the unperturbed scenario first, as query 0
    reruns: int = 2  # evaluations of each best query after the search (reproducibility check)
    rerun_top: int = 1  # how many of the best queries are re-run

    def __post_init__(self) -> None:
        if self.reruns < 0 or self.rerun_top < 0:
            raise ScenarioError(f"search reruns and rerun_top must be >= 0, got {self.reruns}, {self.rerun_top}")
        if not self.score_timeout > 0.0:
            raise ScenarioError(f"search score_timeout: must be positive, got {self.score_timeout}")


class _Recorded:
    """Evaluations through the journal: a recorded query gives its value, anything else is evaluated."""

    def __init__(self, evaluate: Evaluate, recorded: Mapping[int, QueryRecord], log: logging.Logger) -> None:
        self._evaluate, self._recorded, self._log = evaluate, recorded, log

    def __call__(self, perturbation: Perturbation) -> float:
        record = self._recorded.get(perturbation.query_id)
        if record is None:
            return self._evaluate(perturbation)
        same = record.algorithm == perturbation.algorithm and np.array_equal(
            np.asarray(record.delta, dtype=np.float64), perturbation.delta
        )
        if not same:
            raise JournalError(
                f"query {perturbation.query_id}: the search proposed {perturbation.algorithm} "
                f"{perturbation.delta.tolist()} but the journal holds {record.algorithm} {list(record.delta)}: "
                "the search is not deterministic"
            )
        return record.value


def drive_search(
    algorithm: SearchAlgorithm[Any],
    evaluate: Evaluate,
    scenario_id: str,
    actor_ids: tuple[str, ...],
    config: DriverConfig,
    recorded: Mapping[int, QueryRecord],
    stopped: Callable[[], bool],
    log: logging.Logger | None = None,
) -> None:
    """Run the whole search (see the module docstring); returns early when ``stopped()``."""
    run = _Recorded(evaluate, recorded, log or logging.getLogger(__name__))
    if config.score_original:
        run(Perturbation(ORIGINAL_QUERY, scenario_id, (), np.zeros(0), ORIGINAL))
    query_id = ORIGINAL_QUERY + 1
    points: dict[int, FloatArray] = {}
    values: dict[int, float] = {}
    while not algorithm.done and not stopped():
        point = algorithm.ask(1)[0]
        value = run(Perturbation(query_id, scenario_id, actor_ids, point, algorithm.name))
        algorithm.tell(point[None, :], [value])
        points[query_id], values[query_id] = point, value
        query_id += 1
    for best in reversed(ranked_queries(values, config.rerun_top)):  # the best last: its replay is recorded
        for _ in range(config.reruns):
            if stopped():
                return
            run(Perturbation(query_id, scenario_id, actor_ids, points[best], RERUN))
            query_id += 1
