"""ament_python package advsim_ros: the attack graph's nodes, the `advsim` command and the pure core."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "advsim_ros"

# One console script per node (ros2 run advsim_ros <name>), plus the `advsim` command.
NODES: dict[str, str] = {
    "scenario_player": "advsim_ros.nodes.scenario_player:main",
    "perturber": "advsim_ros.nodes.perturber:main",
    "lidar_resim": "advsim_ros.nodes.lidar_resim:main",
    "scorer": "advsim_ros.nodes.scorer:main",
    "search": "advsim_ros.nodes.search:main",
    "stack_adapter": "advsim_ros.nodes.stack_adapter:main",
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
