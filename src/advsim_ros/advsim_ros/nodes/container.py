"""graph_nodes: several of the graph's nodes in one process (a ROS 2 component container, rclpy style).

    python -m advsim_ros.nodes.container scenario_player scorer perturber search --ros-args --params-file ...

Each node keeps its own name, parameters (``/<node>:`` sections of the parameter files) and
topics; only the interpreter is shared. `advsim attack` runs the light nodes this way and
lidar_resim, which computes while the others wait, in a process of its own.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable

from rclpy.node import Node

from advsim_ros import graph
from advsim_ros.ros.graph_node import run_nodes

# Each node's module is imported only when the node is run here: lidar_resim's alone would
# bring Open3D (about 170 MB resident) into a process that never casts a ray.
_MODULES = {node.name: (node.module, node.node_class) for node in graph.runnable()}


def _factory(name: str) -> Callable[[], Node]:
    module, attribute = _MODULES[name]
    factory: Callable[[], Node] = getattr(importlib.import_module(module), attribute)
    return factory


def main() -> None:
    arguments = sys.argv[1 : sys.argv.index("--ros-args")] if "--ros-args" in sys.argv else sys.argv[1:]
    unknown = [name for name in arguments if name not in _MODULES]
    if not arguments or unknown:
        print(f"{sys.argv[0]}: name the nodes to run, from {', '.join(_MODULES)} (got {arguments})", file=sys.stderr)
        sys.exit(2)
    run_nodes([_factory(name) for name in arguments])


if __name__ == "__main__":
    main()
