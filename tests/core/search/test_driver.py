"""Driving one attack's search over evaluation lanes: the same queries, ids and values whatever the lanes."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence

import numpy as np
import pytest

from advsim_ros.core.journal import QueryRecord
from advsim_ros.core.search import SearchConfig, make_search
from advsim_ros.core.search.bo import BayesianOptimization
from advsim_ros.core.search.bo_config import BoConfig
from advsim_ros.core.search.driver import DriverConfig, drive_search
from advsim_ros.core.types import Perturbation

SmallConfig = Callable[[str, int], SearchConfig]
DIMENSION = 12
ACTORS = ("car_1",)


def _objective(delta: np.ndarray) -> float:
    """A deterministic stand-in for a stack's L_adv (a query of the original scenario has no delta)."""
    return float(-np.sum((delta - 0.3) ** 2)) if delta.size else 0.0


def _drive(
    name: str,
    small_config: SmallConfig,
    lanes: int,
    recorded: dict[int, QueryRecord] | None = None,
) -> tuple[list[Perturbation], list[int], int]:
    """Run a whole search; returns every evaluated query in order, the size of each evaluated batch and how
    many queries the driver says the search made."""
    algorithm = make_search(name, DIMENSION, np.random.default_rng(5), small_config(name, 24))
    evaluated: list[Perturbation] = []
    batches: list[int] = []

    def evaluate(perturbations: Sequence[Perturbation]) -> list[float]:
        assert len(perturbations) == 1 or lanes > 1
        batches.append(len(perturbations))
        evaluated.extend(perturbations)
        return [_objective(p.delta) for p in perturbations]

    config = DriverConfig()
    made = drive_search(algorithm, evaluate, "window", ACTORS, config, recorded or {}, lambda: False, lanes=lanes)
    return evaluated, batches, made


def _key(perturbation: Perturbation) -> tuple[object, ...]:
    return perturbation.query_id, perturbation.algorithm, tuple(perturbation.delta.tolist())


@pytest.mark.parametrize("name", ["bo", "ga", "nes", "random", "simba", "bandit"])
def test_every_number_of_lanes_asks_the_same_queries_under_the_same_ids(name: str, small_config: SmallConfig) -> None:
    one, one_batches, _ = _drive(name, small_config, lanes=1)
    three, three_batches, _ = _drive(name, small_config, lanes=3)
    assert [_key(p) for p in one] == [_key(p) for p in three]
    assert set(one_batches) == {1}
    # the original alone, the search in the algorithm's whole batches, then the two re-runs together, then the
    # controls together: the original twice more and the identity control (the actors where they were logged)
    assert three_batches[0] == 1
    assert three_batches[-2:] == [2, 3]
    assert [p.query_id for p in three] == list(range(len(three)))
    assert [p.algorithm for p in three][-5:] == ["rerun", "rerun", "original", "original", "identity"]
    identity = three[-1]
    assert identity.actor_ids == three[-3 - 2].actor_ids
    assert identity.delta.size == 0
    if name in ("random", "ga", "nes", "bo"):  # batches of several points: the lanes are used
        assert max(three_batches) > 1


def test_a_resumed_search_evaluates_only_what_the_journal_lacks_even_inside_a_batch(small_config: SmallConfig) -> None:
    full, _, made = _drive("random", small_config, lanes=3)
    assert made == len(full)
    recorded = {
        p.query_id: QueryRecord(
            p.query_id, p.algorithm, p.actor_ids, tuple(p.delta.tolist()), {"status": "ok", "adversarial_loss": v}
        )
        for p in full[:3]  # the original and two queries: the first batch of four was cut after two
        for v in [_objective(p.delta)]
    }
    resumed, batches, made_resumed = _drive("random", small_config, lanes=3, recorded=recorded)
    assert [_key(p) for p in resumed] == [_key(p) for p in full[3:]]
    assert made_resumed == len(full)  # the three answered from the journal count: the attack's whole size
    assert batches[0] == 2  # the rest of the interrupted batch of four


def test_bo_with_a_batch_size_proposes_distinct_points_the_same_for_the_same_seed(small_config: SmallConfig) -> None:
    config = dataclasses.replace(small_config("bo", 16), batch_size=3)
    assert isinstance(config, BoConfig)

    def run() -> list[np.ndarray]:
        search = BayesianOptimization(config, DIMENSION, np.random.default_rng(2))
        batches = []
        while not search.done:
            points = search.ask()
            batches.append(points)
            search.tell(points, [_objective(point) for point in points])
        return batches

    first, second = run(), run()
    assert [b.shape[0] for b in first] == [8, 3, 3, 2]  # the initial design, then qUCB batches cut at the budget
    for a, b in zip(first, second, strict=True):
        np.testing.assert_array_equal(a, b)
    for batch in first[1:]:
        distances = np.linalg.norm(batch[:, None, :] - batch[None, :, :], axis=-1)
        assert np.all(distances[~np.eye(batch.shape[0], dtype=bool)] > 1e-3)  # pending points push the next away
    assert not math.isnan(_objective(first[-1][0]))
