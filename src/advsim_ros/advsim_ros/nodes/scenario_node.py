"""The base of the graph's nodes: a GraphNode that knows the attack's window and loads its scenario."""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

from rclpy.node import Node

from advsim_ros import graph
from advsim_ros.core.drivable import DrivableConfig
from advsim_ros.core.episode import EpisodeClock, WindowConfig
from advsim_ros.core.types import DrivableArea, Scenario, ScenarioError
from advsim_ros.io.bag import BagConfig, read_scenario_bag
from advsim_ros.io.drivable_cache import bag_drivable_area
from advsim_ros.ros.graph_node import GraphNode
from advsim_ros.ros.params import declare_config

ConfigT = TypeVar("ConfigT")


def declare_section(node: Node, spec: graph.Node, key: str, config_type: type[ConfigT]) -> ConfigT:
    """Declare section ``key`` of the node's entry in advsim_ros.graph as ROS parameters and build its config.

    The entry names the config class, so a node cannot read a section the pre-launch checks do not know.
    """
    declared = graph.resolve(spec.section(key).config)
    if declared is not config_type:
        raise TypeError(f"/{spec.name} {key}: advsim_ros.graph declares {declared}, the node builds {config_type}")
    return declare_config(node, config_type, f"{key}." if key else "")


class ScenarioNode(GraphNode):
    """Every node of one attack gets the same window.* and bag.* parameters."""

    def __init__(self, spec: graph.Node) -> None:
        super().__init__(spec.name)
        self.spec = spec
        self.window = self.declare_section(graph.WINDOW.key, WindowConfig)
        self.bag_config = self.declare_section(graph.BAG.key, BagConfig)

    def declare_section(self, key: str, config_type: type[ConfigT]) -> ConfigT:
        return declare_section(self, self.spec, key, config_type)

    def drivable_area(self, scenario: Scenario) -> DrivableArea:
        """The one drivable raster of the attack (params/drivable.yaml), estimated once per log and cached."""
        config = self.declare_section(graph.DRIVABLE.key, DrivableConfig)
        return bag_drivable_area(Path(self.window.scenario_bag), scenario, config, self.bag_config)

    def load_scenario(self, *, load_sweeps: bool) -> tuple[Scenario, EpisodeClock]:
        """The window's scenario from the bag, and the episode clock all nodes share."""
        if not self.window.scenario_bag:
            raise ScenarioError(f"/{self.get_name()}: parameter window.scenario_bag is not set")
        scenario = read_scenario_bag(Path(self.window.scenario_bag), config=self.bag_config, load_sweeps=load_sweeps)
        return scenario, self.window.clock(scenario.frame_stamps_ns.tolist())
