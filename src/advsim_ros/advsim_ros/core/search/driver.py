"""Driving one attack's search: the original scenario, the algorithm's queries, then re-runs of the best.

``drive_search`` asks the algorithm for one point at a time or, with several evaluation lanes,
for its whole batch, and evaluates it through a callback (the search node hands the batch's
queries to its lanes, graphs of their own, each lane taking the next query as soon as it is
free, and waits for all their scores). The algorithm proposes the same points whatever the
batching (core.search.base), and query ids are handed out in the order of the points, so the
queries, their ids and (for a deterministic stack) their scores do not depend on ``lanes``.
Queries already in the journal are not evaluated again: their recorded values are told instead,
which reproduces the run up to where it stopped because the algorithm is deterministic for its
seed. After the budget, each of the ``rerun_top`` best queries is evaluated ``reruns`` more
times (the best last), so the outputs can say whether a found failure reproduces. Then the
controls: the original ``reruns`` more times (does the unperturbed scenario reproduce?) and the
identity control, the perturbed actors re-inserted on their logged tracks through the
re-simulation (what the simulator alone does to the stack; docs/attack.md, "Reading a finding").
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from advsim_ros.core.journal import JournalError, QueryRecord, ranked_queries
from advsim_ros.core.search.base import SearchAlgorithm
from advsim_ros.core.types import FloatArray, Perturbation, ScenarioError

ORIGINAL_QUERY = 0
ORIGINAL, RERUN, IDENTITY = "original", "rerun", "identity"  # algorithm names of the non-search queries
NOT_SEARCHED = (ORIGINAL, RERUN, IDENTITY)

EvaluateBatch = Callable[[Sequence[Perturbation]], list[float]]  # L_adv of each query, NaN when it failed


@dataclass(frozen=True)
class DriverConfig:
    """/search parameters besides the algorithm's own (params/search.yaml)."""

    algorithm: str = "bo"  # one of core.search.registry.ALGORITHM_NAMES
    seed: int = 0  # seeds the algorithm's generator
    score_timeout: float = 900.0  # longest wait for one query's score [s, wall clock]
    journal_file: str = ""  # the attack's journal: finished queries to replay instead of recompute ("" = none)
    score_original: bool = True  # evaluate the unperturbed scenario first, as query 0
    reruns: int = 2  # evaluations of each best query, and of the original, after the search (reproducibility check)
    rerun_top: int = 1  # how many of the best queries are re-run
    identity_control: bool = True  # evaluate the perturbed actors on their logged tracks, re-simulated, last
    lane_domains: tuple[int, ...] = ()  # ROS domains of the further evaluation lanes (advsim attack --lanes)
    # The first query waits until this many readers of /advsim/perturbation are matched in every lane: a
    # latched topic gives a late reader only the last query (advsim attack: 2, the perturber and its monitor).
    perturbation_readers: int = 1

    def __post_init__(self) -> None:
        if self.reruns < 0 or self.rerun_top < 0:
            raise ScenarioError(f"search reruns and rerun_top must be >= 0, got {self.reruns}, {self.rerun_top}")
        if self.perturbation_readers < 0:
            raise ScenarioError(f"search perturbation_readers: must be >= 0, got {self.perturbation_readers}")
        if not self.score_timeout > 0.0:
            raise ScenarioError(f"search score_timeout: must be positive, got {self.score_timeout}")


class _Recorded:
    """Evaluations through the journal: a recorded query gives its value, the others are evaluated together."""

    def __init__(self, evaluate: EvaluateBatch, recorded: Mapping[int, QueryRecord], log: logging.Logger) -> None:
        self._evaluate, self._recorded, self._log = evaluate, recorded, log
        self.queries = 0  # evaluated or answered from the journal

    def __call__(self, perturbations: Sequence[Perturbation]) -> list[float]:
        self.queries += len(perturbations)
        values: dict[int, float] = {}
        for perturbation in perturbations:
            record = self._recorded.get(perturbation.query_id)
            if record is None:
                continue
            same = record.algorithm == perturbation.algorithm and np.array_equal(
                np.asarray(record.delta, dtype=np.float64), perturbation.delta
            )
            if not same:
                raise JournalError(
                    f"query {perturbation.query_id}: the search proposed {perturbation.algorithm} "
                    f"{perturbation.delta.tolist()} but the journal holds {record.algorithm} {list(record.delta)}: "
                    "the search is not deterministic"
                )
            values[perturbation.query_id] = record.value
        missing = [p for p in perturbations if p.query_id not in values]
        if missing:
            values.update(zip((p.query_id for p in missing), self._evaluate(missing), strict=True))
        return [values[p.query_id] for p in perturbations]


def drive_search(
    algorithm: SearchAlgorithm[Any],
    evaluate: EvaluateBatch,
    scenario_id: str,
    actor_ids: tuple[str, ...],
    config: DriverConfig,
    recorded: Mapping[int, QueryRecord],
    stopped: Callable[[], bool],
    log: logging.Logger | None = None,
    lanes: int = 1,
) -> int:
    """Run the whole search (see the module docstring); returns early when ``stopped()``.

    ``evaluate`` gets one query at a time when ``lanes`` is 1, else whole batches. Returns how many
    queries the search made, those answered from the journal included.
    """
    if lanes < 1:
        raise ScenarioError(f"search lanes: must be at least 1, got {lanes}")
    run = _Recorded(evaluate, recorded, log or logging.getLogger(__name__))
    if config.score_original:
        run([Perturbation(ORIGINAL_QUERY, scenario_id, (), np.zeros(0), ORIGINAL)])
    query_id = ORIGINAL_QUERY + 1
    points: dict[int, FloatArray] = {}
    values: dict[int, float] = {}
    while not algorithm.done and not stopped():
        asked = algorithm.ask(1 if lanes == 1 else None)
        batch = [
            Perturbation(query_id + i, scenario_id, actor_ids, point, algorithm.name) for i, point in enumerate(asked)
        ]
        told = run(batch)
        algorithm.tell(asked, told)
        for perturbation, value in zip(batch, told, strict=True):
            points[perturbation.query_id], values[perturbation.query_id] = perturbation.delta, value
        query_id += len(batch)
    reruns = [best for best in reversed(ranked_queries(values, config.rerun_top)) for _ in range(config.reruns)]
    step = 1 if lanes == 1 else max(1, len(reruns))
    for start in range(0, len(reruns), step):  # the best last: its replay is recorded
        if stopped():
            return run.queries
        chunk = reruns[start : start + step]
        run([Perturbation(query_id + i, scenario_id, actor_ids, points[best], RERUN) for i, best in enumerate(chunk)])
        query_id += len(chunk)
    controls = [Perturbation(query_id + i, scenario_id, (), np.zeros(0), ORIGINAL) for i in range(config.reruns)]
    if config.identity_control and actor_ids:
        controls.append(Perturbation(query_id + len(controls), scenario_id, actor_ids, np.zeros(0), IDENTITY))
    step = 1 if lanes == 1 else max(1, len(controls))
    for start in range(0, len(controls), step):
        if stopped():
            return run.queries
        run(controls[start : start + step])
    return run.queries
