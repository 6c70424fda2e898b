"""The base of the graph's nodes: a GraphNode that knows the attack's window and loads its scenario."""

from __future__ import annotations

from pathlib import Path

from advsim_ros.core.drivable import DrivableConfig
from advsim_ros.core.episode import EpisodeClock, WindowConfig
from advsim_ros.core.types import DrivableArea, Scenario, ScenarioError
from advsim_ros.io.bag import BagConfig, read_scenario_bag
from advsim_ros.io.drivable_cache import bag_drivable_area
from advsim_ros.ros.graph_node import GraphNode
from advsim_ros.ros.params import declare_config


class ScenarioNode(GraphNode):
    """Every node of one attack gets the same window.* and bag.* parameters."""

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.window = declare_config(self, WindowConfig, "window.")
        self.bag_config = declare_config(self, BagConfig, "bag.")

    def drivable_area(self, scenario: Scenario) -> DrivableArea:
        """The one drivable raster of the attack (params/drivable.yaml), estimated once per log and cached."""
        config = declare_config(self, DrivableConfig, "drivable.")
        return bag_drivable_area(Path(self.window.scenario_bag), scenario, config, self.bag_config)

    def load_scenario(self, *, load_sweeps: bool) -> tuple[Scenario, EpisodeClock]:
        """The window's scenario from the bag, and the episode clock all nodes share."""
        if not self.window.scenario_bag:
            raise ScenarioError(f"/{self.get_name()}: parameter window.scenario_bag is not set")
        scenario = read_scenario_bag(Path(self.window.scenario_bag), config=self.bag_config, load_sweeps=load_sweeps)
        return scenario, self.window.clock(scenario.frame_stamps_ns.tolist())
