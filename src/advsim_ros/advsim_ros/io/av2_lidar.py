"""Simulated LiDAR for Argoverse 2 logs: the logs' real tracks, poses and maps, rendered 10 Hz sweeps.

The AV2 logs here have real traffic and HD maps but only 1-2 real sweeps (or none), so
``advsim convert av2 LOG --lidar simulate`` renders a sweep for every annotated frame by ray
casting (``core.lidar.render.render_sweep``, Open3D / Embree) against a scene built from the log:

- ground: the map's ground-height raster (``map/*_ground_height_surface____*.npy``, 0.3 m cells
  placed in the city frame by ``*___img_Sim2_city.json``), resampled to ``ground_cell`` and
  triangulated around the ego's path; cells the raster leaves empty take the nearest value;
- curbs: every drivable-area outline as a vertical strip ``curb_height`` high;
- actors: every labelled actor at its labelled pose as its class template
  (``core.lidar.assets.template_surface``: body + cabin + wheels for vehicles, ...), sized to its box.

Sensor model (documented in docs/data.md): AV2's roof LiDARs are two VLP-32C, one upright
and one upside down, stacked at about 1.6 m (calibration ``up_lidar`` / ``down_lidar``); they
are rendered as one 10 Hz spinning sensor at the upper one's mount whose beams are the union of
the VLP-32C's elevation table and its mirror image (what the flipped unit sees), 0.2 deg
azimuth steps, 0.5..200 m. Ray drop (a chance per hit, per surface kind) and Gaussian range
noise make the returns less perfect. Buildings, vegetation, poles and parked objects the map
does not hold are absent: the LiDAR is SIMULATED, and the bag says so in ScenarioInfo.source.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from advsim_ros.core.lidar.assets import template_surface
from advsim_ros.core.lidar.boxes import yaw_pose
from advsim_ros.core.lidar.raycast import PlacedSurface, Surface, SurfaceCaster
from advsim_ros.core.lidar.render import render_sweep
from advsim_ros.core.types import ActorClass, FloatArray, Scenario, ScenarioError, SensorModel, Sweep
from advsim_ros.io.av2 import Av2Error

# Velodyne VLP-32C (Ultra Puck) beam elevations [deg], from its manual.
VLP32C_ELEVATIONS_DEG = (
    -25.0, -15.639, -11.31, -8.843, -7.254, -6.148, -5.333, -4.667, -4.0, -3.667, -3.333, -3.0, -2.667, -2.333,
    -2.0, -1.667, -1.333, -1.0, -0.667, -0.333, 0.0, 0.333, 0.667, 1.0, 1.333, 1.667, 2.333, 3.333, 4.667, 7.0,
    10.333, 15.0,
)  # fmt: skip
AV2_UP_LIDAR_MOUNT = (1.35, 0.0, 1.64)  # up_lidar in the egovehicle frame (calibration of the fleet's cars) [m]
SIMULATED_SENSOR_FRAME = "lidar_simulated"
SIMULATED_SOURCE_NOTE = (
    "LiDAR SIMULATED: ray-cast 2x VLP-32C model of the map's ground surface, drivable-area curbs and the "
    "labelled actors as class templates; tracks, ego poses and map are the log's real ones"
)


def simulated_vlp32c_pair() -> SensorModel:
    """Two stacked VLP-32C (one upside down) as one sensor: the union of both elevation tables, 0.2 deg, 10 Hz."""
    table = np.array(VLP32C_ELEVATIONS_DEG)
    elevations = np.unique(np.round(np.concatenate([table, -table]), 3))[::-1]
    return SensorModel(
        beam_elevations=np.deg2rad(elevations),
        azimuth_resolution=float(np.deg2rad(0.2)),
        min_range=0.5,
        max_range=200.0,
    )


@dataclass(frozen=True)
class Av2LidarConfig:
    """Scene and sensor realism of the simulated sweeps; units beside each field."""

    ground_cell: float = 1.0  # ground mesh cell edge [m]
    margin: float = 80.0  # ground is built this far around the ego's path [m]
    curb_height: float = 0.15  # [m]
    range_noise_std: float = 0.02  # Gaussian range noise [m] (VLP-32C: +-3 cm typical accuracy)
    ground_drop: float = 0.05  # chance that a ray hitting the road returns nothing
    curb_drop: float = 0.05
    actor_drop: float = 0.1  # dark paint and glass return less
    intensities: tuple[float, ...] = (8.0, 20.0, 30.0)  # ground, curb, actor (AV2's 0..255 scale)

    def __post_init__(self) -> None:
        if not self.ground_cell > 0 or not self.margin > 0 or not self.curb_height > 0:
            raise ScenarioError("Av2LidarConfig: ground_cell, margin and curb_height must be positive")
        if self.range_noise_std < 0:
            raise ScenarioError("Av2LidarConfig range_noise_std: must be >= 0")
        for name in ("ground_drop", "curb_drop", "actor_drop"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise ScenarioError(f"Av2LidarConfig {name}: must lie in [0, 1)")
        if len(self.intensities) != 3:
            raise ScenarioError("Av2LidarConfig intensities: expected [ground, curb, actor]")


@dataclass(frozen=True, eq=False)
class GroundRaster:
    """The map's ground height: heights[row, col] at city (x, y) with (col, row) = scale * ((x, y) + offset)."""

    heights: FloatArray  # (R, C) [m], NaN where the map has none
    scale: float  # raster cells per metre [1/m]
    offset: FloatArray  # (2,) [m]

    def height_at(self, xy: FloatArray) -> FloatArray:
        """Ground height [m] at city xy (N, 2), nearest cell, clamped to the raster."""
        cells = np.round(self.scale * (xy + self.offset)).astype(np.int64)
        rows, columns = self.heights.shape
        result: FloatArray = self.heights[np.clip(cells[:, 1], 0, rows - 1), np.clip(cells[:, 0], 0, columns - 1)]
        return result


