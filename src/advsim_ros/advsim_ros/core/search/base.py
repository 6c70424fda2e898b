"""The ask/tell interface every black-box search algorithm implements.

The search space is the l-infinity ball of radius 1 around the unperturbed scenario:
points are vectors in [-1, 1]^D (D = 12 per perturbed actor). Values are MAXIMISED (the
adversarial objective: higher is more safety-critical). A query that failed (the stack
never answered) is told as NaN: it never becomes the best, and the algorithm sees it as
the worst finite value observed so far, so a failure never attracts the search.

Protocol: ``ask(max_points)`` hands out up to ``max_points`` points of the algorithm's
current batch (its whole batch when None); ``tell(points, values)`` must follow with
exactly those points before the next ask. Asking one point at a time or a batch at a
time gives the same sequence of queries, so results do not depend on how the caller
parallelises. The budget ``max_queries`` is never exceeded: the last batch is cut short.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar, Generic, TypeVar

import numpy as np
import numpy.typing as npt

from advsim_ros.core.types import FloatArray, ScenarioError

LOWER_BOUND = -1.0  # every coordinate of a query lies in [LOWER_BOUND, UPPER_BOUND] (eps = 1)
UPPER_BOUND = 1.0


class SearchError(ScenarioError):
    """A search configuration or an ask/tell call that is not valid; the message names the problem."""


def require_config(condition: bool, config_name: str, key: str, message: str) -> None:
    """Raise SearchError naming the config's bad key unless `condition` holds."""
    if not condition:
        raise SearchError(f"{config_name}.{key}: {message}")


@dataclass(frozen=True)
class SearchConfig:
    """Settings every algorithm has; each algorithm's config extends it."""

    max_queries: int = 75  # query budget: the search never asks for more points [queries]

    def __post_init__(self) -> None:
        require_config(self.max_queries >= 1, type(self).__name__, "max_queries", "must be at least 1")

    def notes(self) -> tuple[str, ...]:
        """What a user should know before running with these settings (valid, but maybe not what was meant)."""
        return ()


@dataclass(frozen=True, eq=False)
class BestPoint:
    """The best query so far."""

    point: FloatArray  # (D,) perturbation in [-1, 1]
    value: float  # its objective value (maximised)
    query_index: int  # 0-based index of the query in the order they were asked


def project_to_box(points: npt.ArrayLike) -> FloatArray:
    """Points clipped into the search box [-1, 1]^D (the l-infinity projection)."""
    return np.clip(np.asarray(points, dtype=np.float64), LOWER_BOUND, UPPER_BOUND)


ConfigT = TypeVar("ConfigT", bound=SearchConfig)


