"""Actor assets: each track's surface in its box frame, built from the log or a class template.

An observed asset aggregates the track's points over the whole log in its box frame
(vehicles and cyclists mirrored left-right: one side seen is both sides known) and turns
them into surfels. Tracks with too few points use a class template: a few cuboids shaped
like the class (also the meshes of the synthetic logs' actors). Every asset carries the
probability that a ray hitting it returns nothing (dark paint, glass), estimated from the
log by comparing the asset's hits at the logged poses with the returns the sensor got.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from advsim_ros.core.lidar.config import ResimConfig
from advsim_ros.core.lidar.raycast import Surface, cuboid_surface
from advsim_ros.core.lidar.surfels import PointSamples, SurfelCloud, surfels_from_samples
from advsim_ros.core.types import ActorClass, FloatArray, Scenario, ScenarioError

if TYPE_CHECKING:  # a type only: log_points imports nothing of assets (core.lidar.alignment aligns its frames)
    from advsim_ros.core.lidar.log_points import LogPoints

# Template parts per class as fractions of (length, width, height), box frame with z from -1/2 to 1/2.
_TEMPLATE_PARTS: dict[ActorClass, tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...]] = {
    ActorClass.VEHICLE: (
        ((-0.5, -0.5, -0.38), (0.5, 0.5, 0.1)),  # body
        ((-0.36, -0.44, 0.1), (0.22, 0.44, 0.5)),  # cabin
        ((0.24, -0.48, -0.5), (0.40, 0.48, -0.38)),  # front wheels
        ((-0.40, -0.48, -0.5), (-0.24, 0.48, -0.38)),  # rear wheels
    ),
    ActorClass.PEDESTRIAN: (
        ((-0.25, -0.35, -0.5), (0.25, 0.35, 0.36)),  # legs and torso
        ((-0.18, -0.2, 0.36), (0.18, 0.2, 0.5)),  # head
    ),
    ActorClass.CYCLIST: (
        ((-0.5, -0.08, -0.5), (0.5, 0.08, -0.05)),  # bicycle
        ((-0.22, -0.4, -0.15), (0.12, 0.4, 0.5)),  # rider
    ),
    ActorClass.OTHER: (((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5)),),
}


def template_surface(actor_class: ActorClass, size: FloatArray, intensity: float) -> Surface:
    """A class-shaped surface filling a box of `size` (3,) l, w, h [m], in the box frame."""
    scale = np.asarray(size, dtype=np.float64)
    parts = _TEMPLATE_PARTS[ActorClass(actor_class)]
    return Surface.concatenate(
        [cuboid_surface(np.array(lower) * scale, np.array(upper) * scale, intensity) for lower, upper in parts]
    )


@dataclass(frozen=True, eq=False)
class ActorAsset:
    """One actor's surface in its box frame and its ray-drop probability."""

    actor_id: str
    actor_class: ActorClass
    size: FloatArray  # (3,) box length, width, height [m]
    surfels: SurfelCloud  # box frame; empty for a template asset
    template_intensity: float  # intensity of the template surface (used when surfels is empty)
    drop_probability: float  # chance that a ray stopped by the asset returns nothing
    num_points: int  # points aggregated from the log (before mirroring)
    pass_probability: FloatArray | None = None  # (S,) chance that a ray crosses each surfel (glass); None: opaque

    def __post_init__(self) -> None:
        if not 0.0 <= self.drop_probability <= 1.0:
            raise ScenarioError(f"ActorAsset {self.actor_id}: drop_probability must lie in [0, 1]")
        object.__setattr__(self, "actor_class", ActorClass(self.actor_class))
        if self.pass_probability is not None:
            passing = np.asarray(self.pass_probability, dtype=np.float64)
            if passing.shape != (self.surfels.count,) or np.any((passing < 0.0) | (passing > 1.0)):
                raise ScenarioError(
                    f"ActorAsset {self.actor_id}: pass_probability needs one value in [0, 1] per surfel"
                )
            object.__setattr__(self, "pass_probability", passing)

    @property
    def is_template(self) -> bool:
        return self.surfels.count == 0

    def surface(self) -> Surface:
        if self.is_template:
            return template_surface(self.actor_class, self.size, self.template_intensity)
        return self.surfels.surface()

    def with_optics(self, drop_probability: float, pass_probability: FloatArray | None) -> ActorAsset:
        """The asset with its ray drop and per-surfel pass probabilities set."""
        return dataclasses.replace(self, drop_probability=drop_probability, pass_probability=pass_probability)


def build_asset(
    actor_id: str,
    actor_class: ActorClass,
    size: FloatArray,
    samples: PointSamples,
    *,
    mirror: bool,
    voxel_size: float,
    size_scale: float,
    max_half_size: float,
    min_points: int,
    template_intensity: float,
) -> ActorAsset:
    """An asset from the track's aggregated box-frame samples; the class template below `min_points` points."""
    count = round(float(samples.weight.sum()))
    if count < min_points:
        surfels = SurfelCloud.empty()
    else:
        if mirror:
            samples = PointSamples.concatenate([samples, samples.mirrored_y()])
        surfels = surfels_from_samples(samples, voxel_size, size_scale, max_half_size)
    return ActorAsset(
        actor_id=actor_id,
        actor_class=actor_class,
        size=np.asarray(size, dtype=np.float64),
        surfels=surfels,
        template_intensity=template_intensity,
        drop_probability=0.0,
        num_points=count,
    )


def build_assets(scenario: Scenario, log_points: LogPoints, config: ResimConfig) -> dict[str, ActorAsset]:
    """One asset per track: observed where it has enough points, the class template otherwise."""
    every = np.concatenate([values for values in log_points.actor_intensity.values()] + [np.zeros(0)])
    fallback = float(np.median(every)) if every.size else float(np.median(log_points.background.intensity))
    by_class: dict[ActorClass, list[FloatArray]] = {}
    for actor in scenario.actors:
        by_class.setdefault(actor.actor_class, []).append(log_points.actor_intensity[actor.actor_id])
    class_intensity = {
        actor_class: float(np.median(np.concatenate(values))) if sum(v.size for v in values) else fallback
        for actor_class, values in by_class.items()
    }
    assets: dict[str, ActorAsset] = {}
    for actor in scenario.actors:
        assets[actor.actor_id] = build_asset(
            actor.actor_id,
            actor.actor_class,
            actor.size,
            log_points.actors[actor.actor_id],
            mirror=actor.actor_class.value in config.mirror_classes,
            voxel_size=config.asset_voxel,
            size_scale=config.surfel_size_scale,
            max_half_size=config.asset_max_half_size,
            min_points=config.asset_min_points,
            template_intensity=class_intensity[actor.actor_class],
        )
    return assets
