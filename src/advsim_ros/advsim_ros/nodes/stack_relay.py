"""stack_relay: bridges the contract's topics to a stack that keeps topic names of its own.

`advsim attack --remap /sensor/lidar/points:=/points_raw` says the stack reads the LiDAR on
/points_raw. A rename rule handed to the stack's command reaches its nodes only when the command
passes `--ros-args` on (not through a shell script or a launch file), so by default the graph
relays instead: each of the stack's inputs is re-published, byte for byte and with the contract's
QoS, under the stack's name, and each of its outputs (plan, detections, predictions) under the
contract's. Latched topics stay latched. The player then looks for the stack under its own names.

Parameters: ``relays`` (CONTRACT:=STACK strings), ``run_id``.
"""

from __future__ import annotations

import dataclasses

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.parameter import Parameter

from advsim_ros.contract import topics
from advsim_ros.core.types import ScenarioError
from advsim_ros.ros.graph_node import GraphNode, run_node
from advsim_ros.ros.lockstep import StackNames

NODE_NAME = "stack_relay"


class StackRelay(GraphNode):
    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        pairs = self.declare_parameter(
            "relays", Parameter.Type.STRING_ARRAY, ParameterDescriptor(description="CONTRACT:=STACK topic pairs")
        ).value
        names = StackNames.from_pairs(pairs or [])
        for contract_name, stack_name in names.renamed.items():
            try:
                spec = topics.stack_topic(contract_name)
            except KeyError:
                raise ScenarioError(f"/{NODE_NAME} relays: {contract_name} is not a topic the stack shares") from None
            theirs = dataclasses.replace(spec, name=stack_name)
            source, target = (spec, theirs) if spec in topics.STACK_INPUTS else (theirs, spec)
            self.subscribe(source, self.publisher(target), raw=True)
            self.get_logger().info(f"relaying {source.name} -> {target.name} ({spec.msgtype})")


def main() -> None:
    run_node(StackRelay)


if __name__ == "__main__":
    main()
