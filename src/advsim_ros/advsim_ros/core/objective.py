"""The adversarial objective L_adv that the search maximises, its ablation presets and two baselines.

L_adv = w_IL l_IL + w_col sum_t l_col(t) + w_c sum_t c_o(t), on the stack's plan (the SDV
follows it), the human trajectory and the perturbed actors' futures (AdvSim, Wang et al.,
CVPR 2021):
- l_IL: mean over plan poses of the smooth-L1 distance (Huber, transition `smooth_l1_beta`,
  summed over x and y) between the plan and the human trajectory at the same stamps [m];
  poses after the end of the log are left out.
- l_col(t): the worst in-range actor that exists at plan stamp t (core.futures: over its observed
  span only): 1 + BEV IoU with the SDV's box when they overlap (deeper overlap costs more), else
  max(0, 1 - gap / collision_margin) with the gap between the boxes [m], so the cost rises
  before contact.
- c_o(t): comfort and rules: w_lat max(0, |a_lat| - lateral_acceleration_limit) +
  w_jerk max(0, |jerk| - jerk_limit) + w_drivable (share of the SDV's box corners and
  centre outside the drivable area) + w_lane max(0, distance to the nearest lane
  centreline - lane_half_width). The drivable part needs a DrivableArea and the lane part a
  RoadMap with centrelines; without them those parts are 0.
Each term can be switched off (presets M0-M5). Baselines for comparison:
- "closest_distance": -(smallest gap between the SDV's plan boxes and any actor) [m]
  (with no actor in range: minus the range's half-diagonal, as far as an actor can be);
- "max_margin": C(plan) - C(human), where C is the collision + comfort cost above (with
  the objective's weights) evaluated on a trajectory: how much worse the stack's plan is
  than the human's under the same planning cost (the human trajectory is collision-free in
  the feasible set, so a large margin means the stack chose a worse plan than it could).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from advsim_ros.core.futures import ActorFutures, BoolArray
from advsim_ros.core.geometry import bev_iou, box_corners, box_distance
from advsim_ros.core.metrics import (
    MetricsConfig,
    actors_in_range,
    human_at,
    plan_times,
    require_aligned,
    trajectory_kinematics,
)
from advsim_ros.core.params import ParamsError, config_from_mapping, load_node_params
from advsim_ros.core.types import EgoGeometry, EgoTrajectory, FloatArray, Plan, RoadMap, ScenarioError

if TYPE_CHECKING:  # the raster type only; importing drivable pulls in scipy
    from advsim_ros.core.types import DrivableArea

OBJECTIVE_KINDS = ("advsim", "closest_distance", "max_margin")
PRESET_NAMES = ("M0", "M1", "M2", "M3", "M4", "M5", "closest_distance", "max_margin")
MIN_PLAN_POSES = 4  # jerk needs four poses


@dataclass(frozen=True)
class ObjectiveConfig:
    """Which terms L_adv uses and their weights (params/scorer.yaml)."""

    kind: str = "advsim"  # "advsim" (L_adv), "closest_distance" or "max_margin" (baselines)
    use_imitation: bool = True  # l_IL term on
    use_collision: bool = True  # collision term on
    use_comfort: bool = True  # comfort / rule term on
    imitation_weight: float = 1.0  # w_IL [1/m]
    collision_weight: float = 1.0  # w_col [1]
    comfort_weight: float = 1.0  # w_c [1]
    smooth_l1_beta: float = 1.0  # smooth-L1 switches from quadratic to linear at this error [m]
    collision_margin: float = 2.0  # the collision cost starts rising when the boxes are this close [m]
    lateral_acceleration_limit: float = 2.0  # comfortable |lateral acceleration| [m/s^2]
    jerk_limit: float = 2.0  # comfortable |longitudinal jerk| [m/s^3]
    lateral_acceleration_weight: float = 1.0  # cost per m/s^2 above the limit [s^2/m]
    jerk_weight: float = 0.1  # cost per m/s^3 above the limit [s^3/m]
    drivable_weight: float = 1.0  # cost of a box entirely off the drivable area [1]
    lane_weight: float = 0.5  # cost per metre beyond half a lane from the nearest centreline [1/m]
    lane_half_width: float = 1.75  # half a lane's width [m]

    def __post_init__(self) -> None:
        name = type(self).__name__
        if self.kind not in OBJECTIVE_KINDS:
            raise ScenarioError(f"{name}.kind: {self.kind!r} is not one of {', '.join(OBJECTIVE_KINDS)}")
        if self.kind == "advsim" and not (self.use_imitation or self.use_collision or self.use_comfort):
            raise ScenarioError(f"{name}: use_imitation, use_collision and use_comfort are all off")
        for key in (
            "imitation_weight",
            "collision_weight",
            "comfort_weight",
            "lateral_acceleration_limit",
            "jerk_limit",
            "lateral_acceleration_weight",
            "jerk_weight",
            "drivable_weight",
            "lane_weight",
            "lane_half_width",
        ):
            value = getattr(self, key)
            if not (np.isfinite(value) and value >= 0.0):
                raise ScenarioError(f"{name}.{key}: must be finite and non-negative, got {value!r}")
        for key in ("smooth_l1_beta", "collision_margin"):
            value = getattr(self, key)
            if not (np.isfinite(value) and value > 0.0):
                raise ScenarioError(f"{name}.{key}: must be positive, got {value!r}")


_PRESET_TERMS = {  # (imitation, collision, comfort): this project's reading of the paper's ablation rows
    "M0": (True, False, False),
    "M1": (False, True, False),
    "M2": (True, True, False),
    "M3": (True, False, True),
    "M4": (False, True, True),
    "M5": (True, True, True),
}


def objective_preset(name: str, base: ObjectiveConfig | None = None) -> ObjectiveConfig:
    """Preset `name` (M0-M5, closest_distance, max_margin) applied to base's weights (defaults when None).

    M0 l_IL; M1 collision; M2 l_IL + collision; M3 l_IL + comfort; M4 collision + comfort;
    M5 all three (the full AdvSim objective, the default).
    """
    config = ObjectiveConfig() if base is None else base
    if name in _PRESET_TERMS:
        imitation, collision, comfort = _PRESET_TERMS[name]
        return replace(config, kind="advsim", use_imitation=imitation, use_collision=collision, use_comfort=comfort)
    if name in ("closest_distance", "max_margin"):
        return replace(config, kind=name)
    raise ScenarioError(f"unknown objective preset {name!r} (known: {', '.join(PRESET_NAMES)})")


@dataclass(frozen=True, eq=False)
class ObjectiveTerms:
    """The objective of one query and its parts (each already summed over time, before weights)."""

    value: float  # what the search maximises (L_adv or the baseline's value)
    imitation: float  # l_IL [m]
    collision: float  # sum_t l_col(t) [1]
    comfort: float  # sum_t c_o(t) [1]
    closest_distance: float  # smallest gap between the SDV's plan and any in-range actor; inf without actors [m]
    lane_available: bool  # whether a drivable area or lane centrelines fed the rule part of c_o


def smooth_l1(error: FloatArray, beta: float) -> FloatArray:
    """Elementwise Huber / smooth-L1: 0.5 e^2 / beta below beta, |e| - 0.5 beta above [m]."""
    magnitude = np.abs(error)
    result: FloatArray = np.where(magnitude < beta, 0.5 * magnitude**2 / beta, magnitude - 0.5 * beta)
    return result


def imitation_loss(plan: Plan, human: EgoTrajectory, beta: float) -> float:
    """l_IL: mean smooth-L1 (summed over x, y) between plan and human poses at the plan's stamps [m]."""
    human_xy, _, covered = human_at(human, plan.stamps_ns)
    if not np.any(covered):
        raise ScenarioError("imitation loss: the human trajectory does not cover any of the plan's stamps")
    per_pose = smooth_l1(plan.xy[covered] - human_xy[covered], beta).sum(axis=-1)
    return float(per_pose.mean())


