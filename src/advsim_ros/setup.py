"""ament_python package advsim_ros: the attack graph's nodes, the `advsim` command and the pure core."""

import importlib.util
import sys
from glob import glob
from pathlib import Path
from types import ModuleType

from setuptools import find_packages, setup

PACKAGE = "advsim_ros"


def _graph() -> ModuleType:
    """advsim_ros/graph.py on its own (standard library only): the package's dependencies may not be installed yet."""
    spec = importlib.util.spec_from_file_location("_advsim_ros_graph", Path(__file__).parent / PACKAGE / "graph.py")
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the file runs
    spec.loader.exec_module(module)
    return module


# One console script per node of the attack graph (ros2 run advsim_ros <name>; advsim_ros.graph declares them), one
# per reference stack under test, and the `advsim` command.
NODES: dict[str, str] = {
    **{node.name: node.entry_point for node in _graph().runnable()},
    "modular_stack": "advsim_ros.stacks.modular.node:main",
    "learned_stack": "advsim_ros.stacks.learned.node:main",
}

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    package_data={"advsim_ros.ros": ["*.xml"], "advsim_ros.stacks.learned": ["weights/*.pt"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/params", glob("../../params/*.yaml")),
        # ros2 launch advsim_ros attack.launch.py / replay.launch.py (full ROS 2 installs)
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="advsim_ros maintainers",
    maintainer_email="maintainers@advsim-ros.dev",
    description="AdvSim as a ROS 2 node graph: safety-critical scenarios for LiDAR-based autonomy stacks.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "advsim = advsim_ros.cli:main",
            *(f"{name} = {target}" for name, target in NODES.items()),
        ],
    },
)
