"""SimBA (Guo et al., "Simple Black-box Adversarial Attacks", ICML 2019) in the Cartesian basis.

Starting from the unperturbed scenario (the origin), take the coordinates in a random
order; for each, try a step of +step along it and keep it if the value improves, else try
-step and keep that if it improves. Steps are clipped to the box; a step the box clips to
nothing is skipped without a query. One query at a time: each depends on the last.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from advsim_ros.core.search.base import SearchAlgorithm, SearchConfig, project_to_box, require_config
from advsim_ros.core.types import FloatArray


@dataclass(frozen=True)
class SimbaConfig(SearchConfig):
    """SimBA with the paper's step 0.25 and 100 coordinate iterations (at most 2 queries each, plus the start)."""

    max_queries: int = 201  # query budget: 1 + 2 x 100 iterations [queries]
    step: float = 0.25  # step along one coordinate, in units of the box half-width [1]

    def __post_init__(self) -> None:
        super().__post_init__()
        require_config(0.0 < self.step <= 2.0, type(self).__name__, "step", "must be in (0, 2]")


class Simba(SearchAlgorithm[SimbaConfig]):
    """Greedy coordinate search with random coordinate order."""

    name = "simba"

    def __init__(self, config: SimbaConfig, dimension: int, rng: np.random.Generator) -> None:
        super().__init__(config, dimension, rng)
        self._current: FloatArray = np.zeros(dimension)  # the accepted point
        self._current_value: float | None = None  # its value, None until the start is evaluated
        self._order: list[int] = []  # coordinates left in this pass
        self._coordinate = -1  # coordinate being tried
        self._sign = 0.0  # +1 or -1: direction being tried

    def _propose(self) -> FloatArray:
        if self._current_value is None:
            return self._current[None, :].copy()
        while True:
            if self._sign > 0.0:
                self._sign = -1.0  # the + step failed: try the - step on the same coordinate
            else:
                if not self._order:
                    self._order = [int(index) for index in self.rng.permutation(self.dimension)]
                self._coordinate = self._order.pop(0)
                self._sign = 1.0
            candidate = self._current.copy()
            candidate[self._coordinate] += self._sign * self.config.step
            candidate = project_to_box(candidate)
            if not np.array_equal(candidate, self._current):
                return candidate[None, :]

    def _observe(self, points: FloatArray, values: FloatArray) -> None:
        value = float(values[0])
        if self._current_value is None:
            self._current_value = value
        elif value > self._current_value:
            self._current = points[0].copy()
            self._current_value = value
            self._sign = 0.0  # accepted: the next proposal moves on to a new coordinate