def collision_costs(
    sdv_boxes: FloatArray, actor_boxes: FloatArray, margin: float, present: BoolArray | None = None
) -> tuple[FloatArray, FloatArray]:
    """(H,) l_col(t) over actors (N, H, 5) against SDV boxes (H, 5), and (H,) the smallest gap [m].

    ``present`` (N, H): where each actor exists (default everywhere); elsewhere it costs 0 and is
    infinitely far, whatever its box holds.
    """
    steps = sdv_boxes.shape[0]
    if actor_boxes.shape[0] == 0:
        return np.zeros(steps), np.full(steps, np.inf)
    exists = np.ones(actor_boxes.shape[:2], dtype=bool) if present is None else present
    boxes = np.where(exists[..., None], actor_boxes, 0.0)  # finite stand-ins, masked below
    gaps = np.where(exists, box_distance(boxes, sdv_boxes[None]), np.inf)  # (N, H) [m]
    iou = np.where(exists, bev_iou(boxes, sdv_boxes[None]), 0.0)
    overlapping = iou > 0.0
    touching = gaps <= 0.0  # touching without area overlap counts as contact
    cost = np.where(overlapping | touching, 1.0 + iou, np.maximum(0.0, 1.0 - gaps / margin))
    return cost.max(axis=0), gaps.min(axis=0)


