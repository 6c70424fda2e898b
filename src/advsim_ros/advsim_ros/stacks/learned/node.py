"""learned_stack: the imitation-learning reference stack as a ROS 2 node (params/stack_learned.yaml)."""

from __future__ import annotations

from advsim_ros.ros.graph_node import run_node
from advsim_ros.stacks.learned.config import NODE_NAME, LearnedStackConfig
from advsim_ros.stacks.learned.stack import LearnedStack
from advsim_ros.stacks.stack_node import StackNode


def make_node() -> StackNode[LearnedStackConfig]:
    return StackNode(NODE_NAME, LearnedStack, LearnedStackConfig)


def main() -> None:
    run_node(make_node)


if __name__ == "__main__":
    main()
