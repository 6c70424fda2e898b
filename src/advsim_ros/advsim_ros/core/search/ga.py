"""Genetic algorithm with GenAttack's adaptive mutation (Alzantot et al., GECCO 2019).

Generation 0 is `population` uniform points. Each later generation keeps the elite (the
best member so far, not queried again) and breeds `population - 1` children: two parents
drawn with probabilities softmax(standardised fitness / temperature), a uniform crossover
that takes each coordinate from a parent with probability proportional to its selection
probability, and a mutation that adds U(-alpha, alpha) to each coordinate with probability
rho; children are clipped into the box. A generation whose best does not beat the elite
is a plateau; with n plateaus so far rho = max(rho_min, rho_0 decay^n) and
alpha = max(alpha_min, alpha_0 decay^n), and the search stops after `max_plateaus`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from advsim_ros.core.search.base import (
    LOWER_BOUND,
    UPPER_BOUND,
    SearchAlgorithm,
    SearchConfig,
    project_to_box,
    require_config,
)
from advsim_ros.core.types import FloatArray


@dataclass(frozen=True)
class GaConfig(SearchConfig):
    """GenAttack-style GA with the paper's population 32, 50 generations, 25 plateaus, rho 0.5 -> 0.1, decay 0.9."""

    max_queries: int = 1551  # query budget: 32 + 49 generations x 31 children [queries]
    population: int = 32  # members per generation [1]
    max_plateaus: int = 25  # generations without improvement before the search stops [1]
    mutation_probability: float = 0.5  # rho_0: chance that a coordinate mutates [1]
    min_mutation_probability: float = 0.1  # rho_min [1]
    mutation_range: float = 0.4  # alpha_0: mutation amplitude, in box half-widths (GenAttack's 0.4) [1]
    min_mutation_range: float = 0.15  # alpha_min (GenAttack's 0.15) [1]
    decay: float = 0.9  # factor per plateau applied to rho and alpha [1]
    temperature: float = 0.5  # softmax temperature on standardised fitness [1]

    def __post_init__(self) -> None:
        super().__post_init__()
        name = type(self).__name__
        require_config(self.population >= 2, name, "population", "must be at least 2")
        require_config(self.max_plateaus >= 1, name, "max_plateaus", "must be at least 1")
        require_config(0.0 < self.mutation_probability <= 1.0, name, "mutation_probability", "must be in (0, 1]")
        require_config(
            0.0 < self.min_mutation_probability <= self.mutation_probability,
            name,
            "min_mutation_probability",
            "must be in (0, mutation_probability]",
        )
        require_config(0.0 < self.mutation_range <= 2.0, name, "mutation_range", "must be in (0, 2]")
        require_config(
            0.0 < self.min_mutation_range <= self.mutation_range,
            name,
            "min_mutation_range",
            "must be in (0, mutation_range]",
        )
        require_config(0.0 < self.decay <= 1.0, name, "decay", "must be in (0, 1]")
        require_config(self.temperature > 0.0, name, "temperature", "must be positive")


class GeneticAlgorithm(SearchAlgorithm[GaConfig]):
    """Elitist GA: one generation is one batch."""

    name = "ga"

    def __init__(self, config: GaConfig, dimension: int, rng: np.random.Generator) -> None:
        super().__init__(config, dimension, rng)
        self._members: FloatArray = np.empty((0, dimension))  # the last evaluated generation, elite included
        self._fitness: FloatArray = np.empty(0)
        self._plateaus = 0

    def _propose(self) -> FloatArray:
        if self._fitness.size == 0:
            return self.rng.uniform(LOWER_BOUND, UPPER_BOUND, size=(self.config.population, self.dimension))
        return self._children(self.config.population - 1)

    def _children(self, count: int) -> FloatArray:
        config = self.config
        spread = float(np.std(self._fitness))
        standardised = (self._fitness - self._fitness.mean()) / (spread if spread > 0.0 else 1.0)
        logits = standardised / config.temperature
        probabilities = np.exp(logits - logits.max())
        probabilities /= probabilities.sum()
        parents = self.rng.choice(self._fitness.size, size=(count, 2), p=probabilities)
        first, second = probabilities[parents[:, 0]], probabilities[parents[:, 1]]
        take_first = self.rng.random((count, self.dimension)) < (first / (first + second))[:, None]
        children = np.where(take_first, self._members[parents[:, 0]], self._members[parents[:, 1]])
        rho = max(config.min_mutation_probability, config.mutation_probability * config.decay**self._plateaus)
        alpha = max(config.min_mutation_range, config.mutation_range * config.decay**self._plateaus)
        mutate = self.rng.random((count, self.dimension)) < rho
        noise = self.rng.uniform(-alpha, alpha, size=(count, self.dimension))
        return project_to_box(children + mutate * noise)

    def _observe(self, points: FloatArray, values: FloatArray) -> None:
        if self._fitness.size == 0:
            self._members, self._fitness = points, values
            return
        elite = int(np.argmax(self._fitness))
        if values.max() <= self._fitness[elite]:
            self._plateaus += 1
            if self._plateaus >= self.config.max_plateaus:
                self._stop()
        self._members = np.concatenate([self._members[elite : elite + 1], points])
        self._fitness = np.concatenate([self._fitness[elite : elite + 1], values])
