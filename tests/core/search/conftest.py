"""Small search configs shared by the search tests: quick enough for CI, big enough to exercise each algorithm."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import pytest

from advsim_ros.core.search import SearchConfig, default_config

ATTACK_DIMENSIONS = (12, 24)  # 12 per perturbed actor: one and two actors


def _small_config(name: str, max_queries: int) -> SearchConfig:
    """Algorithm `name` with budget `max_queries` and batches small enough to see several of them."""
    config = dataclasses.replace(default_config(name), max_queries=max_queries)
    if name == "bo":
        config = dataclasses.replace(config, initial_points=8, raw_samples=128)
    if name == "ga":
        config = dataclasses.replace(config, population=8)
    if name == "random":
        config = dataclasses.replace(config, batch_size=4)
    return config


@pytest.fixture(params=ATTACK_DIMENSIONS, ids=lambda dimension: f"D{dimension}")
def dimension(request: pytest.FixtureRequest) -> int:
    value: int = request.param
    return value


@pytest.fixture
def small_config() -> Callable[[str, int], SearchConfig]:
    """Factory: algorithm name and budget -> a small config of that algorithm."""
    return _small_config
