"""Physically plausible actor perturbations: feasible sets, actor selection and projection (AdvSim, Sec. 3).

Each actor's perturbation is a normalised delta rolled out through the kinematic bicycle model
from the fit of its logged track (``rollout``); its feasible set is a cloud of sampled deltas
whose rollouts pass the pruning (``pruning``, ``feasible_set``); projection replaces a proposed
delta by the L2-nearest feasible candidates (``projection``); selection picks the actors to
perturb in a window (``selection``).

Modules, in the order a window is worked on:

- ``config``: ``PerturberConfig`` (params/perturber.yaml), the delta layout;
- ``window``: ``Window``, the perturbed horizon, and how a logged actor appears over it;
- ``reference``: ``ActorReference``, the bicycle-model fit of a logged track (delta = 0);
- ``rollout``: ``PerturbedTrajectory``, delta -> controls -> trajectory;
- ``obstacles``: ``WindowObstacles``, the SDV's and the other actors' logged boxes;
- ``cull_raster``, ``pruning``: the pruning of sampled candidates, cheapest test first;
- ``feasible_set``: ``FeasibleSet``, ``build_feasible_set``;
- ``projection_index``, ``projection``: ``project``;
- ``selection``: ``ActorSelection``, ``select_actors``;
- ``errors``: ``InfeasibleError``.

The names below are the package's public interface; import them from here.
"""

from advsim_ros.core.feasibility.config import (
    STATE_OFFSETS,
    PerturberConfig,
    load_perturber_config,
    perturbation_names,
)
from advsim_ros.core.feasibility.errors import InfeasibleError
from advsim_ros.core.feasibility.feasible_set import COLLISION_BATCH, FeasibleSet, build_feasible_set
from advsim_ros.core.feasibility.obstacles import (
    EGO_ID,
    WindowObstacles,
    actor_window_boxes,
    ego_window_boxes,
    window_obstacles,
)
from advsim_ros.core.feasibility.projection import MAX_JOINT_CHECKED, project
from advsim_ros.core.feasibility.pruning import COARSE_STRIDE, KINEMATIC_CHECKS, PruningCounts
from advsim_ros.core.feasibility.reference import ActorReference, fit_reference
from advsim_ros.core.feasibility.rollout import PerturbedTrajectory, perturbation_to_trajectory
from advsim_ros.core.feasibility.selection import (
    ActorReport,
    ActorSelection,
    TooFewActorsError,
    rank_actors,
    select_actors,
)
from advsim_ros.core.feasibility.window import STATIC_SPAN, Window, is_standing

__all__ = [
    "COARSE_STRIDE",
    "COLLISION_BATCH",
    "EGO_ID",
    "KINEMATIC_CHECKS",
    "MAX_JOINT_CHECKED",
    "STATE_OFFSETS",
    "STATIC_SPAN",
    "ActorReference",
    "ActorReport",
    "ActorSelection",
    "FeasibleSet",
    "InfeasibleError",
    "PerturbedTrajectory",
    "PerturberConfig",
    "PruningCounts",
    "TooFewActorsError",
    "Window",
    "WindowObstacles",
    "actor_window_boxes",
    "build_feasible_set",
    "ego_window_boxes",
    "fit_reference",
    "is_standing",
    "load_perturber_config",
    "perturbation_names",
    "perturbation_to_trajectory",
    "project",
    "rank_actors",
    "select_actors",
    "window_obstacles",
]