def _lane_distance(points: FloatArray, road_map: RoadMap) -> FloatArray:
    """(H,) distance from each point to the nearest lane centreline [m]."""
    import shapely

    # MultiLineString, not multilinestrings(): lanes have different point counts (real maps), which
    # numpy cannot stack into one array.
    lines = shapely.MultiLineString([np.asarray(lane) for lane in road_map.lane_centerlines])
    result: FloatArray = shapely.distance(shapely.points(points), lines)
    return result


def comfort_costs(
    plan: Plan,
    config: ObjectiveConfig,
    drivable: DrivableArea | None,
    road_map: RoadMap | None,
    ego: EgoGeometry,
) -> tuple[FloatArray, bool]:
    """(H,) c_o at each plan pose, and whether the rule part (drivable area / lanes) was available.

    Kinematic terms computed between poses are assigned to the later pose.
    """
    steps = plan.stamps_ns.shape[0]
    kinematics = trajectory_kinematics(plan_times(plan), plan.xy, plan.yaws)
    cost = np.zeros(steps)
    lateral = np.maximum(0.0, np.abs(kinematics.lateral_acceleration) - config.lateral_acceleration_limit)
    cost[1:] += config.lateral_acceleration_weight * lateral
    jerk = np.maximum(0.0, np.abs(kinematics.jerk) - config.jerk_limit)
    cost[2 : 2 + jerk.shape[0]] += config.jerk_weight * jerk
    available = False
    boxes = ego.boxes(plan.xy, plan.yaws)
    if drivable is not None:
        available = True
        samples = np.concatenate([box_corners(boxes), boxes[:, None, :2]], axis=1)  # (H, 5, 2)
        outside = ~drivable.contains(samples[..., 0], samples[..., 1])
        cost += config.drivable_weight * outside.mean(axis=1)
    if road_map is not None and road_map.lane_centerlines:
        available = True
        beyond = np.maximum(0.0, _lane_distance(boxes[:, :2], road_map) - config.lane_half_width)
        cost += config.lane_weight * beyond
    return cost, available


def _planning_cost(
    plan: Plan,
    actors: ActorFutures,
    ego: EgoGeometry,
    config: ObjectiveConfig,
    metrics: MetricsConfig,
    drivable: DrivableArea | None,
    road_map: RoadMap | None,
) -> tuple[float, float, float, bool]:
    """Collision sum, comfort sum, closest gap and lane availability of one trajectory."""
    active = actors_in_range(plan, actors, metrics)
    sdv = ego.boxes(plan.xy, plan.yaws)
    collision, gaps = collision_costs(sdv, actors.boxes()[active], config.collision_margin, actors.present[active])
    comfort, available = comfort_costs(plan, config, drivable, road_map, ego)
    return float(collision.sum()), float(comfort.sum()), float(gaps.min()), available


