"""The attack graph, declared once: its nodes, where each runs and the parameter sections each reads.

Everything that lists the graph's nodes derives from this table: setup.py's console scripts, the
light-node container (nodes/container.py), the processes `advsim attack` starts (attack/run.py),
the pre-launch checks of every node's parameters (attack/checks.py) and the names that tell the
graph's own ROS nodes from the stack's (handed to ros/ as arguments). core/ keeps no node names.

Standard library only, with config classes named as ``"module:Class"`` and imported on use
(``resolve``): setup.py reads this file before the package's dependencies exist, and the light
nodes' process must not import lidar_resim's Open3D by reading it.

Adding a node or a parameter section: its entry here, and its node's file (which declares the
section through ``nodes.scenario_node.declare_section``).
"""

from __future__ import annotations

import enum
import importlib
from dataclasses import dataclass
from typing import Any


class Process(enum.Enum):
    CONTAINER = "graph_nodes"  # the light nodes share one process (nodes/container.py)
    OWN = "own"  # a process of its own: lidar_resim computes while the others wait
    ORCHESTRATOR = "orchestrator"  # inside `advsim attack` itself (the monitor)


class Role(enum.Enum):
    """Which graph a node is part of: an attack's first lane, a further evaluation lane, a replay."""

    SEARCH = "search"
    LANE = "lane"  # `advsim attack --lanes K`: the search is in the first lane's graph only
    REPLAY = "replay"


EVERY_ROLE = frozenset(Role)
# A section key standing for one section per search algorithm, named after it; its config names
# the function from an algorithm's name to its config class.
ALGORITHMS = "<algorithm>"


@dataclass(frozen=True)
class Section:
    """One parameter section of a node: ROS parameters ``<key>.<field>`` (the node's own fields for key "")."""

    key: str
    config: str  # "module:Class": the frozen dataclass the node builds from the section
    build: str = ""  # "module:function" (values, context) -> config, for a section that is more than its dataclass


@dataclass(frozen=True)
class Node:
    name: str  # its ROS node name and console script; params/<name>.yaml holds its parameters
    module: str  # its module: ``main`` runs it alone, ``node_class`` is built by the container ("" in none)
    node_class: str
    process: Process
    roles: frozenset[Role] = EVERY_ROLE
    sections: tuple[Section, ...] = ()  # none: configured by its starter alone, without params/ files
    on_demand: str = ""  # started only when this holds (the reason), not with every graph

    @property
    def entry_point(self) -> str:
        return f"{self.module}:main"

    def section(self, key: str) -> Section:
        for section in self.sections:
            if section.key == key:
                return section
        raise KeyError(f"/{self.name}: no parameter section {key!r} in advsim_ros.graph")


# Every node of one attack reads the same window and bag; the drivable area is the scorer's, as scored.
WINDOW = Section("window", "advsim_ros.core.episode:WindowConfig")
BAG = Section("bag", "advsim_ros.io.bag:BagConfig")
DRIVABLE = Section("drivable", "advsim_ros.core.drivable:DrivableConfig")

SCENARIO_PLAYER = Node(
    "scenario_player", "advsim_ros.nodes.scenario_player", "ScenarioPlayer", Process.CONTAINER,
    sections=(
        WINDOW, BAG,
        Section("", "advsim_ros.ros.lockstep:PlayerConfig"),
        Section("controller", "advsim_ros.core.closed_loop:ControllerConfig"),  # closed loop
        Section("reactive", "advsim_ros.core.reactive:IdmConfig"),  # closed loop, reactive actors
    ),
)  # fmt: skip
SCORER = Node(
    "scorer", "advsim_ros.nodes.scorer", "Scorer", Process.CONTAINER,
    sections=(
        WINDOW, BAG, DRIVABLE,
        # a preset (M0..M5, a baseline) besides the weights
        Section(
            "objective", "advsim_ros.core.objective:ObjectiveConfig", "advsim_ros.core.objective:objective_from_params"
        ),
        Section("metrics", "advsim_ros.core.metrics:MetricsConfig"),
    ),
)  # fmt: skip
PERTURBER = Node(
    "perturber", "advsim_ros.nodes.perturber", "Perturber", Process.CONTAINER,
    roles=frozenset({Role.SEARCH, Role.LANE}),
    sections=(WINDOW, BAG, DRIVABLE, Section("", "advsim_ros.core.feasibility:PerturberConfig")),
)  # fmt: skip
SEARCH = Node(
    "search", "advsim_ros.nodes.search", "SearchNode", Process.CONTAINER,
    roles=frozenset({Role.SEARCH}),
    sections=(
        Section("", "advsim_ros.core.search.driver:DriverConfig"),
        Section(ALGORITHMS, "advsim_ros.core.search.registry:config_type"),
    ),
)  # fmt: skip
LIDAR_RESIM = Node(
    "lidar_resim", "advsim_ros.nodes.lidar_resim", "LidarResim", Process.OWN,
    sections=(
        WINDOW, BAG,
        Section("", "advsim_ros.core.lidar.config:ResimNodeConfig"),
        Section("resim", "advsim_ros.core.lidar.config:ResimConfig"),
    ),
)  # fmt: skip
STACK_ADAPTER = Node(
    "stack_adapter", "advsim_ros.nodes.stack_adapter", "StackAdapter", Process.OWN,
    on_demand="a stack profile or --remap: the stack's own names, types, frames, timing",
)  # fmt: skip
MONITOR = Node("advsim_monitor", "", "", Process.ORCHESTRATOR)  # ros.monitor.AttackMonitor, one per lane

NODES = (SCENARIO_PLAYER, SCORER, PERTURBER, SEARCH, LIDAR_RESIM, STACK_ADAPTER, MONITOR)
# Every ROS node of the graph itself: every other node on an attack's domain belongs to the stack.
NAMES = frozenset(node.name for node in NODES)
CONFIGURED = tuple(node for node in NODES if node.sections)  # those reading params/<name>.yaml


def runnable() -> tuple[Node, ...]:
    """The nodes with a module of their own: a console script each, and the container can run them."""
    return tuple(node for node in NODES if node.module)


def started(role: Role, process: Process) -> tuple[Node, ...]:
    """The nodes of one role's graph that run in ``process`` and are started with every such graph."""
    return tuple(n for n in NODES if role in n.roles and n.process is process and not n.on_demand)


def resolve(reference: str) -> Any:
    """The object a ``"module:attribute"`` reference names (imported now)."""
    module, _, attribute = reference.partition(":")
    return getattr(importlib.import_module(module), attribute)
