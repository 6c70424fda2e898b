"""Parameters of the auto-labeller (params/labelling.yaml, node /advsim_label), one section per stage."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from advsim_ros.core.params import config_from_mapping, load_node_params
from advsim_ros.core.types import ScenarioError
from advsim_ros.stacks.modular.config import DetectorConfig, GroundConfig

LABELLING_NODE = "advsim_label"


def _positive(owner: str, **values: float) -> None:
    for name, value in values.items():
        if not (math.isfinite(value) and value > 0):
            raise ScenarioError(f"labelling {owner} {name}: must be positive, got {value!r}")


@dataclass(frozen=True)
class OfflineTrackerConfig:
    """Offline tracking: constant-velocity Kalman filter forwards, Hungarian association, RTS smoother backwards."""

    gate: float = 2.5  # largest distance of a vehicle detection from its track's prediction [m]
    small_gate: float = 1.2  # the same for pedestrians and cyclists [m]
    max_misses: int = 5  # a track survives this many sweeps without a detection (offline: bridged by smoothing)
    position_noise: float = 0.35  # measurement noise of a box centre, standard deviation [m]
    acceleration_noise: float = 1.5  # process noise, standard deviation of acceleration [m/s^2]
    initial_speed_noise: float = 6.0  # standard deviation of a new track's velocity [m/s]
    link_gap: int = 10  # fragments of one object up to this many sweeps apart are joined [sweeps]
    link_distance: float = 2.0  # ... when each one's smoothed motion reaches the other within this [m]
    min_points: int = 15  # a vehicle candidate with fewer returns is never tracked: no track starts from it [1]
    min_small_points: int = 10  # the same for pedestrian and cyclist candidates [1]
    extend_static: bool = True  # parked vehicles' tracks grow over sweeps with pieces of them (labelling/extend.py)

    def __post_init__(self) -> None:
        _positive(
            "tracker",
            gate=self.gate,
            small_gate=self.small_gate,
            position_noise=self.position_noise,
            acceleration_noise=self.acceleration_noise,
            initial_speed_noise=self.initial_speed_noise,
            link_distance=self.link_distance,
        )
        if self.max_misses < 0 or self.link_gap < 0:
            raise ScenarioError("labelling tracker max_misses, link_gap: must be >= 0")
        if self.min_points < 1 or self.min_small_points < 1:
            raise ScenarioError("labelling tracker min_points, min_small_points: must be >= 1")


@dataclass(frozen=True)
class GateConfig:
    """Quality gates: which tracks become (perturbable) actors. Every gate is listed in docs/data.md."""

    min_detections: int = 6  # a track needs at least this many detections (0.6 s at 10 Hz)
    min_detection_ratio: float = 0.5  # detections / sweeps over the track's span
    min_class_share: float = 0.6  # share of its detections that agree with the track's class
    min_confidence: float = 0.12  # the track's confidence (see refine.track_confidence)
    vehicle_height: tuple[float, ...] = (1.3, 2.4)  # a vehicle track's top above the ground (hedges, walls: taller) [m]
    long_vehicle_length: float = 7.0  # vehicle tracks at least this long are trucks, buses, tankers ... [m]
    long_vehicle_height: float = 4.3  # ... whose top may reach this high [m]
    long_vehicle_width: float = 2.2  # ... and who are at least this wide (walls, fences, hedges seen side-on: thin) [m]
    ground_radius: float = 6.0  # a vehicle's ground is the lowest ground seen this close to its centre [m]
    max_ground_lift: float = 0.6  # a vehicle track whose own ground sits higher above that is not on the road [m]
    max_static_spread: float = 0.7  # median distance of a static track's detections from their median centre [m]
    static_speed: float = 0.8  # tracks whose smoothed speed stays below this are static [m/s]
    static_displacement: float = 1.5  # ... and whose net displacement is below this [m]
    max_heading_misalignment_deg: float = 35.0  # a moving vehicle moves along its box, within this [deg]
    classes: tuple[str, ...] = ("vehicle", "pedestrian", "cyclist")  # classes that become actors
    small_must_move: bool = True  # static "pedestrians" and "cyclists" are mostly poles and trunks: dropped
    max_share_inside: float = 0.5  # a track inside another actor's box this share of its frames: a duplicate, or
    # (a pedestrian or cyclist inside a vehicle) part of it (labelling/overlaps.py)
    inside_margin: float = 0.3  # the other's box grown by this for that test [m]

    def __post_init__(self) -> None:
        if self.min_detections < 1:
            raise ScenarioError("labelling gates min_detections: must be >= 1")
        for name in ("min_detection_ratio", "min_class_share", "min_confidence", "max_share_inside"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ScenarioError(f"labelling gates {name}: must lie in [0, 1], got {value}")
        _positive(
            "gates",
            max_static_spread=self.max_static_spread,
            static_speed=self.static_speed,
            static_displacement=self.static_displacement,
            max_heading_misalignment_deg=self.max_heading_misalignment_deg,
            long_vehicle_length=self.long_vehicle_length,
            long_vehicle_height=self.long_vehicle_height,
            long_vehicle_width=self.long_vehicle_width,
            ground_radius=self.ground_radius,
            max_ground_lift=self.max_ground_lift,
        )
        if self.inside_margin < 0.0:
            raise ScenarioError(f"labelling gates inside_margin: must be >= 0, got {self.inside_margin}")
        if len(self.vehicle_height) != 2 or not 0 < self.vehicle_height[0] < self.vehicle_height[1]:
            raise ScenarioError(f"labelling gates vehicle_height: expected [low, high], got {self.vehicle_height}")
        known = {"vehicle", "pedestrian", "cyclist", "other"}
        if not self.classes or not set(self.classes) <= known:
            raise ScenarioError(f"labelling gates classes: expected a non-empty subset of {sorted(known)}")


LABELLING_DETECTOR = DetectorConfig(
    vehicle_prior=(3.9, 1.65),
    vehicle_length=(2.4, 18.0),
    vehicle_width=(1.3, 3.0),  # a 2.55 m truck measures up to 2.95 m on the 0.2 m grid
    vehicle_height=(1.1, 4.3),
    max_footprint=19.0,
)


@dataclass(frozen=True)
class LabellingConfig:
    """Everything the auto-labeller reads; the detector and ground sections are the reference stack's."""

    ground: GroundConfig = field(default_factory=GroundConfig)
    # The reference detector with a smaller car prior (KITTI's and European cars average ~3.9 x 1.65 m; a
    # track's own detections then make its box longer when they show more), and vehicles up to 18 m long and
    # 4.3 m tall (trucks, buses, tankers: one cluster, one track) where the stack stops at 7.5 m and 3.2 m.
    detector: DetectorConfig = field(default_factory=lambda: LABELLING_DETECTOR)
    tracker: OfflineTrackerConfig = field(default_factory=OfflineTrackerConfig)
    gates: GateConfig = field(default_factory=GateConfig)
    vehicle_size_quantile: float = 0.8  # a vehicle's length and width: this quantile of its detected extents [1]
    max_vehicle_size: tuple[float, ...] = (18.0, 2.8)  # length, width a vehicle track is clipped to [m]

    def __post_init__(self) -> None:
        if not 0.0 < self.vehicle_size_quantile <= 1.0:
            raise ScenarioError("labelling vehicle_size_quantile: must lie in (0, 1]")
        if len(self.max_vehicle_size) != 2 or min(self.max_vehicle_size) <= 0:
            raise ScenarioError("labelling max_vehicle_size: expected [length, width] > 0")


_SECTIONS = {"ground": GroundConfig, "detector": DetectorConfig, "tracker": OfflineTrackerConfig, "gates": GateConfig}


def load_labelling_config(path: Path) -> LabellingConfig:
    """The labeller's parameters from a file in the ROS shape (``/advsim_label: ros__parameters: ...``)."""
    parameters = dict(load_node_params(Path(path), LABELLING_NODE))
    sections: dict[str, Any] = {
        name: config_from_mapping(kind, parameters.pop(name), f"{path} {name}")
        for name, kind in _SECTIONS.items()
        if name in parameters
    }
    if "detector" in sections:  # keys left out keep the labeller's detector defaults, not the stack's
        given = load_node_params(Path(path), LABELLING_NODE)["detector"]
        sections["detector"] = dataclasses.replace(
            LABELLING_DETECTOR, **{key: getattr(sections["detector"], key) for key in given}
        )
    top = config_from_mapping(LabellingConfig, parameters, f"{path}")
    return dataclasses.replace(top, **sections)
