"""NES gradient estimation with projected sign-gradient steps (Ilyas et al., ICML 2018).

Each iteration probes ``samples`` points around the current iterate in antithetic pairs
x +- probe * u, u ~ N(0, I / D) (so |probe * u| is about `probe`), estimates the gradient
g = sum_i (f(x + probe u_i) - f(x - probe u_i)) u_i / (probe * samples), and steps
x <- clip(x + lr * sign(g)) (the l-infinity projected gradient step). Probes outside the
box are clipped into it. The search starts at the unperturbed scenario (the origin).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from advsim_ros.core.search.base import SearchAlgorithm, SearchConfig, project_to_box, require_config
from advsim_ros.core.types import FloatArray


@dataclass(frozen=True)
class NesConfig(SearchConfig):
    """NES with the paper's 10 samples, lr 0.25, probe 0.5, 20 iterations."""

    max_queries: int = 200  # query budget: 20 iterations x 10 samples [queries]
    samples: int = 10  # queries per gradient estimate, an even number (antithetic pairs) [queries]
    learning_rate: float = 0.25  # l-infinity step per iteration, in box half-widths [1]
    probe: float = 0.5  # finite-difference radius of the probes [1]

    def __post_init__(self) -> None:
        super().__post_init__()
        name = type(self).__name__
        require_config(self.samples >= 2 and self.samples % 2 == 0, name, "samples", "must be an even number >= 2")
        require_config(self.learning_rate > 0.0, name, "learning_rate", "must be positive")
        require_config(self.probe > 0.0, name, "probe", "must be positive")


class Nes(SearchAlgorithm[NesConfig]):
    """Natural evolution strategies gradient estimate + projected sign steps."""

    name = "nes"

    def __init__(self, config: NesConfig, dimension: int, rng: np.random.Generator) -> None:
        super().__init__(config, dimension, rng)
        self._current: FloatArray = np.zeros(dimension)
        self._directions: FloatArray = np.empty((0, dimension))  # u_i of the pending probes

    def _propose(self) -> FloatArray:
        pairs = self.config.samples // 2
        self._directions = self.rng.standard_normal((pairs, self.dimension)) / np.sqrt(self.dimension)
        offsets = self.config.probe * self._directions
        # Interleaved x + p u_i, x - p u_i so that a budget cut keeps whole pairs first.
        probes = np.stack([self._current + offsets, self._current - offsets], axis=1).reshape(-1, self.dimension)
        return project_to_box(probes)

    def _observe(self, points: FloatArray, values: FloatArray) -> None:
        del points
        plus, minus = values[0::2], values[1::2]
        gradient = ((plus - minus)[:, None] * self._directions).sum(axis=0) / (self.config.probe * self.config.samples)
        self._current = project_to_box(self._current + self.config.learning_rate * np.sign(gradient))
