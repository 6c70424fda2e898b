"""graph_nodes: several of the graph's nodes in one process (a ROS 2 component container, rclpy style).

    python -m advsim_ros.nodes.container scenario_player scorer perturber search --ros-args --params-file ...

Each node keeps its own name, parameters (``/<node>:`` sections of the parameter files) and
topics; only the interpreter is shared. `advsim attack` runs the light nodes this way and
lidar_resim, which computes while the others wait, in a process of its own.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

from rclpy.node import Node

from advsim_ros.ros.graph_node import run_nodes


def _factories() -> dict[str, Callable[[], Node]]:
    from advsim_ros.nodes.lidar_resim import LidarResim
    from advsim_ros.nodes.perturber import Perturber
    from advsim_ros.nodes.scenario_player import ScenarioPlayer
    from advsim_ros.nodes.scorer import Scorer
    from advsim_ros.nodes.search import SearchNode

    return {
        "scenario_player": ScenarioPlayer,
        "scorer": Scorer,
        "perturber": Perturber,
        "search": SearchNode,
        "lidar_resim": LidarResim,
    }


def main() -> None:
    arguments = sys.argv[1 : sys.argv.index("--ros-args")] if "--ros-args" in sys.argv else sys.argv[1:]
    factories = _factories()
    unknown = [name for name in arguments if name not in factories]
    if not arguments or unknown:
        print(f"{sys.argv[0]}: name the nodes to run, from {', '.join(factories)} (got {arguments})", file=sys.stderr)
        sys.exit(2)
    run_nodes([factories[name] for name in arguments])


if __name__ == "__main__":
    main()
