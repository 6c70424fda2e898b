"""What every node of the attack graph shares: contract topics as raw CDR, the run id, the main loop.

Messages travel as CDR bytes built and parsed by ``advsim_ros.contract`` (rclpy's
``publish(bytes)`` and ``raw=True`` subscriptions), so what a node publishes is byte for byte
what a bag records. Protocol messages carry the attack's run id: a subscription drops, and
logs once, those of another run, so a stray graph on the same ROS domain changes nothing.
"""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Callable, Sequence

import rclpy
from rclpy.callback_groups import CallbackGroup
from rclpy.context import Context
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.rcutils_logger import RcutilsLogger
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.utilities import try_shutdown

from advsim_ros.contract import codec
from advsim_ros.contract.codec import Msg
from advsim_ros.contract.qos import QosSpec
from advsim_ros.contract.topics import TopicSpec
from advsim_ros.core.types import ScenarioError
from advsim_ros.ros.messages import message_class
from advsim_ros.ros.qos import profile
from advsim_ros.ros.trace import Trace

RUN_ID_PARAMETER = "run_id"  # every node of one attack gets the same value (advsim attack draws it)
# Subscriptions keep this many messages whatever the writers keep: a latched topic's single slot
# would otherwise be overwritten by another writer's message (a stray graph) before it is read.
SUBSCRIPTION_DEPTH = 100

Publish = Callable[[Msg | bytes], None]  # publishes a typestore message object or ready CDR bytes


class TypedNode(Node):
    """rclpy's Node with the two methods rclpy leaves unannotated typed (unchanged): the graph's nodes and the
    reference stacks' derive from it."""

    def get_logger(self) -> RcutilsLogger:
        logger: RcutilsLogger = Node.get_logger(self)
        return logger

    def destroy_node(self) -> None:
        Node.destroy_node(self)


class GraphNode(TypedNode):
    """A node that speaks the contract as CDR, knows the attack's window and ignores other runs."""

    def __init__(
        self, name: str, parameter_overrides: list[Parameter] | None = None, context: Context | None = None
    ) -> None:
        super().__init__(name, parameter_overrides=parameter_overrides, context=context)
        self.run_id = int(self.declare_parameter(RUN_ID_PARAMETER, 0).value)
        self.trace = Trace(name)
        self._foreign_runs: set[tuple[str, int]] = set()
        self._publishers_by_topic: dict[str, Publisher] = {}

    def publisher(self, topic: TopicSpec, qos: QosSpec | None = None) -> Publish:
        """A publish function taking a typestore message object or ready CDR bytes."""
        publisher = self.create_publisher(message_class(topic.msgtype), topic.name, profile(qos or topic.offered))
        self._publishers_by_topic[topic.name] = publisher

        def publish(value: Msg | bytes) -> None:
            publisher.publish(value if isinstance(value, bytes) else codec.encode(value))

        return publish

    def matched_readers(self, topic: TopicSpec) -> int:
        """Subscriptions matched with this node's publisher of ``topic`` (made by ``publisher``)."""
        count: int = self._publishers_by_topic[topic.name].get_subscription_count()
        return count

    def latch(self, topic: TopicSpec, value: Msg) -> Publisher:
        """Publish one message on a latched (transient-local) topic; the publisher is returned to keep it alive."""
        publisher = self.create_publisher(message_class(topic.msgtype), topic.name, profile(topic.offered))
        publisher.publish(codec.encode(value))
        return publisher

    def subscribe(
        self,
        topic: TopicSpec,
        callback: Callable[[Msg], None],  # the decoded message, or its CDR bytes with raw=True
        *,
        qos: QosSpec | None = None,
        raw: bool = False,
        group: CallbackGroup | None = None,
    ) -> None:
        """Subscribe; the callback gets the decoded message (its CDR bytes with raw=True).

        Messages with a run id (the protocol's) reach the callback only when it is this attack's.
        """

        def on_message(data: bytes) -> None:
            if raw:
                callback(data)
                return
            decoded = codec.decode(data, topic.msgtype)
            foreign = getattr(decoded, "run_id", self.run_id)
            if foreign != self.run_id:
                self._ignore(topic.name, int(foreign))
                return
            callback(decoded)

        offered = qos or topic.offered
        depth = max(offered.depth, SUBSCRIPTION_DEPTH)
        self.create_subscription(
            message_class(topic.msgtype),
            topic.name,
            on_message,
            profile(dataclasses.replace(offered, depth=depth)),
            raw=True,
            callback_group=group,
        )

    def _ignore(self, topic: str, run_id: int) -> None:
        if (topic, run_id) not in self._foreign_runs:
            self._foreign_runs.add((topic, run_id))
            self.get_logger().warning(
                f"ignoring {topic} messages of run {run_id:#x} (this attack is run {self.run_id:#x}): "
                "another graph shares the ROS domain"
            )


def run_node(factory: Callable[[], Node]) -> None:
    """Create the node and spin it until SIGINT/SIGTERM; a start-up error exits 1 with its message."""
    run_nodes([factory])


def run_nodes(factories: Sequence[Callable[[], Node]]) -> None:
    """Several nodes in one process (as a ROS 2 component container does), spun by one executor.

    The graph's light nodes share one interpreter this way: one import of numpy, rclpy and the
    contract, one typestore, instead of one per process. A start-up error exits 1 with its message.
    """
    rclpy.init()
    nodes: list[Node] = []
    exit_code = 0
    try:
        nodes.extend(factory() for factory in factories)
        for node in nodes:  # start-up as bench/bench_attack.py splits it: imports, parameters, models
            trace = getattr(node, "trace", None)  # the graph's nodes and the reference stacks
            if isinstance(trace, Trace):
                trace("ready")
        executor = SingleThreadedExecutor()
        for node in nodes:
            executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ScenarioError, OSError) as error:
        print(f"{sys.argv[0]}: error: {error}", file=sys.stderr)
        exit_code = 1
    finally:
        for node in reversed(nodes):
            node.destroy_node()
        try_shutdown()
    if exit_code:
        sys.exit(exit_code)
