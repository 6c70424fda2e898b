"""Settings of the LiDAR re-simulation (params/lidar_resim.yaml, key ``resim``)."""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path

from advsim_ros.core.params import config_from_mapping, load_node_params
from advsim_ros.core.types import ScenarioError

RESIM_PARAMS_KEY = "resim"


@dataclass(frozen=True)
class ResimConfig:
    """How the background, the actor assets and the merge are built; units beside each field."""

    box_margin: float = 0.1  # growth of actor boxes on every side when telling actor points from static ones [m]
    removal_margin: float = 0.2  # growth of an actor's box on every side when cutting it out of a sweep [m]
    ground_clearance: float = 0.05  # points this close to the ground around an actor are ground, not actor [m]
    background_voxel: float = 0.08  # background thinning grid [m]
    background_max_range: float = 60.0  # farther returns are left out of the background [m]
    background_sweep_stride: int = 1  # use every n-th sweep for the background
    carve_sweep_stride: int = 8  # every n-th sweep checks the background for things that moved away
    carve_range: float = 40.0  # surfels farther than this from a checking sweep's sensor get no vote [m]
    background_max_half_size: float = 0.25  # cap on a background surfel's half side [m]
    surfel_size_scale: float = 0.85  # surfel half side / local point spacing (0.75 leaves ~1 % of rays through a plane)
    ground_cell: float = 0.5  # ground height grid cell [m]
    ground_fill_radius: float = 3.0  # holes in the ground this close to seen ground get filled [m]
    ground_normal_min_z: float = 0.9  # surfels with |normal z| at least this are ground candidates
    asset_voxel: float = 0.04  # actor asset thinning grid [m]
    asset_max_half_size: float = 0.12  # cap on an asset surfel's half side [m]
    asset_min_points: int = 150  # fewer aggregated points than this: use the class template
    mirror_classes: tuple[str, ...] = ("vehicle", "cyclist")  # classes whose assets are mirrored left-right
    drop_estimate_frames: int = 20  # frames per track used to estimate its ray-drop probability
    default_drop_probability: float = 0.1  # ray drop of template assets when a class has no observed asset
    max_drop_probability: float = 0.8  # cap on an estimated ray-drop probability
    snap_to_ground: bool = True  # keep a moved actor's height above the background ground
    pose_tolerance: float = 0.01  # actors that moved less than this count as unchanged [m]
    yaw_tolerance: float = 0.001  # ... and turned less than this [rad]
    coverage_tolerance: float = 0.75  # a cell is served by a return this close to its centre [azimuth steps]
    window_margin: float = 0.01  # growth of an actor's angular window [rad]
    sweep_cache_size: int = 32  # sweeps whose per-point geometry is kept between calls

    def __post_init__(self) -> None:
        positive = (
            "background_voxel",
            "background_max_range",
            "carve_range",
            "background_max_half_size",
            "surfel_size_scale",
            "ground_cell",
            "asset_voxel",
            "asset_max_half_size",
            "pose_tolerance",
            "yaw_tolerance",
            "coverage_tolerance",
        )
        for name in positive:
            if not getattr(self, name) > 0:
                raise ScenarioError(f"ResimConfig {name}: must be positive, got {getattr(self, name)}")
        for name in ("box_margin", "removal_margin", "ground_clearance", "ground_fill_radius", "window_margin"):
            if not getattr(self, name) >= 0:
                raise ScenarioError(f"ResimConfig {name}: must be >= 0, got {getattr(self, name)}")
        for name in (
            "background_sweep_stride",
            "carve_sweep_stride",
            "asset_min_points",
            "drop_estimate_frames",
            "sweep_cache_size",
        ):
            if getattr(self, name) < 1:
                raise ScenarioError(f"ResimConfig {name}: must be >= 1, got {getattr(self, name)}")
        for name in ("ground_normal_min_z", "default_drop_probability", "max_drop_probability"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ScenarioError(f"ResimConfig {name}: must lie in [0, 1], got {getattr(self, name)}")
        if self.asset_max_half_size < 0.5 * self.asset_voxel:
            raise ScenarioError("ResimConfig asset_max_half_size: must be at least half of asset_voxel")
        if self.background_max_half_size < 0.5 * self.background_voxel:
            raise ScenarioError("ResimConfig background_max_half_size: must be at least half of background_voxel")
        known = {"vehicle", "pedestrian", "cyclist", "other"}
        unknown = sorted(set(self.mirror_classes) - known)
        if unknown:
            raise ScenarioError(f"ResimConfig mirror_classes: unknown classes {unknown} (known: {sorted(known)})")

    def model_key(self) -> str:
        """The settings that shape the built background and assets (the cache key part)."""
        skip = {"snap_to_ground", "pose_tolerance", "yaw_tolerance", "sweep_cache_size"}
        return ";".join(
            f"{field.name}={getattr(self, field.name)!r}" for field in fields(self) if field.name not in skip
        )


def load_resim_config(path: Path, *, node: str) -> ResimConfig:
    """The ``resim`` settings of node ``node`` (advsim_ros.graph names it) in a parameters file (missing keys keep
    their defaults)."""
    section = load_node_params(path, node).get(RESIM_PARAMS_KEY, {})
    return config_from_mapping(ResimConfig, section, f"{path} /{node} {RESIM_PARAMS_KEY}")


@dataclass(frozen=True)
class ResimNodeConfig:
    """/lidar_resim parameters besides the re-simulation settings (params/lidar_resim.yaml).

    Here, not in the node's module, so that `advsim attack` checks them without importing Open3D.
    """

    seed: int = 0  # ray-drop sampling: seeded from (seed, frame, the perturbed tracks' content)
    cache_dir: str = ""  # where the background and assets are cached; "" = <advsim cache>/resim
    build_model: bool = True  # build the model at start-up (off for `advsim replay`: nothing moves there)
    render_distance: float = 0.01  # closed loop: a sensor further than this from where it was logged is rendered [m]
    render_yaw: float = 0.001  # ... or turned more than this [rad]; nearer, the logged sweep is re-simulated
    # keep only the history frames' sweeps in memory (open loop requests no other frame; `advsim attack` sets it);
    # off, every sweep of the log is kept (closed loop re-simulates later frames and calibrates its rendering on them)
    history_sweeps_only: bool = False
