"""Parameters of the modular stack (params/stack_modular.yaml, node /modular_stack), one section per module."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from advsim_ros.core.types import ScenarioError
from advsim_ros.stacks.interface import TopicIoConfig
from advsim_ros.stacks.params import default_params_file, load_stack_config

NODE_NAME = "modular_stack"


def _positive(owner: str, **values: float) -> None:
    for name, value in values.items():
        if not (math.isfinite(value) and value > 0):
            raise ScenarioError(f"{owner} {name}: must be positive, got {value!r}")


def _range(owner: str, name: str, bounds: tuple[float, ...]) -> None:
    if len(bounds) != 2 or not all(math.isfinite(value) for value in bounds) or not bounds[0] < bounds[1]:
        raise ScenarioError(f"{owner} {name}: expected [low, high] with low < high, got {list(bounds)}")


@dataclass(frozen=True)
class GroundConfig:
    """Ground removal: lowest return per coarse cell, smoothed; points near it are ground."""

    range_x: tuple[float, ...] = (-72.0, 72.0)  # kept x range in the ego frame [m] (the metric range)
    range_y: tuple[float, ...] = (-40.0, 40.0)  # kept y range in the ego frame [m]
    range_z: tuple[float, ...] = (-4.0, 5.0)  # kept z range in the ego frame [m] (drops stray returns)
    self_filter: tuple[float, ...] = (-1.6, 3.4, -1.5, 1.5)  # x min, x max, y min, y max of own-vehicle returns [m]
    cell_size: float = 2.0  # ground-height cell edge [m]
    ground_tolerance: float = 0.25  # points less than this above the local ground are ground [m]
    max_object_height: float = 3.0  # points higher than this above the ground are ignored (canopy, signs) [m]
    ground_outlier: float = 0.3  # a cell further than this from its 3x3 median takes the median [m]

    def __post_init__(self) -> None:
        for name in ("range_x", "range_y", "range_z"):
            _range("ground", name, getattr(self, name))
        if len(self.self_filter) != 4:
            raise ScenarioError(
                f"ground self_filter: expected [x_min, x_max, y_min, y_max], got {list(self.self_filter)}"
            )
        _range("ground", "self_filter x", self.self_filter[:2])
        _range("ground", "self_filter y", self.self_filter[2:])
        _positive(
            "ground",
            cell_size=self.cell_size,
            ground_tolerance=self.ground_tolerance,
            max_object_height=self.max_object_height,
            ground_outlier=self.ground_outlier,
        )
        if self.max_object_height <= self.ground_tolerance:
            raise ScenarioError("ground max_object_height: must exceed ground_tolerance")


@dataclass(frozen=True)
class DetectorConfig:
    """Clustering detector: connected components of a BEV occupancy grid, L-shape box fitting."""

    cell_size: float = 0.2  # occupancy cell edge [m]
    min_points: int = 5  # clusters with fewer points are dropped
    max_footprint: float = 16.0  # clusters whose axis-aligned diagonal exceeds this are structures, dropped [m]
    min_top_height: float = 0.4  # clusters whose highest return is lower than this above the ground are dropped [m]
    angle_steps: int = 30  # headings tried over [0, 90) deg in the L-shape fit
    closeness_floor: float = 0.05  # distance floor of the closeness criterion (Zhang et al. 2017) [m]
    complete_vehicles: bool = True  # grow partly seen vehicles to the prior size, away from the sensor
    vehicle_prior: tuple[float, ...] = (4.3, 1.8)  # typical car length, width [m]
    vehicle_length: tuple[float, ...] = (2.4, 7.5)  # accepted vehicle length after completion [m]
    vehicle_width: tuple[float, ...] = (1.3, 2.8)  # accepted vehicle width [m]
    vehicle_height: tuple[float, ...] = (1.1, 3.2)  # accepted vehicle top above the ground [m]
    vehicle_min_points: int = 15  # fewer returns than this are never a vehicle (sparse clutter)
    vehicle_min_extent: float = 1.0  # a vehicle shows at least this much of its longer side [m]
    vehicle_min_seen_width: float = 1.1  # ... and this much across, unless it is longer than a cyclist [m]
    pedestrian_height: tuple[float, ...] = (1.0, 2.1)  # accepted pedestrian / cyclist top above the ground [m]
    pedestrian_footprint: float = 1.2  # pedestrians fit in a square of this edge [m]
    cyclist_length: tuple[float, ...] = (1.2, 2.2)  # cyclist box length [m]
    vehicle_typical_height: tuple[float, ...] = (1.5, 0.4)  # mean and spread of a car's top above the ground [m]
    confidence_points: float = 60.0  # a vehicle with this many points scores 0.5 on the point-count term
    only_classes: tuple[str, ...] = ("vehicle", "pedestrian", "cyclist", "other")  # classes reported

    def __post_init__(self) -> None:
        _positive(
            "detector",
            cell_size=self.cell_size,
            max_footprint=self.max_footprint,
            min_top_height=self.min_top_height,
            closeness_floor=self.closeness_floor,
            pedestrian_footprint=self.pedestrian_footprint,
            confidence_points=self.confidence_points,
        )
        _positive(
            "detector", vehicle_min_extent=self.vehicle_min_extent, vehicle_min_seen_width=self.vehicle_min_seen_width
        )
        if self.min_points < 1 or self.vehicle_min_points < 1:
            raise ScenarioError("detector min_points, vehicle_min_points: must be >= 1")
        if self.angle_steps < 2:
            raise ScenarioError(f"detector angle_steps: must be >= 2, got {self.angle_steps}")
        if len(self.vehicle_typical_height) != 2 or not self.vehicle_typical_height[1] > 0:
            raise ScenarioError("detector vehicle_typical_height: expected [mean, spread > 0]")
        for name in ("vehicle_length", "vehicle_width", "vehicle_height", "pedestrian_height", "cyclist_length"):
            _range("detector", name, getattr(self, name))
        if len(self.vehicle_prior) != 2 or min(self.vehicle_prior) <= 0:
            raise ScenarioError(f"detector vehicle_prior: expected [length, width] > 0, got {list(self.vehicle_prior)}")
        known = {"vehicle", "pedestrian", "cyclist", "other"}
        if not self.only_classes or not set(self.only_classes) <= known:
            raise ScenarioError(f"detector only_classes: expected a non-empty subset of {sorted(known)}")


@dataclass(frozen=True)
class TrackerConfig:
    """Multi-object tracker: constant-velocity Kalman filters, Hungarian assignment on centre distance."""

    gate: float = 2.5  # largest distance of a vehicle detection from its track's predicted centre [m]
    small_gate: float = 1.0  # the same for pedestrians, cyclists and other objects [m]
    min_hits: int = 2  # a track is confirmed (and predicted) after this many updates
    max_misses: int = 3  # a track is dropped after this many sweeps without a detection
    position_noise: float = 0.5  # measurement noise of a box centre, standard deviation [m]
    acceleration_noise: float = 2.0  # process noise, standard deviation of acceleration [m/s^2]
    initial_speed_noise: float = 5.0  # standard deviation of a new track's velocity [m/s]
    static_speed: float = 1.0  # tracks slower than this are predicted standing still [m/s]
    static_displacement: float = 2.0  # tracks that moved less than this since they were born stand still [m]
    heading_tolerance_deg: float = 30.0  # vehicles and cyclists count as moving only along their box, within this [deg]
    max_gap_s: float = 0.5  # a jump in time longer than this (or backwards) resets the tracker [s]

    def __post_init__(self) -> None:
        _positive(
            "tracker",
            gate=self.gate,
            small_gate=self.small_gate,
            position_noise=self.position_noise,
            acceleration_noise=self.acceleration_noise,
            initial_speed_noise=self.initial_speed_noise,
            max_gap_s=self.max_gap_s,
            heading_tolerance_deg=self.heading_tolerance_deg,
        )
        if self.min_hits < 1 or self.max_misses < 0:
            raise ScenarioError("tracker: need min_hits >= 1 and max_misses >= 0")
        if self.static_speed < 0 or self.static_displacement < 0:
            raise ScenarioError("tracker static_speed, static_displacement: must be >= 0")


@dataclass(frozen=True)
class PredictionConfig:
    """Motion forecasts of the tracked objects."""

    model: str = "ctrv"  # "cv" (constant velocity) or "ctrv" (constant turn rate and velocity)
    max_yaw_rate: float = 0.5  # turn rates are clipped to this [rad/s]
    yaw_rate_smoothing: float = 0.5  # weight of the newest turn-rate estimate in its running mean [1]

    def __post_init__(self) -> None:
        if self.model not in ("cv", "ctrv"):
            raise ScenarioError(f"prediction model: must be 'cv' or 'ctrv', got {self.model!r}")
        _positive("prediction", max_yaw_rate=self.max_yaw_rate)
        if not 0.0 < self.yaw_rate_smoothing <= 1.0:
            raise ScenarioError(f"prediction yaw_rate_smoothing: must be in (0, 1], got {self.yaw_rate_smoothing}")


@dataclass(frozen=True)
class PlannerConfig:
    """Frenet sampling planner: lateral x longitudinal rollouts along a reference path, scored."""

    horizon_s: float = 5.0  # plan length [s]
    ego_length: float = 4.7  # ego box length [m]
    ego_width: float = 1.9  # ego box width [m]
    ego_forward_offset: float = 1.0  # ego box centre ahead of the ego frame origin [m]
    step_s: float = 0.1  # time between plan poses [s]
    lateral_offsets: tuple[float, ...] = (-3.0, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0)  # end offsets from the reference [m]
    lateral_times: tuple[float, ...] = (2.5, 4.0)  # time to reach the end offset [s]
    speed_factors: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75, 0.9, 1.0, 1.1)  # end speeds / desired speed
    longitudinal_times: tuple[float, ...] = (3.0, 5.0)  # time to reach the end speed [s]
    speed_limit: float = 15.0  # no plan ends faster than this [m/s]
    min_desired_speed: float = 0.0  # desired speed is the current speed, at least this [m/s]
    max_curvature: float = 0.2  # reference curvatures are clipped to this [1/m]
    tentacle_spread: float = 0.06  # without a map, arcs up to this far from the ego's curvature are tried [1/m]
    tentacle_count: int = 13  # number of arcs tried (odd: the ego's own curvature is one of them)
    tentacle_clearance: float = 0.2  # an arc is free while the ego box keeps this from occupied cells [m]
    min_lookahead: float = 15.0  # arcs are judged over the distance covered in the horizon, at least this [m]
    lane_search_radius: float = 5.0  # a map lane is the reference when it passes this close to the ego [m]
    lane_heading_tolerance: float = 0.8  # ... and runs within this of the ego heading [rad]
    static_max_height: float = 2.0  # object returns higher than this above the ground do not block the ego [m]
    static_min_points: int = 2  # a static obstacle cell needs this many returns (one is noise)
    moving_clearance: float = 0.6  # cells this close to a moving object's box belong to it, not to the static world [m]
    footprint_circles: int = 5  # the ego box is covered by this many circles against static cells
    collision_stride: int = 2  # collisions are checked every this many plan steps (0.2 s: no overlap slips through)
    safety_margin: float = 0.5  # the ego box is grown by this on every side for the proximity cost [m]
    obstacle_reach: float = 100.0  # objects farther than this from the ego are ignored [m]
    weight_collision: float = 1000.0  # per second of overlap with an object (box or static cell), decaying in time
    collision_decay_s: float = 3.0  # collision cost decays as exp(-t / this) [s]
    weight_proximity: float = 5.0  # per second within safety_margin of an object
    weight_progress: float = 10.0  # per unit shortfall of travelled distance against the desired speed
    weight_speed_excess: float = 10.0  # per (m/s) of end speed above the desired speed
    weight_lateral_acceleration: float = 0.5  # per (m/s^2)^2, mean over the plan
    weight_longitudinal_acceleration: float = 0.5  # per (m/s^2)^2, mean over the plan
    weight_jerk: float = 0.05  # per (m/s^3)^2, mean over the plan
    weight_offset: float = 0.5  # per m^2 of mean squared lateral offset from the reference
    weight_offroad: float = 50.0  # per unit fraction of poses off the drivable area (with a map)
    drivable_resolution: float = 0.5  # raster cell of the map's drivable area [m]

    def __post_init__(self) -> None:
        _positive(
            "planner",
            horizon_s=self.horizon_s,
            ego_length=self.ego_length,
            ego_width=self.ego_width,
            step_s=self.step_s,
            speed_limit=self.speed_limit,
            max_curvature=self.max_curvature,
            lane_search_radius=self.lane_search_radius,
            lane_heading_tolerance=self.lane_heading_tolerance,
            obstacle_reach=self.obstacle_reach,
            static_max_height=self.static_max_height,
            collision_decay_s=self.collision_decay_s,
            drivable_resolution=self.drivable_resolution,
        )
        if self.tentacle_count < 1 or self.tentacle_count % 2 == 0:
            raise ScenarioError(f"planner tentacle_count: must be a positive odd number, got {self.tentacle_count}")
        if self.static_min_points < 1:
            raise ScenarioError(f"planner static_min_points: must be >= 1, got {self.static_min_points}")
        if self.footprint_circles < 1:
            raise ScenarioError(f"planner footprint_circles: must be >= 1, got {self.footprint_circles}")
        if self.collision_stride < 1:
            raise ScenarioError(f"planner collision_stride: must be >= 1, got {self.collision_stride}")
        if not math.isfinite(self.ego_forward_offset):
            raise ScenarioError(f"planner ego_forward_offset: must be finite, got {self.ego_forward_offset!r}")
        if self.horizon_s < self.step_s:
            raise ScenarioError("planner horizon_s: must be at least one step_s")
        for name in ("lateral_offsets", "lateral_times", "speed_factors", "longitudinal_times"):
            values = getattr(self, name)
            if not values or not all(math.isfinite(value) for value in values):
                raise ScenarioError(f"planner {name}: needs at least one finite value")
        if min(self.lateral_times) <= 0 or min(self.longitudinal_times) <= 0:
            raise ScenarioError("planner lateral_times / longitudinal_times: must be positive")
        if min(self.speed_factors) < 0:
            raise ScenarioError("planner speed_factors: must be >= 0")
        weights = {name: getattr(self, name) for name in self.__dataclass_fields__ if name.startswith("weight_")}
        weights["safety_margin"] = self.safety_margin
        weights["moving_clearance"] = self.moving_clearance
        weights["tentacle_spread"] = self.tentacle_spread
        weights["tentacle_clearance"] = self.tentacle_clearance
        weights["min_lookahead"] = self.min_lookahead
        weights["min_desired_speed"] = self.min_desired_speed
        for name, value in weights.items():
            if not (math.isfinite(value) and value >= 0):
                raise ScenarioError(f"planner {name}: must be >= 0, got {value!r}")


@dataclass(frozen=True)
class ModularStackConfig:
    """The whole modular stack."""

    ground: GroundConfig = field(default_factory=GroundConfig)
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    prediction: PredictionConfig = field(default_factory=PredictionConfig)
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    io: TopicIoConfig = field(default_factory=TopicIoConfig)


def load_modular_config(path: Path | None = None) -> ModularStackConfig:
    """The modular stack's config from params/stack_modular.yaml (or `path`)."""
    return load_stack_config(ModularStackConfig, path or default_params_file("stack_modular.yaml"), NODE_NAME)