def load_ground_raster(log_dir: Path) -> GroundRaster:
    """The log's ground-height raster with its empty cells filled from the nearest valid one."""
    map_dir = Path(log_dir) / "map"
    arrays = sorted(map_dir.glob("*_ground_height_surface____*.npy"))
    transforms = sorted(map_dir.glob("*___img_Sim2_city.json"))
    if not arrays or not transforms:
        raise Av2Error(f"{map_dir}: no ground-height raster (*_ground_height_surface____*.npy, *___img_Sim2_city.json)")
    try:
        heights = np.load(arrays[0]).astype(np.float64)
        sim2 = json.loads(transforms[0].read_text(encoding="utf-8"))
        rotation = np.array(sim2["R"], dtype=np.float64).reshape(2, 2)
        offset = np.array(sim2["t"], dtype=np.float64)
        scale = float(sim2["s"])
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise Av2Error(f"{map_dir}: unreadable ground-height raster or Sim2 ({error})") from None
    if heights.ndim != 2 or not np.allclose(rotation, np.eye(2)) or not scale > 0:
        raise Av2Error(f"{map_dir}: expected a 2-D raster and an axis-aligned Sim2, got {heights.shape}, R={rotation}")
    valid = np.isfinite(heights)
    if not valid.any():
        raise Av2Error(f"{arrays[0]}: the ground-height raster holds no values")
    nearest = ndimage.distance_transform_edt(~valid, return_distances=False, return_indices=True)
    return GroundRaster(heights=heights[nearest[0], nearest[1]], scale=scale, offset=offset)


def ground_surface(raster: GroundRaster, low: FloatArray, high: FloatArray, cell: float, intensity: float) -> Surface:
    """A height-field mesh of the ground over the city box low..high (2,) [m]."""
    xs = np.arange(low[0], high[0] + cell, cell)
    ys = np.arange(low[1], high[1] + cell, cell)
    grid_x, grid_y = np.meshgrid(xs, ys)
    xy = np.column_stack([grid_x.ravel(), grid_y.ravel()])
    vertices = np.column_stack([xy, raster.height_at(xy)])
    columns = xs.shape[0]
    corner = (np.arange(ys.shape[0] - 1)[:, None] * columns + np.arange(columns - 1)[None, :]).ravel()
    triangles = np.concatenate(
        [np.column_stack([corner, corner + 1, corner + columns + 1]), np.column_stack([corner, corner + columns + 1,
                                                                                       corner + columns])]
    )  # fmt: skip
    return Surface(vertices=vertices, triangles=triangles, intensity=np.full(triangles.shape[0], intensity))


