"""Uniform random sampling in the search box: the baseline every algorithm must beat."""

from __future__ import annotations

from dataclasses import dataclass

from advsim_ros.core.search.base import LOWER_BOUND, UPPER_BOUND, SearchAlgorithm, SearchConfig, require_config
from advsim_ros.core.types import FloatArray


@dataclass(frozen=True)
class RandomSearchConfig(SearchConfig):
    """Uniform sampling, `batch_size` points per batch."""

    max_queries: int = 75  # query budget [queries]
    batch_size: int = 16  # points proposed at a time; the points do not depend on it (one stream) [queries]

    def __post_init__(self) -> None:
        super().__post_init__()
        require_config(self.batch_size >= 1, type(self).__name__, "batch_size", "must be at least 1")


class RandomSearch(SearchAlgorithm[RandomSearchConfig]):
    """Independent uniform samples in [-1, 1]^D."""

    name = "random"

    def _propose(self) -> FloatArray:
        return self.rng.uniform(LOWER_BOUND, UPPER_BOUND, size=(self.config.batch_size, self.dimension))

    def _observe(self, points: FloatArray, values: FloatArray) -> None:
        del points, values  # uniform sampling ignores what it has seen