def evaluate_objective(
    plan: Plan,
    human: EgoTrajectory,
    actors: ActorFutures,
    ego: EgoGeometry,
    config: ObjectiveConfig,
    metrics: MetricsConfig | None = None,
    drivable: DrivableArea | None = None,
    road_map: RoadMap | None = None,
) -> ObjectiveTerms:
    """The objective of one query: the stack's plan against the human trajectory and the actors.

    `actors` are sampled at the plan's stamps; only actors inside the metrics' evaluation
    range at the decision time count, and each only where it exists; ``ego`` is the SDV's box.
    """
    metrics_config = MetricsConfig() if metrics is None else metrics
    require_aligned(plan, actors)
    if plan.stamps_ns.shape[0] < MIN_PLAN_POSES:
        raise ScenarioError(f"objective: the plan has {plan.stamps_ns.shape[0]} poses, needs >= {MIN_PLAN_POSES}")
    imitation = imitation_loss(plan, human, config.smooth_l1_beta)
    collision, comfort, closest, available = _planning_cost(
        plan, actors, ego, config, metrics_config, drivable, road_map
    )
    if config.kind == "closest_distance":
        farthest = float(np.hypot(max(np.abs(metrics_config.x_range)), max(np.abs(metrics_config.y_range))))
        value = -closest if np.isfinite(closest) else -farthest
    elif config.kind == "max_margin":
        human_xy, human_yaws, covered = human_at(human, plan.stamps_ns)
        if not np.all(covered):
            raise ScenarioError("max-margin objective: the human trajectory must cover every plan stamp")
        human_plan = Plan(plan.stamps_ns, human_xy, human_yaws)
        human_collision, human_comfort, _, _ = _planning_cost(
            human_plan, actors, ego, config, metrics_config, drivable, road_map
        )
        value = config.collision_weight * (collision - human_collision) + config.comfort_weight * (
            comfort - human_comfort
        )
    else:
        value = (
            config.imitation_weight * imitation * config.use_imitation
            + config.collision_weight * collision * config.use_collision
            + config.comfort_weight * comfort * config.use_comfort
        )
    return ObjectiveTerms(
        value=float(value),
        imitation=imitation,
        collision=collision,
        comfort=comfort,
        closest_distance=closest,
        lane_available=available,
    )


@dataclass(frozen=True)
class ScorerSettings:
    """What the scorer computes: the objective and the metrics."""

    objective: ObjectiveConfig
    metrics: MetricsConfig


def scorer_settings_from_params(parameters: Mapping[str, Any], context: str) -> ScorerSettings:
    """Settings from the scorer's parameters: `objective` (with an optional `preset`) and `metrics` sections."""
    unknown = sorted(set(parameters) - {"objective", "metrics"})
    if unknown:
        raise ParamsError(f"{context}: unknown parameter(s) {unknown} (known: ['metrics', 'objective'])")
    objective = objective_from_params(parameters.get("objective", {}), f"{context}.objective")
    metrics = config_from_mapping(MetricsConfig, parameters.get("metrics", {}), f"{context}.metrics")
    return ScorerSettings(objective, metrics)


def objective_from_params(values: Mapping[str, Any], context: str) -> ObjectiveConfig:
    """The objective section: ObjectiveConfig's fields, and an optional `preset` (M0..M5 or a baseline) applied
    on top of them."""
    fields = dict(values)
    preset = fields.pop("preset", None)
    objective = config_from_mapping(ObjectiveConfig, fields, context)
    if preset is not None:
        if not isinstance(preset, str) or preset not in PRESET_NAMES:
            raise ParamsError(f"{context}.preset: {preset!r} is not one of {', '.join(PRESET_NAMES)}")
        objective = objective_preset(preset, objective)
    return objective


def load_scorer_settings(path: Path, *, node: str) -> ScorerSettings:
    """Read the parameters of node ``node`` (advsim_ros.graph names it) in params/scorer.yaml."""
    return scorer_settings_from_params(load_node_params(path, node), f"{path} /{node}")
