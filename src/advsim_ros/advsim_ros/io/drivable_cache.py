"""The drivable area of a scenario bag, estimated once per log and kept in the cache.

Estimating it for a log without a map reads LiDAR sweeps of the whole log (core.drivable); the
perturber and the scorer of every attack on that log need the same raster, so it is computed once,
stored under <advsim cache>/drivable keyed by the bag's metadata and the settings, and read back
(a few milliseconds) afterwards — the nodes then never load the log's sweeps for it.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from advsim_ros.core.atomic import atomic_file
from advsim_ros.core.digest import Digest
from advsim_ros.core.drivable import DrivableConfig, drivable_area_for
from advsim_ros.core.types import DrivableArea, EgoGeometry, Scenario
from advsim_ros.io.bag import BagConfig, read_scenario_bag
from advsim_ros.io.cache import cache_root

CACHE_VERSION = "drivable-1"


def _key(bag: Path, config: DrivableConfig, bag_config: BagConfig, ego: EgoGeometry) -> str:
    digest = Digest(CACHE_VERSION)
    digest.raw((Path(bag) / "metadata.yaml").read_bytes())
    digest.text(json.dumps(dataclasses.asdict(config), sort_keys=True))
    digest.text(json.dumps(dataclasses.asdict(bag_config), sort_keys=True))
    digest.array(ego.size)
    digest.text(repr(ego.forward_offset))
    return digest.hexdigest()


def bag_drivable_area(
    bag: Path, scenario: Scenario, config: DrivableConfig, bag_config: BagConfig, cache_dir: Path | None = None
) -> DrivableArea:
    """The drivable area of ``scenario`` (read from ``bag`` without sweeps): stored, from its map, or cached."""
    if scenario.drivable_area is not None or (scenario.road_map is not None and scenario.road_map.drivable_areas):
        return drivable_area_for(scenario, config)
    folder = cache_dir or cache_root() / "drivable"
    path = folder / f"{_key(bag, config, bag_config, scenario.ego_geometry)}.npz"
    if path.is_file():
        with np.load(path, allow_pickle=False) as stored:
            return DrivableArea(stored["origin"], float(stored["resolution"]), stored["mask"], str(stored["source"]))
    with_sweeps = read_scenario_bag(Path(bag), config=bag_config, load_sweeps=True)
    area = drivable_area_for(with_sweeps, config)
    with atomic_file(path, "wb") as stream:
        np.savez(stream, origin=area.origin, resolution=area.resolution, mask=area.mask, source=area.source)
    return area
