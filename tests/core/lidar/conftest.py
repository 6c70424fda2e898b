"""Fixtures for the LiDAR re-simulation tests: a synthetic log with its meshes, and real KITTI 0000."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from advsim_ros.core.lidar.resim import ResimModel
from advsim_ros.core.types import Scenario
from advsim_ros.io.cache import cache_root
from advsim_ros.io.synthetic import SyntheticConfig, SyntheticLog, generate_synthetic_log

SYNTHETIC_SEED = 7


@pytest.fixture(scope="session")
def synthetic_log() -> SyntheticLog:
    """The default 8 s synthetic street log (seed 7): sweeps, tracks and the meshes they came from."""
    return generate_synthetic_log(np.random.default_rng(SYNTHETIC_SEED), SyntheticConfig(), "synthetic_7")


@pytest.fixture(scope="session")
def synthetic_model(synthetic_log: SyntheticLog, tmp_path_factory: pytest.TempPathFactory) -> ResimModel:
    """The re-simulation model built from the synthetic log's own sweeps (not from its meshes)."""
    return ResimModel.build(synthetic_log.scenario, tmp_path_factory.mktemp("resim_cache"))


@pytest.fixture(scope="session")
def short_log() -> SyntheticLog:
    """A 3 s synthetic log (seed 7): quick to build a model from, for the tests that need any model."""
    return generate_synthetic_log(np.random.default_rng(SYNTHETIC_SEED), SyntheticConfig(duration=3.0), "short_7")


@pytest.fixture(scope="session")
def short_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("short_resim_cache")


@pytest.fixture(scope="session")
def short_model(short_log: SyntheticLog, short_cache: Path) -> ResimModel:
    return ResimModel.build(short_log.scenario, short_cache)


@pytest.fixture(scope="session")
def kitti_model(kitti_scenario: Scenario) -> ResimModel:
    """KITTI 0000's model, cached where the lidar_resim node caches it (built once per machine)."""
    return ResimModel.build(kitti_scenario, cache_root() / "resim")
