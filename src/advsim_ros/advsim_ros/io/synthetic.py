"""Synthetic street logs: the embedded default data of ``make demo`` and exact ground truth for tests.

A straight street is built as triangle meshes: a four-lane road with lane markings,
parking strips, curbs and sidewalks, buildings with gaps, poles, parked cars, moving
vehicles and a pedestrian. The ego drives along its lane and a 64-beam, 10 Hz spinning
LiDAR is rendered by ray casting (the same caster as the re-simulation:
``advsim_ros.core.lidar.render``). The log carries the tracks, the ego poses and a
vector map, and keeps the meshes so that any frame can be rendered again with actors at
other poses (the exact answer the re-simulation is checked against). Everything follows
from the random generator passed in: the same seed gives the same log.

World frame: x along the street, y to the left, z up, road surface at z = 0.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from advsim_ros.core.lidar.assets import template_surface
from advsim_ros.core.lidar.boxes import yaw_pose
from advsim_ros.core.lidar.raycast import PlacedSurface, Surface, SurfaceCaster, cuboid_surface
from advsim_ros.core.lidar.render import render_sweep
from advsim_ros.core.types import (
    ActorTrack,
    EgoTrajectory,
    FloatArray,
    RoadMap,
    Scenario,
    ScenarioError,
    SensorModel,
    Sweep,
)
from advsim_ros.io.bag import BagConfig, write_scenario_bag
from advsim_ros.io.synthetic_families import (
    CROSSING_HALF_WIDTH,
    LANE_WIDTH,
    ROAD_HALF_WIDTH,
    SIDEWALK_WIDTH,
    SceneLayout,
    crossing_of,
    scene_layout,
)

SYNTHETIC_START_NS = 1_000_000_000  # first frame at 1 s (ROS treats time 0 as unset)
SYNTHETIC_FRAME_PERIOD_NS = 100_000_000  # 10 Hz
SYNTHETIC_SENSOR_HEIGHT = 1.73  # LiDAR above the road [m]
SYNTHETIC_SENSOR_FRAME = "lidar"
CURB_HEIGHT = 0.15  # [m]
STREET_START, STREET_END = -60.0, 180.0  # extent of the street along x [m]
CROSS_STREET_HALF_LENGTH = 60.0  # the cross street of an intersection runs this far each way [m]


@dataclass(frozen=True)
class SyntheticConfig:
    """Size and sensor realism of a synthetic log; units beside each field."""

    duration: float = 8.0  # log length [s]
    ego_speed: float = 8.0  # [m/s]
    range_noise_std: float = 0.01  # Gaussian range noise of every return [m]
    ray_drop_probability: float = 0.0  # chance that a ray hitting anything returns nothing
    azimuth_resolution_deg: float = 0.2  # horizontal angle between firings [deg]
    parked_cars_per_side: int = 5
    family: str = "street"  # the staged interaction (io.synthetic_families.FAMILY_NAMES)

    def __post_init__(self) -> None:
        crossing_of(self.family)  # an unknown family is named here
        if not 0.5 <= self.duration <= 60.0:
            raise ScenarioError(f"SyntheticConfig duration: must lie in [0.5, 60] s, got {self.duration}")
        if not 0.0 <= self.ego_speed <= 20.0:
            raise ScenarioError(f"SyntheticConfig ego_speed: must lie in [0, 20] m/s, got {self.ego_speed}")
        if self.range_noise_std < 0.0:
            raise ScenarioError(f"SyntheticConfig range_noise_std: must be >= 0, got {self.range_noise_std}")
        if not 0.0 <= self.ray_drop_probability < 1.0:
            raise ScenarioError(
                f"SyntheticConfig ray_drop_probability: must lie in [0, 1), got {self.ray_drop_probability}"
            )
        if not 0.05 <= self.azimuth_resolution_deg <= 2.0:
            raise ScenarioError(
                f"SyntheticConfig azimuth_resolution_deg: must lie in [0.05, 2], got {self.azimuth_resolution_deg}"
            )
        if not 0 <= self.parked_cars_per_side <= 12:
            raise ScenarioError(
                f"SyntheticConfig parked_cars_per_side: must lie in [0, 12], got {self.parked_cars_per_side}"
            )

    @property
    def num_frames(self) -> int:
        return round(self.duration * 1e9 / SYNTHETIC_FRAME_PERIOD_NS)


def synthetic_sensor_model(config: SyntheticConfig) -> SensorModel:
    """A 64-beam spinning LiDAR shaped like the HDL-64E: +2 to -24.8 deg, 1 to 100 m."""
    return SensorModel(
        beam_elevations=np.deg2rad(np.linspace(2.0, -24.8, 64)),
        azimuth_resolution=float(np.deg2rad(config.azimuth_resolution_deg)),
        min_range=1.0,
        max_range=100.0,
    )


@dataclass(frozen=True, eq=False)
class SyntheticLog:
    """A synthetic log and the meshes it was rendered from."""

    scenario: Scenario  # sweeps, ego, actors, map, sensor model
    static_surface: Surface  # road, curbs, sidewalks, buildings, poles in the world frame
    actor_surfaces: dict[str, Surface]  # actor id -> its mesh in its box frame
    config: SyntheticConfig

    @property
    def sensor(self) -> SensorModel:
        assert self.scenario.sensor is not None
        return self.scenario.sensor

    def actor_poses_at(self, stamp_ns: int) -> dict[str, FloatArray]:
        """T_world_box (4, 4) of every actor at a frame stamp."""
        poses: dict[str, FloatArray] = {}
        for actor in self.scenario.actors:
            index = int(np.searchsorted(actor.stamps_ns, stamp_ns))
            if index < actor.stamps_ns.shape[0] and int(actor.stamps_ns[index]) == stamp_ns:
                poses[actor.actor_id] = yaw_pose(actor.centers[index], float(actor.yaws[index]))
        return poses

    def render(
        self, sensor_pose: FloatArray, actor_poses: Mapping[str, FloatArray], rng: np.random.Generator
    ) -> np.ndarray:
        """The sweep seen from `sensor_pose` (T_world_sensor) with actors at `actor_poses` (T_world_box)."""
        unknown = sorted(set(actor_poses) - set(self.actor_surfaces))
        if unknown:
            raise ScenarioError(f"synthetic render: unknown actors {unknown}")
        world = Surface.concatenate(
            [self.static_surface]
            + [self.actor_surfaces[actor_id].transformed(pose) for actor_id, pose in sorted(actor_poses.items())]
        )
        return render_sweep(
            self.sensor,
            sensor_pose,
            [PlacedSurface(SurfaceCaster(world))],
            rng=rng,
            range_noise_std=self.config.range_noise_std,
            drop_probabilities=[self.config.ray_drop_probability],
        )


def _quad(x0: float, x1: float, y0: float, y1: float, z: float, intensity: float) -> Surface:
    vertices = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]])
    return Surface(vertices=vertices, triangles=np.array([[0, 1, 2], [0, 2, 3]]), intensity=np.full(2, intensity))


def _outside(x0: float, x1: float, gap: tuple[float, float] | None) -> list[tuple[float, float]]:
    """[x0, x1] without the part inside ``gap`` (an intersection), as up to two intervals."""
    if gap is None:
        return [(x0, x1)]
    return [(a, b) for a, b in ((x0, min(x1, gap[0])), (max(x0, gap[1]), x1)) if b > a]


def _street_surface(rng: np.random.Generator, crossing_x: float | None = None) -> Surface:
    """Road with markings, parking strips, curbs, sidewalks, buildings and poles (world frame).

    With ``crossing_x`` a cross street (same width, along y) meets the street there: curbs,
    sidewalks, markings, buildings and poles leave it open (the random draws stay the same).
    """
    parts: list[Surface] = []
    gap = None
    if crossing_x is not None:
        gap = (crossing_x - CROSSING_HALF_WIDTH - SIDEWALK_WIDTH, crossing_x + CROSSING_HALF_WIDTH + SIDEWALK_WIDTH)
    tile = 20.0  # the road as tiles keeps triangles small enough for float32 precision
    for x0 in np.arange(STREET_START, STREET_END, tile):
        parts.append(_quad(x0, x0 + tile, -ROAD_HALF_WIDTH, ROAD_HALF_WIDTH, 0.0, 0.12))
    marking_z = 0.005
    for y in (-LANE_WIDTH, LANE_WIDTH):  # dashed lane separators
        for x0 in np.arange(STREET_START, STREET_END, 9.0):
            if gap is None or not gap[0] - 3.0 < x0 < gap[1]:
                parts.append(_quad(x0, x0 + 3.0, y - 0.075, y + 0.075, marking_z, 0.7))
    for y in (-0.1, 0.1):  # double centre line
        for a, b in _outside(STREET_START, STREET_END, gap):
            parts.append(_quad(a, b, y - 0.06, y + 0.06, marking_z, 0.7))
    for y in (-2 * LANE_WIDTH, 2 * LANE_WIDTH):  # parking strip edges
        for a, b in _outside(STREET_START, STREET_END, gap):
            parts.append(_quad(a, b, y - 0.075, y + 0.075, marking_z, 0.6))
    for side in (-1.0, 1.0):
        inner, outer = side * ROAD_HALF_WIDTH, side * (ROAD_HALF_WIDTH + SIDEWALK_WIDTH)
        low, high = min(inner, outer), max(inner, outer)
        for a, b in _outside(STREET_START, STREET_END, gap):
            parts.append(cuboid_surface([a, low, -0.3], [b, high, CURB_HEIGHT], 0.3))
        x = STREET_START
        while x < STREET_END:  # buildings with gaps
            length = float(rng.uniform(8.0, 25.0))
            depth = float(rng.uniform(6.0, 14.0))
            height = float(rng.uniform(5.0, 20.0))
            near_y = side * (ROAD_HALF_WIDTH + SIDEWALK_WIDTH)
            far_y = near_y + side * depth
            reflectivity = float(rng.uniform(0.2, 0.5))
            for a, b in _outside(x, min(x + length, STREET_END), gap):
                parts.append(
                    cuboid_surface([a, min(near_y, far_y), 0.0], [b, max(near_y, far_y), height], reflectivity)
                )
            x += length + float(rng.uniform(2.0, 7.0))
        for x_pole in np.arange(STREET_START + float(rng.uniform(0.0, 15.0)), STREET_END, 15.0):
            if gap is None or not gap[0] <= x_pole <= gap[1]:
                y_pole = side * (ROAD_HALF_WIDTH + 0.6)
                parts.append(
                    cuboid_surface([x_pole - 0.1, y_pole - 0.1, CURB_HEIGHT], [x_pole + 0.1, y_pole + 0.1, 4.5], 0.5)
                )
    if crossing_x is not None:
        parts.extend(_cross_street_surface(crossing_x))
    return Surface.concatenate(parts)


def _cross_street_surface(crossing_x: float) -> list[Surface]:
    """The cross street's road (tiles along y), centre line and sidewalks beyond the main street's."""
    parts: list[Surface] = []
    reach = CROSS_STREET_HALF_LENGTH
    for y0 in np.arange(-reach, reach, 20.0):
        parts.append(
            _quad(crossing_x - CROSSING_HALF_WIDTH, crossing_x + CROSSING_HALF_WIDTH, y0, y0 + 20.0, 0.0, 0.12)
        )
    kerb = ROAD_HALF_WIDTH + SIDEWALK_WIDTH
    for side in (-1.0, 1.0):
        x_in, x_out = (
            crossing_x + side * CROSSING_HALF_WIDTH,
            crossing_x + side * (CROSSING_HALF_WIDTH + SIDEWALK_WIDTH),
        )
        for y0, y1 in ((-reach, -kerb), (kerb, reach)):
            parts.append(cuboid_surface([min(x_in, x_out), y0, -0.3], [max(x_in, x_out), y1, CURB_HEIGHT], 0.3))
            parts.append(_quad(crossing_x - 0.06, crossing_x + 0.06, y0, y1, 0.005, 0.7))
    return parts


def _road_map(layout: SceneLayout) -> RoadMap:
    """Drivable area and lane centre lines (traffic keeps right) of the street and its cross street."""
    lanes = [
        np.array([[STREET_START, y], [STREET_END, y]]) if y < 0 else np.array([[STREET_END, y], [STREET_START, y]])
        for y in (-1.5 * LANE_WIDTH, -0.5 * LANE_WIDTH, 0.5 * LANE_WIDTH, 1.5 * LANE_WIDTH)
    ]
    areas = [_rectangle(STREET_START, STREET_END, -ROAD_HALF_WIDTH, ROAD_HALF_WIDTH)]
    if layout.crossing_x is not None:
        reach, x = CROSS_STREET_HALF_LENGTH, layout.crossing_x
        for offset in (-1.5 * LANE_WIDTH, -0.5 * LANE_WIDTH, 0.5 * LANE_WIDTH, 1.5 * LANE_WIDTH):
            ends = [[x + offset, -reach], [x + offset, reach]]  # east of the centre line northbound
            lanes.append(np.array(ends if offset > 0 else ends[::-1]))
        areas.append(_rectangle(x - CROSSING_HALF_WIDTH, x + CROSSING_HALF_WIDTH, -reach, reach))
    lanes.extend(layout.turn_lanes)
    return RoadMap(drivable_areas=tuple(areas), lane_centerlines=tuple(lanes))


def _rectangle(x0: float, x1: float, y0: float, y1: float) -> FloatArray:
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])


def generate_synthetic_log(
    rng: np.random.Generator, config: SyntheticConfig | None = None, scenario_id: str = "synthetic"
) -> SyntheticLog:
    """A synthetic street log of ``config.family`` drawn from `rng` (same generator state, same log)."""
    config = config or SyntheticConfig()
    sensor = synthetic_sensor_model(config)
    static = _street_surface(rng, crossing_of(config.family))
    count = config.num_frames
    stamps = SYNTHETIC_START_NS + SYNTHETIC_FRAME_PERIOD_NS * np.arange(count, dtype=np.int64)
    times = (stamps - stamps[0]) * 1e-9
    layout = scene_layout(config.family, rng, times, config.ego_speed, config.parked_cars_per_side)
    ego_poses = np.stack(
        [yaw_pose([x, y, 0.0], float(yaw)) for (x, y), yaw in zip(layout.ego_xy, layout.ego_yaw, strict=True)]
    )
    ego_T_sensor = yaw_pose([0.0, 0.0, SYNTHETIC_SENSOR_HEIGHT], 0.0)
    actors: list[ActorTrack] = []
    surfaces: dict[str, Surface] = {}
    for motion in layout.actors:
        size = np.asarray(motion.size)
        centers = np.column_stack([motion.xy, np.full(count, 0.5 * size[2])])
        actors.append(ActorTrack(motion.actor_id, motion.actor_class, size, stamps, centers, motion.yaw))
        surfaces[motion.actor_id] = template_surface(motion.actor_class, size, motion.intensity)
    unrendered = Scenario(
        scenario_id=scenario_id,
        frame_stamps_ns=stamps,
        ego=EgoTrajectory(stamps_ns=stamps, poses=ego_poses),
        actors=tuple(actors),
        ego_T_sensor=ego_T_sensor,
        sensor=sensor,
        road_map=_road_map(layout),
    )
    log = SyntheticLog(scenario=unrendered, static_surface=static, actor_surfaces=surfaces, config=config)
    sweeps = []
    for index, stamp in enumerate(stamps):
        sensor_pose = ego_poses[index] @ ego_T_sensor
        points = log.render(sensor_pose, log.actor_poses_at(int(stamp)), rng)
        sweeps.append(
            Sweep(stamp_ns=int(stamp), frame_id=SYNTHETIC_SENSOR_FRAME, points=points, sensor_pose=sensor_pose)
        )
    scenario = Scenario(
        scenario_id=scenario_id,
        frame_stamps_ns=stamps,
        ego=unrendered.ego,
        actors=unrendered.actors,
        sweeps=tuple(sweeps),
        ego_T_sensor=ego_T_sensor,
        sensor=sensor,
        road_map=unrendered.road_map,
    )
    return SyntheticLog(scenario=scenario, static_surface=static, actor_surfaces=surfaces, config=config)


def write_synthetic_bag(
    path: Path,
    *,
    seed: int,
    config: SyntheticConfig | None = None,
    bag_config: BagConfig | None = None,
    overwrite: bool = False,
) -> Path:
    """Generate the synthetic log of `seed` and write it as a scenario bag at `path` (atomically)."""
    config = config or SyntheticConfig()
    name = synthetic_name(config.family, seed)
    log = generate_synthetic_log(np.random.default_rng(seed), config, scenario_id=name)
    source = f"synthetic/{seed}" if config.family == "street" else f"synthetic/{config.family}/{seed}"
    return write_scenario_bag(log.scenario, path, config=bag_config, source=source, overwrite=overwrite)


def synthetic_name(family: str, seed: int) -> str:
    """The scenario id of a synthetic log (the street family keeps its original names)."""
    return f"synthetic_{seed}" if family == "street" else f"synthetic_{family}_{seed}"


__all__ = [
    "SYNTHETIC_FRAME_PERIOD_NS",
    "SYNTHETIC_START_NS",
    "SyntheticConfig",
    "SyntheticLog",
    "generate_synthetic_log",
    "synthetic_name",
    "synthetic_sensor_model",
    "write_synthetic_bag",
]
