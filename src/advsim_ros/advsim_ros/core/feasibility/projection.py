"""Projection of a proposed delta onto the feasible sets.

Each actor's block is replaced by the feasible candidate whose positions are L2-nearest to its
rollout over the whole horizon; with several actors the jointly nearest candidates that do not
collide with each other are returned.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from advsim_ros.core.feasibility.errors import InfeasibleError
from advsim_ros.core.feasibility.feasible_set import FeasibleSet
from advsim_ros.core.feasibility.rollout import PerturbedTrajectory, RolloutBatch, perturbation_to_trajectory
from advsim_ros.core.geometry import boxes_overlap
from advsim_ros.core.types import FloatArray, IntArray, ScenarioError

MAX_JOINT_CHECKED = 20_000  # candidates a joint projection checks before it returns its best so far


class _Ranking:
    """One actor's feasible candidates in ascending L2 distance to a query, fetched in growing prefixes."""

    def __init__(self, feasible: FeasibleSet, query: PerturbedTrajectory) -> None:
        self.feasible = feasible
        origin = feasible.reference.origin
        self.query = np.column_stack([query.x - origin[0], query.y - origin[1]]).reshape(-1)
        self.indices = np.zeros(0, dtype=np.int64)
        self.distances = np.zeros(0)
        self.fetch(feasible.config.projection_candidates)

    def fetch(self, count: int) -> None:
        """Make sure the `count` nearest candidates are ranked (fewer if the set is smaller)."""
        count = min(count, self.feasible.size)
        if count > self.indices.size:
            self.indices, self.distances = self.feasible.index.nearest(self.feasible.positions, self.query, count)

    def block(self, start: int, length: int) -> tuple[IntArray, FloatArray]:
        """Candidate indices and distances of ranks start .. start + length - 1 (fewer at the end)."""
        if start + length > self.indices.size:
            self.fetch(max(4 * self.indices.size, start + length))
        return self.indices[start : start + length], self.distances[start : start + length]


class _BudgetSpentError(Exception):
    """The joint projection checked its maximum number of candidates."""


def _joint_nearest(rankings: Sequence[_Ranking], max_checked: int) -> tuple[PerturbedTrajectory, ...]:
    """Branch and bound for the candidates minimising the summed squared distances, pairwise collision-free.

    Actor by actor, candidates are visited in ascending distance and checked, in blocks that grow
    fourfold, against the ones already chosen; a branch stops as soon as its cost bound reaches
    the best full solution found so far. The search starts from the logged behaviours (the zero
    deltas) when they are feasible together, and after max_checked candidates it returns the
    best solution found, so a query never takes long.
    """
    count = len(rankings)
    floors = [float(ranking.distances[0] ** 2) for ranking in rankings]
    best_cost, best = _logged_combination(rankings)
    checked = 0
    first_block = max(1, rankings[0].feasible.config.projection_candidates)

    def search(level: int, chosen: list[PerturbedTrajectory], chosen_boxes: list[FloatArray], cost: float) -> None:
        nonlocal best_cost, best, checked
        ranking = rankings[level]
        floor = sum(floors[level + 1 :])
        start, size = 0, first_block
        while start < ranking.feasible.size:
            indices, distances = ranking.block(start, size)
            squared = distances**2
            viable = int(np.count_nonzero(cost + squared + floor < best_cost))
            if viable == 0:
                return  # ranks are ascending: nothing further can beat the best
            if checked + viable > max_checked:
                raise _BudgetSpentError
            checked += viable
            feasible = ranking.feasible
            deltas = feasible.deltas[indices[:viable]].astype(np.float64)
            batch = RolloutBatch(feasible.reference, deltas, feasible.config)
            boxes = batch.boxes()  # (T, n, 5)
            clear = np.ones(viable, dtype=bool)
            for other in chosen_boxes:
                clear &= ~np.any(boxes_overlap(boxes, other[:, None, :]), axis=0)
            for column in np.nonzero(clear)[0]:
                total = cost + float(squared[column])
                if total + floor >= best_cost:
                    return
                trajectory = batch.trajectory(int(column))
                if level == count - 1:
                    best_cost, best = total, [*chosen, trajectory]
                    return  # later candidates of the last actor are farther
                search(level + 1, [*chosen, trajectory], [*chosen_boxes, boxes[:, column]], total)
            if viable < indices.size:
                return
            start, size = start + size, 4 * size

    with contextlib.suppress(_BudgetSpentError):
        search(0, [], [], 0.0)
    if not best:
        raise InfeasibleError(
            f"no collision-free combination of feasible candidates of actors {[r.feasible.actor_id for r in rankings]}"
            f" found within {max_checked} checked candidates"
        )
    return tuple(best)


def _logged_combination(rankings: Sequence[_Ranking]) -> tuple[float, list[PerturbedTrajectory]]:
    """The zero-delta candidates of every actor and their summed squared distance, if all are feasible together."""
    chosen: list[PerturbedTrajectory] = []
    cost = 0.0
    for ranking in rankings:
        feasible = ranking.feasible
        if feasible.size == 0 or np.any(feasible.deltas[0] != 0):
            return math.inf, []
        trajectory = feasible.trajectory(0)
        if any(np.any(boxes_overlap(trajectory.boxes(), other.boxes())) for other in chosen):
            return math.inf, []
        chosen.append(trajectory)
        cost += float(np.sum((feasible.positions[0].astype(np.float64) - ranking.query) ** 2))
    return cost, chosen


def project(sets: Sequence[FeasibleSet], delta: npt.ArrayLike) -> tuple[PerturbedTrajectory, ...]:
    """Project a concatenated delta (m D,) onto the feasible sets: one trajectory per actor, in order.

    Each block is rolled out and replaced by the feasible candidate whose positions over the
    horizon are L2-nearest; with several actors the sum of squared distances is minimised over
    combinations whose trajectories do not overlap each other. Deterministic: ties go to the
    lower candidate index.
    """
    if not sets:
        raise ScenarioError("project: no feasible sets given")
    config = sets[0].config
    values = np.asarray(delta, dtype=np.float64)
    dim = config.perturbation_dim
    if values.shape != (dim * len(sets),):
        raise ScenarioError(
            f"project: expected delta of {dim * len(sets)} entries for {len(sets)} actors, got {values.shape}"
        )
    empty = [feasible.actor_id for feasible in sets if feasible.size == 0]
    if empty:
        raise InfeasibleError(f"project: actors {empty} have no feasible candidates")
    rankings = [
        _Ranking(feasible, perturbation_to_trajectory(feasible.reference, values[i * dim : (i + 1) * dim], config))
        for i, feasible in enumerate(sets)
    ]
    return _joint_nearest(rankings, MAX_JOINT_CHECKED)
