"""The contract every registered search algorithm honours (parametrised over the registry).

A new algorithm added to the registry is picked up here without touching this file.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import pytest

from advsim_ros.core.search import ALGORITHM_NAMES, SearchConfig, SearchError, make_search, run_search
from advsim_ros.core.search.synthetic import make_test_function
from advsim_ros.core.types import FloatArray

SmallConfig = Callable[[str, int], SearchConfig]
BUDGET = 23  # odd on purpose: no algorithm's batch divides it


def _sphere(points: FloatArray) -> FloatArray:
    """Values to maximise with the optimum at 0.3 in every coordinate."""
    return -np.sum((points - 0.3) ** 2, axis=1)


def _run(
    config: SearchConfig, name: str, dimension: int, seed: int, max_points: int | None
) -> tuple[FloatArray, FloatArray]:
    search = make_search(name, dimension, np.random.default_rng(seed), config)
    run_search(search, _sphere, max_points=max_points)
    return search.history_points, search.history_values


@pytest.mark.parametrize("name", ALGORITHM_NAMES)
def test_every_query_lies_in_the_unit_linf_ball(name: str, dimension: int, small_config: SmallConfig) -> None:
    function = make_test_function("rastrigin", dimension, np.random.default_rng(5))
    search = make_search(name, dimension, np.random.default_rng(1), small_config(name, BUDGET))
    run_search(search, function)
    points = search.history_points
    assert points.shape == (BUDGET, dimension)
    assert np.all(np.abs(points) <= 1.0)


@pytest.mark.parametrize("name", ALGORITHM_NAMES)
@pytest.mark.parametrize("max_points", [None, 1, 3])
def test_the_search_stops_exactly_at_its_query_budget(
    name: str, max_points: int | None, small_config: SmallConfig
) -> None:
    search = make_search(name, 12, np.random.default_rng(2), small_config(name, BUDGET))
    asked = 0
    while not search.done:
        points = search.ask(max_points)
        assert 1 <= points.shape[0] <= (max_points or BUDGET)
        asked += points.shape[0]
        search.tell(points, _sphere(points))
    assert asked == BUDGET
    assert search.num_queries == BUDGET
    assert search.remaining == 0
    with pytest.raises(SearchError, match="search is over"):
        search.ask()


@pytest.mark.parametrize("name", ALGORITHM_NAMES)
def test_the_same_seed_gives_the_same_queries_however_they_are_batched(
    name: str, dimension: int, small_config: SmallConfig
) -> None:
    points_batched, values_batched = _run(small_config(name, BUDGET), name, dimension, seed=7, max_points=None)
    points_single, values_single = _run(small_config(name, BUDGET), name, dimension, seed=7, max_points=1)
    np.testing.assert_array_equal(points_batched, points_single)
    np.testing.assert_array_equal(values_batched, values_single)
    points_other, _ = _run(small_config(name, BUDGET), name, dimension, seed=8, max_points=None)
    assert not np.array_equal(points_batched, points_other)


@pytest.mark.parametrize("name", ALGORITHM_NAMES)
def test_best_so_far_is_the_largest_value_told_and_its_point(name: str, small_config: SmallConfig) -> None:
    search = make_search(name, 12, np.random.default_rng(3), small_config(name, BUDGET))
    running_best = -np.inf
    while not search.done:
        points = search.ask(2)
        values = _sphere(points)
        search.tell(points, values)
        running_best = max(running_best, float(values.max()))
        best = search.best
        assert best is not None
        assert best.value == running_best
        np.testing.assert_array_equal(search.history_points[best.query_index], best.point)
        assert search.history_values[best.query_index] == best.value


@pytest.mark.parametrize("name", ALGORITHM_NAMES)
def test_failed_queries_never_become_the_best_and_the_search_goes_on(name: str, small_config: SmallConfig) -> None:
    search = make_search(name, 12, np.random.default_rng(4), small_config(name, BUDGET))
    told = 0
    while not search.done:
        points = search.ask(1)
        failed = told % 3 == 1  # every third query "times out"
        search.tell(points, np.array([np.nan]) if failed else _sphere(points))
        told += 1
    values = search.history_values
    assert told == BUDGET
    assert np.isnan(values[1::3]).all()
    best = search.best
    assert best is not None
    assert best.value == np.nanmax(values)


@pytest.mark.parametrize("name", ALGORITHM_NAMES)
def test_tell_rejects_points_that_were_not_asked(name: str, small_config: SmallConfig) -> None:
    search = make_search(name, 12, np.random.default_rng(0), small_config(name, BUDGET))
    with pytest.raises(SearchError, match="without a preceding ask"):
        search.tell(np.zeros((1, 12)), [0.0])
    points = search.ask(1)
    with pytest.raises(SearchError, match="ask called again before tell"):
        search.ask(1)
    with pytest.raises(SearchError, match="exactly the points"):
        search.tell(points + 0.01, [0.0])
    with pytest.raises(SearchError, match="finite"):
        search.tell(points, [np.inf])
    search.tell(points, [0.0])
    assert search.num_queries == 1


@pytest.mark.parametrize("name", ALGORITHM_NAMES)
def test_configs_reject_a_zero_budget_naming_the_key(name: str, small_config: SmallConfig) -> None:
    config = small_config(name, BUDGET)
    with pytest.raises(SearchError, match=r"max_queries: must be at least 1"):
        dataclasses.replace(config, max_queries=0)


def test_an_unknown_algorithm_name_lists_the_known_ones() -> None:
    with pytest.raises(
        SearchError, match=r"unknown search algorithm 'cmaes' \(known: bo, ga, simba, nes, bandit, random\)"
    ):
        make_search("cmaes", 12, np.random.default_rng(0))


@pytest.mark.parametrize("name", ALGORITHM_NAMES)
def test_a_flat_objective_runs_to_the_budget_without_errors(name: str, small_config: SmallConfig) -> None:
    search = make_search(name, 12, np.random.default_rng(6), small_config(name, BUDGET))
    best = run_search(search, lambda points: np.zeros(points.shape[0]))
    assert search.num_queries == BUDGET
    assert best is not None
    assert best.value == 0.0
    assert np.all(np.abs(search.history_points) <= 1.0)