class SearchAlgorithm(ABC, Generic[ConfigT]):
    """Base of every algorithm: budget, batching, failed queries and the best so far.

    Subclasses implement ``_propose`` (the next batch, inside the box) and ``_observe``
    (the values of a complete batch). They draw every random number from ``self.rng``.
    """

    name: ClassVar[str]  # the registry name ("bo", "ga", "simba", "nes", "bandit", "random")

    def __init__(self, config: ConfigT, dimension: int, rng: np.random.Generator) -> None:
        if dimension < 1:
            raise SearchError(f"{self.name}: dimension must be at least 1, got {dimension}")
        self.config: ConfigT = config
        self.dimension = dimension
        self.rng = rng
        self._points: list[FloatArray] = []  # every told query, in order
        self._values: list[float] = []  # their values (NaN for failed queries)
        self._best: BestPoint | None = None
        self._batch: FloatArray = np.empty((0, dimension))  # the current batch from _propose
        self._batch_values: list[float] = []  # values of the current batch told so far
        self._pending: FloatArray | None = None  # points handed out by ask, awaiting tell
        self._finished = False  # set by a subclass that stops before the budget

    # ----------------------------------------------------------------------------- algorithm hooks

    @abstractmethod
    def _propose(self) -> FloatArray:
        """The next batch (k >= 1, D) of points in [-1, 1]^D."""

    @abstractmethod
    def _observe(self, points: FloatArray, values: FloatArray) -> None:
        """Values (k,) of the whole batch last proposed; failed queries already replaced."""

    def _stop(self) -> None:
        """Called by a subclass whose own stopping rule ended the search before the budget."""
        self._finished = True

    # ----------------------------------------------------------------------------- public interface

    @property
    def num_queries(self) -> int:
        """Queries told so far."""
        return len(self._values)

    @property
    def remaining(self) -> int:
        """Queries left in the budget (handed out but untold ones count as used)."""
        pending = 0 if self._pending is None else self._pending.shape[0]
        return self.config.max_queries - self.num_queries - pending

    @property
    def done(self) -> bool:
        """True once the budget is spent or the algorithm stopped on its own rule."""
        return self._pending is None and (self.remaining <= 0 or self._finished)

    @property
    def best(self) -> BestPoint | None:
        """The best successful query so far, None before the first one."""
        return self._best

    @property
    def history_points(self) -> FloatArray:
        """(Q, D) every told query, in order."""
        return np.array(self._points).reshape(-1, self.dimension)

    @property
    def history_values(self) -> FloatArray:
        """(Q,) their values, NaN for failed queries."""
        return np.array(self._values, dtype=np.float64)

    def ask(self, max_points: int | None = None) -> FloatArray:
        """The next (k, D) points to evaluate, 1 <= k <= max_points (the whole batch when None)."""
        if self._pending is not None:
            raise SearchError(f"{self.name}: ask called again before tell for the {len(self._pending)} pending points")
        if self.done:
            raise SearchError(
                f"{self.name}: the search is over ({self.num_queries} queries of {self.config.max_queries})"
            )
        if max_points is not None and max_points < 1:
            raise SearchError(f"{self.name}: max_points must be at least 1, got {max_points}")
        if len(self._batch_values) == self._batch.shape[0]:
            self._start_batch()
        start = len(self._batch_values)
        count = self._batch.shape[0] - start
        if max_points is not None:
            count = min(count, max_points)
        self._pending = self._batch[start : start + count].copy()
        return self._pending.copy()

    def tell(self, points: npt.ArrayLike, values: npt.ArrayLike) -> None:
        """Report the values (k,) of the points (k, D) the last ask returned; NaN marks a failed query."""
        if self._pending is None:
            raise SearchError(f"{self.name}: tell called without a preceding ask")
        told_points = np.asarray(points, dtype=np.float64)
        told_values = np.asarray(values, dtype=np.float64).reshape(-1)
        if told_points.shape != self._pending.shape or not np.array_equal(told_points, self._pending):
            raise SearchError(f"{self.name}: tell must report exactly the points of the last ask, in order")
        if told_values.shape[0] != told_points.shape[0]:
            raise SearchError(
                f"{self.name}: got {told_values.shape[0]} values for {told_points.shape[0]} points",
            )
        if np.any(np.isinf(told_values)):
            raise SearchError(f"{self.name}: values must be finite, or NaN for a failed query")
        self._pending = None
        for point, value in zip(told_points, told_values, strict=True):
            self._record(point, float(value))
        self._batch_values.extend(float(value) for value in told_values)
        batch_complete = len(self._batch_values) == self._batch.shape[0]
        if batch_complete and self.remaining > 0:
            self._observe(self._batch.copy(), self._without_failures(np.array(self._batch_values)))

    # ----------------------------------------------------------------------------- internals

    def _start_batch(self) -> None:
        batch = np.asarray(self._propose(), dtype=np.float64)
        if batch.ndim != 2 or batch.shape[0] < 1 or batch.shape[1] != self.dimension:
            raise RuntimeError(
                f"{self.name}: proposed a batch of shape {batch.shape}, expected (k >= 1, {self.dimension})"
            )
        if not np.all(np.isfinite(batch)) or np.any(batch < LOWER_BOUND) or np.any(batch > UPPER_BOUND):
            raise RuntimeError(f"{self.name}: proposed points outside the search box [-1, 1]^{self.dimension}")
        self._batch = batch[: self.remaining]
        self._batch_values = []

    def _record(self, point: FloatArray, value: float) -> None:
        index = len(self._values)
        self._points.append(point.copy())
        self._values.append(value)
        if np.isfinite(value) and (self._best is None or value > self._best.value):
            self._best = BestPoint(point=point.copy(), value=value, query_index=index)

    def _without_failures(self, values: FloatArray) -> FloatArray:
        """Failed (NaN) values replaced by the worst finite value seen so far (0 when there is none)."""
        failed = np.isnan(values)
        if not np.any(failed):
            return values
        history = self.history_values
        finite = history[np.isfinite(history)]
        worst = float(finite.min()) if finite.size else 0.0
        return np.where(failed, worst, values)


def run_search(
    algorithm: SearchAlgorithm[Any],
    objective: Callable[[FloatArray], FloatArray],
    max_points: int | None = None,
) -> BestPoint | None:
    """Ask and tell until the search is over; `objective` maps (k, D) points to (k,) values."""
    while not algorithm.done:
        points = algorithm.ask(max_points)
        algorithm.tell(points, objective(points))
    return algorithm.best