def curb_surface(outlines: tuple[FloatArray, ...], raster: GroundRaster, height: float, intensity: float) -> Surface:
    """Each closed outline (K, 2) as a vertical strip from the ground up by ``height`` [m]."""
    parts = []
    for outline in outlines:
        start = outline
        end = np.roll(outline, -1, axis=0)
        base_start, base_end = raster.height_at(start), raster.height_at(end)
        count = start.shape[0]
        vertices = np.concatenate(
            [
                np.column_stack([start, base_start]),
                np.column_stack([end, base_end]),
                np.column_stack([end, base_end + height]),
                np.column_stack([start, base_start + height]),
            ]
        )
        index = np.arange(count)
        quads = np.column_stack([index, index + count, index + 2 * count, index + 3 * count])
        triangles = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
        parts.append(Surface(vertices=vertices, triangles=triangles, intensity=np.full(triangles.shape[0], intensity)))
    if not parts:
        return Surface(vertices=np.zeros((0, 3)), triangles=np.zeros((0, 3), dtype=np.int64), intensity=np.zeros(0))
    return Surface.concatenate(parts)


def _actors_at(scenario: Scenario, stamp: int, intensity: float) -> Surface:
    parts = []
    for actor in scenario.actors:
        row = int(np.searchsorted(actor.stamps_ns, stamp))
        if row < actor.stamps_ns.shape[0] and int(actor.stamps_ns[row]) == stamp:
            template = template_surface(ActorClass(actor.actor_class), actor.size, intensity)
            parts.append(template.transformed(yaw_pose(actor.centers[row], float(actor.yaws[row]))))
    if not parts:
        return Surface(vertices=np.zeros((0, 3)), triangles=np.zeros((0, 3), dtype=np.int64), intensity=np.zeros(0))
    return Surface.concatenate(parts)


def simulate_av2_lidar(
    scenario: Scenario,
    log_dir: Path,
    rng: np.random.Generator,
    config: Av2LidarConfig | None = None,
    stamps: Collection[int] | None = None,
) -> Scenario:
    """The AV2 scenario with a simulated sweep at every frame (or at ``stamps`` only), replacing any real ones."""
    config = config or Av2LidarConfig()
    if scenario.road_map is None:
        raise Av2Error(f"{log_dir}: the simulated LiDAR needs the log's map")
    raster = load_ground_raster(log_dir)
    sensor = simulated_vlp32c_pair()
    ego_T_sensor = np.eye(4)
    ego_T_sensor[:3, 3] = AV2_UP_LIDAR_MOUNT
    path = scenario.ego.poses[:, :2, 3]
    low, high = path.min(axis=0) - config.margin, path.max(axis=0) + config.margin
    ground_intensity, curb_intensity, actor_intensity = config.intensities
    static = [
        PlacedSurface(SurfaceCaster(ground_surface(raster, low, high, config.ground_cell, ground_intensity))),
        PlacedSurface(
            SurfaceCaster(curb_surface(scenario.road_map.drivable_areas, raster, config.curb_height, curb_intensity))
        ),
    ]
    drops = (config.ground_drop, config.curb_drop, config.actor_drop)
    sweeps = []
    for index, stamp in enumerate(scenario.frame_stamps_ns.tolist()):
        if stamps is not None and stamp not in stamps:
            continue
        sensor_pose = scenario.ego.poses[index] @ ego_T_sensor
        actors = PlacedSurface(SurfaceCaster(_actors_at(scenario, stamp, actor_intensity)))
        points = render_sweep(
            sensor, sensor_pose, [*static, actors], rng=rng, range_noise_std=config.range_noise_std,
            drop_probabilities=drops,
        )  # fmt: skip
        sweeps.append(Sweep(stamp_ns=stamp, frame_id=SIMULATED_SENSOR_FRAME, points=points, sensor_pose=sensor_pose))
    return dataclasses.replace(
        scenario, sweeps=tuple(sweeps), ego_T_sensor=ego_T_sensor, sensor=sensor, sensor_frame=""
    )


