"""Perturbation, feasibility and projection settings (params/perturber.yaml, node /perturber).

Also the layout of one actor's delta block: dx0, dy0, dheading0, dv0, then K acceleration and
K curvature-rate knots (see core.feasibility.rollout).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from advsim_ros.core.dynamics import KinematicBounds
from advsim_ros.core.params import config_from_mapping, load_node_params
from advsim_ros.core.types import ActorClass, ScenarioError

STATE_OFFSETS = 4  # dx0, dy0, dheading0, dv0


@dataclass(frozen=True)
class PerturberConfig:
    """Perturbation, feasibility and projection settings (params/perturber.yaml, node /perturber)."""

    seed: int = 0  # random seed of the candidate sampling (the perturber node's generator)
    horizon_steps: int = 60  # states per trajectory: 6 s at 10 Hz
    frame_period: float = 0.1  # expected spacing of the log's frames [s]
    num_knots: int = 4  # control knots per control over the horizon
    num_candidates: int = 200_000  # sampled deltas per actor (the zero delta included)
    min_feasible: int = 100  # an actor is perturbed only if at least this many candidates survive
    num_actors: int = 1  # m: actors perturbed at once
    perturbable_classes: tuple[str, ...] = ("vehicle",)  # ActorClass values the search may move
    min_observed_steps: int = 10  # a perturbed actor is labelled in at least this many window frames
    max_position_offset: float = 5.0  # |dx0|, |dy0| along / across the initial heading [m]
    max_heading_offset: float = math.pi / 4  # |dheading0| [rad]
    max_speed_offset: float = 5.0  # |dv0| [m/s]
    max_accel_offset: float = 2.0  # |acceleration offset| at a knot [m/s^2]
    max_curvature_rate_offset: float = 0.05  # |curvature-rate offset| at a knot [1/(m s)]
    max_curvature: float = 0.2  # [1/m]
    max_curvature_rate: float = 0.05  # [1/(m s)]
    max_accel: float = 2.0  # [m/s^2]
    max_lateral_accel: float = 3.0  # [m/s^2]
    max_speed: float = 15.0  # [m/s]
    collision_margin: float = 0.05  # perturbed boxes are grown by this on every side when pruning [m]
    drivable_margin: float = 0.0  # the actor's centre stays this far inside the drivable area [m]
    chunk_size: int = 4096  # candidates pruned at once: small enough for the CPU caches
    cull_cell: float = 1.0  # cell of the coarse collision raster [m]
    bound_slack: float = 1e-4  # relative tightening of the bounds while pruning in float32
    projection_components: int = 24  # principal components of the projection's lower bounds
    projection_candidates: int = 16  # nearest candidates per actor considered first in joint projection

    def __post_init__(self) -> None:
        positive_ints = ("horizon_steps", "num_candidates", "min_feasible", "num_actors", "chunk_size")
        for name in (*positive_ints, "projection_components", "projection_candidates"):
            if getattr(self, name) < 1:
                raise ScenarioError(f"PerturberConfig {name}: must be >= 1, got {getattr(self, name)}")
        if not 2 <= self.num_knots <= self.horizon_steps:
            raise ScenarioError(f"PerturberConfig num_knots: must be in [2, horizon_steps], got {self.num_knots}")
        if self.horizon_steps < 2:
            raise ScenarioError(f"PerturberConfig horizon_steps: must be >= 2, got {self.horizon_steps}")
        if not 1 <= self.min_observed_steps <= self.horizon_steps:
            raise ScenarioError(
                f"PerturberConfig min_observed_steps: must be in [1, horizon_steps], got {self.min_observed_steps}"
            )
        positive = (
            "frame_period",
            "max_position_offset",
            "max_heading_offset",
            "max_speed_offset",
            "max_accel_offset",
            "max_curvature_rate_offset",
            "cull_cell",
        )
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ScenarioError(f"PerturberConfig {name}: must be positive, got {value!r}")
        for name in ("collision_margin", "drivable_margin", "bound_slack"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ScenarioError(f"PerturberConfig {name}: must be >= 0, got {value!r}")
        if self.bound_slack >= 0.01:
            raise ScenarioError(f"PerturberConfig bound_slack: must be below 0.01, got {self.bound_slack}")
        valid = {member.value for member in ActorClass}
        unknown = [name for name in self.perturbable_classes if name not in valid]
        if unknown or not self.perturbable_classes:
            raise ScenarioError(
                f"PerturberConfig perturbable_classes: {list(self.perturbable_classes)} must be a non-empty subset "
                f"of {sorted(valid)}"
            )
        object.__setattr__(self, "perturbable_classes", tuple(self.perturbable_classes))
        self.bounds  # noqa: B018 - validates the kinematic bounds with their own messages

    @property
    def bounds(self) -> KinematicBounds:
        return KinematicBounds(
            max_curvature=self.max_curvature,
            max_curvature_rate=self.max_curvature_rate,
            max_accel=self.max_accel,
            max_lateral_accel=self.max_lateral_accel,
            max_speed=self.max_speed,
        )

    @property
    def perturbation_dim(self) -> int:
        """Entries of delta per perturbed actor: dx0, dy0, dheading0, dv0, then K accel and K curvature-rate knots."""
        return STATE_OFFSETS + 2 * self.num_knots

    @classmethod
    def from_mapping(cls, parameters: Mapping[str, Any], context: str = "PerturberConfig") -> PerturberConfig:
        return config_from_mapping(cls, parameters, context)


def load_perturber_config(path: Path, *, node: str) -> PerturberConfig:
    """The parameters of node ``node`` (advsim_ros.graph names it) in a YAML file in the ROS shape; errors name
    the file and key."""
    return PerturberConfig.from_mapping(load_node_params(path, node), f"{path} /{node}")


def perturbation_names(num_knots: int) -> tuple[str, ...]:
    """Names of the entries of one actor's delta block, in order."""
    accel = tuple(f"da_{k}" for k in range(num_knots))
    rate = tuple(f"dr_{k}" for k in range(num_knots))
    return ("dx0", "dy0", "dheading0", "dv0", *accel, *rate)
