"""The feasible set of one actor: a cloud of sampled deltas (the zero delta first) that survive the pruning.

Their 6-s rollouts respect the kinematic bounds, keep their centre on the drivable area and
overlap neither the SDV's logged trajectory nor any other actor's logged box at any step.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from advsim_ros.core.drivable import DrivableConfig, drivable_area_for
from advsim_ros.core.feasibility.config import PerturberConfig
from advsim_ros.core.feasibility.obstacles import WindowObstacles, window_obstacles
from advsim_ros.core.feasibility.projection_index import ProjectionIndex
from advsim_ros.core.feasibility.pruning import KINEMATIC_CHECKS, Pruner, PruningCounts
from advsim_ros.core.feasibility.reference import ActorReference, fit_reference
from advsim_ros.core.feasibility.rollout import PerturbedTrajectory, perturbation_to_trajectory
from advsim_ros.core.feasibility.window import Window
from advsim_ros.core.types import DrivableArea, Scenario

Float32Array = npt.NDArray[np.float32]

COLLISION_BATCH = 16_384  # candidates whose collisions are tested at once


@dataclass(frozen=True, eq=False)
class FeasibleSet:
    """The surviving candidates of one actor: their deltas and positions, with pruning statistics."""

    reference: ActorReference
    config: PerturberConfig
    deltas: Float32Array  # (S, D) normalised perturbations; row 0 is the zero delta when it survived
    positions: Float32Array  # (S, 2T) x0, y0, x1, y1, ... relative to reference.origin [m]
    counts: PruningCounts

    @functools.cached_property
    def index(self) -> ProjectionIndex:
        """Built on the first projection, so that sets that are never projected cost nothing more."""
        return ProjectionIndex.build(self.positions, self.config.projection_components)

    @property
    def actor_id(self) -> str:
        return self.reference.actor_id

    @property
    def size(self) -> int:
        return int(self.deltas.shape[0])

    def trajectory(self, candidate: int) -> PerturbedTrajectory:
        """The candidate's trajectory, recomputed in float64 from its delta."""
        return perturbation_to_trajectory(self.reference, self.deltas[candidate].astype(np.float64), self.config)


def build_feasible_set(
    scenario: Scenario,
    window: Window,
    actor_id: str,
    config: PerturberConfig,
    rng: np.random.Generator,
    *,
    drivable: DrivableArea | None = None,
    obstacles: WindowObstacles | None = None,
) -> FeasibleSet:
    """Sample config.num_candidates deltas for one actor and keep the physically plausible ones.

    ``drivable`` and ``obstacles`` default to drivable_area_for(scenario) and
    window_obstacles(scenario, window); pass them in to share them between actors.
    Raises InfeasibleError if the actor cannot be fitted (not labelled at the window start).
    """
    reference = fit_reference(scenario, window, actor_id, config)
    if drivable is None:
        drivable = drivable_area_for(scenario, DrivableConfig())  # a stored area (the nodes') wins
    if obstacles is None:
        obstacles = window_obstacles(scenario, window, config)
    pruner = Pruner(reference, config, drivable, obstacles)
    dim, steps = config.perturbation_dim, reference.num_steps
    tally = {"kinematic": 0, "drivable": 0, "ego": 0, "actors": 0}
    removed = dict.fromkeys(KINEMATIC_CHECKS, 0)
    kept_deltas: list[Float32Array] = []
    kept_positions: list[Float32Array] = []
    # Bounds and drivable area run on cache-sized chunks; the collision tests, whose cost is
    # mostly per call, on batches of at least COLLISION_BATCH survivors.
    pending: list[tuple[Float32Array, Float32Array, Float32Array, Float32Array]] = []
    pending_count = 0
    for start in range(0, config.num_candidates, config.chunk_size):
        count = min(config.chunk_size, config.num_candidates - start)
        deltas = rng.random((count, dim), dtype=np.float32) * np.float32(2.0) - np.float32(1.0)
        if start == 0:
            deltas[0] = 0.0  # the logged behaviour is always a candidate
        pending.append(pruner.on_road(deltas, tally, removed))
        pending_count += pending[-1][0].shape[0]
        if pending_count >= COLLISION_BATCH or start + count >= config.num_candidates:
            batch_deltas = np.concatenate([part[0] for part in pending])
            x, y, yaw = (np.concatenate([part[i] for part in pending], axis=1) for i in (1, 2, 3))
            survivors, positions = pruner.collision_free(batch_deltas, x, y, yaw, tally)
            kept_deltas.append(survivors)
            kept_positions.append(positions)
            pending, pending_count = [], 0
    counts = PruningCounts(
        sampled=config.num_candidates,
        kinematic=tally["kinematic"],
        drivable=tally["drivable"],
        ego=tally["ego"],
        actors=tally["actors"],
        violations=removed,
    )
    all_deltas = np.concatenate(kept_deltas) if kept_deltas else np.zeros((0, dim), dtype=np.float32)
    positions = np.concatenate(kept_positions) if kept_positions else np.zeros((0, 2 * steps), dtype=np.float32)
    return FeasibleSet(reference, config, all_deltas, positions, counts)
