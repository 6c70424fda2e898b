"""modular_stack: the modular reference stack as a ROS 2 node (params/stack_modular.yaml)."""

from __future__ import annotations

from advsim_ros.ros.graph_node import run_node
from advsim_ros.stacks.modular.config import NODE_NAME, ModularStackConfig
from advsim_ros.stacks.modular.stack import ModularStack
from advsim_ros.stacks.stack_node import StackNode


def make_node() -> StackNode[ModularStackConfig]:
    return StackNode(NODE_NAME, ModularStack, ModularStackConfig)


def main() -> None:
    run_node(make_node)


if __name__ == "__main__":
    main()