@dataclass(frozen=True)
class RealSweepComparison:
    """A simulated sweep against the real one of the same frame (both in the world frame)."""

    stamp_ns: int
    real_points: int
    simulated_points: int
    actors_compared: int  # actors with >= min_points real returns in their box
    median_count_ratio: float  # median over those actors of simulated / real returns in the box [1]
    chamfer_m: float  # symmetric mean nearest-neighbour distance within ``radius`` of the sensor [m]
    actor_chamfer_m: float  # the same over the returns inside actor boxes only [m]


def _world_points(sweep: Sweep) -> FloatArray:
    xyz = sweep.xyz
    result: FloatArray = xyz @ sweep.sensor_pose[:3, :3].T + sweep.sensor_pose[:3, 3]
    return result


def _chamfer(a: FloatArray, b: FloatArray) -> float:
    if a.shape[0] == 0 or b.shape[0] == 0:
        return float("nan")
    return 0.5 * float(cKDTree(b).query(a)[0].mean() + cKDTree(a).query(b)[0].mean())


def compare_with_real(
    real: Scenario, simulated: Scenario, radius: float = 50.0, min_points: int = 20
) -> list[RealSweepComparison]:
    """Per real sweep: per-actor return counts and Chamfer distances of the simulated sweep of that frame."""
    simulated_at = {sweep.stamp_ns: sweep for sweep in simulated.sweeps}
    results = []
    for sweep in real.sweeps:
        twin = simulated_at.get(sweep.stamp_ns)
        if twin is None:
            continue
        real_xyz, sim_xyz = _world_points(sweep), _world_points(twin)
        centre = sweep.sensor_pose[:3, 3]
        real_near = real_xyz[np.linalg.norm(real_xyz[:, :2] - centre[:2], axis=1) <= radius]
        sim_near = sim_xyz[np.linalg.norm(sim_xyz[:, :2] - centre[:2], axis=1) <= radius]
        ratios = []
        real_in_actors, sim_in_actors = [], []
        real_tree, sim_tree = cKDTree(real_near[:, :2]), cKDTree(sim_near[:, :2])
        for actor in real.actors:
            row = int(np.searchsorted(actor.stamps_ns, sweep.stamp_ns))
            if row >= actor.stamps_ns.shape[0] or int(actor.stamps_ns[row]) != sweep.stamp_ns:
                continue
            box_T_world = np.linalg.inv(yaw_pose(actor.centers[row], float(actor.yaws[row])))
            half = 0.5 * actor.size + 0.1  # a margin for the float16 coordinates and the labels
            reach = float(np.hypot(half[0], half[1]))
            inside = []
            for points, tree in ((real_near, real_tree), (sim_near, sim_tree)):
                near = points[tree.query_ball_point(actor.centers[row, :2], reach)]
                local = near @ box_T_world[:3, :3].T + box_T_world[:3, 3]
                inside.append(near[np.all(np.abs(local) <= half, axis=1)])
            real_in_actors.append(inside[0])
            sim_in_actors.append(inside[1])
            if inside[0].shape[0] >= min_points:
                ratios.append(inside[1].shape[0] / inside[0].shape[0])
        results.append(
            RealSweepComparison(
                stamp_ns=sweep.stamp_ns,
                real_points=sweep.num_points,
                simulated_points=twin.num_points,
                actors_compared=len(ratios),
                median_count_ratio=float(np.median(ratios)) if ratios else float("nan"),
                chamfer_m=_chamfer(real_near, sim_near),
                actor_chamfer_m=_chamfer(
                    np.concatenate(real_in_actors) if real_in_actors else np.zeros((0, 3)),
                    np.concatenate(sim_in_actors) if sim_in_actors else np.zeros((0, 3)),
                ),
            )
        )
    return results
