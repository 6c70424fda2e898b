"""Bandit optimisation with a time-dependent prior (Ilyas, Engstrom and Madry, ICLR 2019).

A prior v (the running gradient estimate, in [-1, 1]^D) is refined each iteration with
two queries, x + probe * q / |q| for q = v +- exploration * u, u ~ N(0, I / D): their
difference estimates the directional derivative along u, and v takes an exponentiated
gradient step of size `prior_learning_rate` (the l-infinity variant of the paper). Each
difference is divided by the mean absolute difference of the pairs so far, so the step
does not depend on the objective's units (Ilyas et al.'s losses are cross-entropies of
order 1; on the test functions this scaling beat scaling by the spread of the values). The
iterate then moves x <- clip(x + lr * sign(v)). Ilyas et al. also tile the prior over
image pixels (the data-dependent prior, "TD"); a perturbation vector has no spatial
neighbourhood, so the tile size is 1 here. The search starts at the origin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from advsim_ros.core.search.base import SearchAlgorithm, SearchConfig, project_to_box, require_config
from advsim_ros.core.types import FloatArray


@dataclass(frozen=True)
class BanditConfig(SearchConfig):
    """Bandit-TD with the paper's prior lr 1.0, lr 0.25, probe 0.5, exploration 1.0."""

    max_queries: int = 200  # query budget: 100 iterations x 2 queries [queries]
    prior_learning_rate: float = 1.0  # exponentiated-gradient step of the prior [1]
    learning_rate: float = 0.25  # l-infinity step of the iterate, in box half-widths [1]
    probe: float = 0.5  # finite-difference radius [1]
    exploration: float = 1.0  # scale of the exploration noise added to the prior [1]

    def __post_init__(self) -> None:
        super().__post_init__()
        name = type(self).__name__
        for key in ("prior_learning_rate", "learning_rate", "probe", "exploration"):
            require_config(getattr(self, key) > 0.0, name, key, "must be positive")


def _normalised(vector: FloatArray) -> FloatArray:
    norm = float(np.linalg.norm(vector))
    return vector / norm if norm > 0.0 else vector


class BanditTd(SearchAlgorithm[BanditConfig]):
    """Gradient-prior bandit: two queries per iteration, projected sign steps."""

    name = "bandit"

    def __init__(self, config: BanditConfig, dimension: int, rng: np.random.Generator) -> None:
        super().__init__(config, dimension, rng)
        self._current: FloatArray = np.zeros(dimension)
        self._prior: FloatArray = np.zeros(dimension)
        self._noise: FloatArray = np.zeros(dimension)  # exploration * u of the pending pair
        self._differences: list[float] = []  # |f(plus) - f(minus)| of every pair so far

    def _propose(self) -> FloatArray:
        self._noise = self.config.exploration * self.rng.standard_normal(self.dimension) / np.sqrt(self.dimension)
        plus = self._current + self.config.probe * _normalised(self._prior + self._noise)
        minus = self._current + self.config.probe * _normalised(self._prior - self._noise)
        return project_to_box(np.stack([plus, minus]))

    def _observe(self, points: FloatArray, values: FloatArray) -> None:
        del points
        difference = float(values[0] - values[1])
        self._differences.append(abs(difference))
        typical = float(np.mean(self._differences))
        scale = typical if typical > 0.0 else 1.0
        derivative = difference / (scale * self.config.probe * self.config.exploration)
        gradient = derivative * self._noise
        # Exponentiated-gradient step keeps the prior in [-1, 1] (Ilyas et al.'s l-infinity prior update).
        as_probability = np.clip((self._prior + 1.0) / 2.0, 1e-6, 1.0 - 1e-6)  # never stuck at 0 or 1
        exponent = np.clip(self.config.prior_learning_rate * gradient, -50.0, 50.0)
        positive = as_probability * np.exp(exponent)
        negative = (1.0 - as_probability) * np.exp(-exponent)
        self._prior = 2.0 * positive / (positive + negative) - 1.0
        self._current = project_to_box(self._current + self.config.learning_rate * np.sign(self._prior))
