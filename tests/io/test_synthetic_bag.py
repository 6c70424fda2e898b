"""Synthetic logs survive the scenario -> bag -> scenario round trip exactly (the generator is io/synthetic.py)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from advsim_ros.core.types import Scenario
from advsim_ros.io.bag import BagConfig, read_scenario_bag, write_scenario_bag
from advsim_ros.io.synthetic import SyntheticConfig, generate_synthetic_log


def test_a_synthetic_log_round_trips_through_mcap_and_sqlite3_bags(
    tmp_path: Path, scenarios_equal: Callable[[Scenario, Scenario], None]
) -> None:
    scenario = generate_synthetic_log(np.random.default_rng(3), SyntheticConfig(duration=1.0)).scenario
    assert len(scenario.sweeps) == 10  # the log has everything a bag carries: sweeps, map, sensor model
    assert scenario.road_map is not None
    assert scenario.sensor is not None
    for storage in ("mcap", "sqlite3"):
        bag = write_scenario_bag(scenario, tmp_path / storage, config=BagConfig(storage=storage), source="synthetic/3")
        scenarios_equal(read_scenario_bag(bag), scenario)
