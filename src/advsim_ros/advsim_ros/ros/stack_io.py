"""stack_adapter's ends on the graph: publishers that wait for the stack's readers, relays, acknowledgements."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterable
from typing import Generic, Protocol, TypeVar

from rclpy.publisher import Publisher

from advsim_ros.contract import codec, topics
from advsim_ros.contract.codec import Msg
from advsim_ros.contract.qos import QosSpec
from advsim_ros.core.types import ScenarioError
from advsim_ros.ros.graph_node import GraphNode, Publish
from advsim_ros.ros.messages import message_class
from advsim_ros.ros.qos import profile

Due = tuple[topics.TopicSpec, int, int, object]  # contract topic, sweep stamp, made [ns], answer (the converter's)
TransformT = TypeVar("TransformT")  # the converter's own transform (adapters.plans.PlanarTransform), opaque here
MATCH_WAIT = 2.0  # longest wait for the stack's readers to match before a message is relayed to them [s]


def to_stack_publisher(node: GraphNode, spec: topics.TopicSpec) -> Publish:
    """A publisher to the stack whose first message waits (bounded) for the stack's readers to match.

    The player's readiness sees its own writers matched, not this hop's: a volatile reader of the
    stack still matching (or not yet discovered here) would lose the first sweep or pose.
    """
    publisher = node.create_publisher(message_class(spec.msgtype), spec.name, profile(spec.offered))
    first = [True]

    def publish(value: Msg | bytes) -> None:
        if first[0]:
            first[0] = False
            deadline = time.monotonic() + MATCH_WAIT
            while publisher.get_subscription_count() < max(1, node.count_subscribers(spec.name)):
                if time.monotonic() > deadline:
                    break  # nobody reads it (a renamed topic the stack does not use): never wait again
                time.sleep(0.005)  # matching happens on the middleware's threads
        publisher.publish(value if isinstance(value, bytes) else codec.encode(value))

    return publish


def relay_topic(
    node: GraphNode,
    source: topics.TopicSpec,
    target: topics.TopicSpec,
    to_stack: bool,
    qos: QosSpec,
    then: Callable[[bytes], None] | None = None,
) -> None:
    """Relay ``source`` to ``target`` byte for byte (to the stack: waiting for its readers first); ``then(raw)``
    after each message is passed on."""
    publish = to_stack_publisher(node, target) if to_stack else node.publisher(target)
    if then is not None:
        relay = publish

        def publish(raw: bytes) -> None:
            relay(raw)
            then(raw)

    node.subscribe(source, publish, raw=True, qos=qos)
    node.get_logger().info(f"relaying {source.name} -> {target.name} ({source.msgtype})")


class Acknowledgements:
    """Timer-driven stack: once a frame's pose and sweep went to the stack, tell the player, which moves
    /clock to the frame only then. Publishing is synchronous and a process's shared-memory port is read
    in order, so the stack has them before that /clock: a timer firing on it sees this frame's inputs."""

    def __init__(self, node: GraphNode, passed_on: Callable[[int, str], bool] | None) -> None:
        """``passed_on(stamp, kind)``: whether the frame is complete now (adapters.timing.FrameRelay); None:
        the stack plans per sweep, and nothing is acknowledged."""
        self.publish_relayed = node.publisher(topics.RELAYED)
        self.passed_on = passed_on

    def __call__(self, stamp_ns: int, kind: str) -> None:
        if self.passed_on is not None and self.passed_on(stamp_ns, kind):
            self.publish_relayed(codec.header_msg(stamp_ns, ""))

    def sweep(self, raw: bytes) -> None:
        """A sweep (CDR) went to the stack."""
        self(codec.header_stamp_ns(raw), "sweep")


class SweepOutlet:
    """The sweeps to the stack's own LiDAR topics, each in the stack's sensor frame where it names one.

    ``reframe(raw)`` gives the sweep in that frame and, the first time a sweep's frame is seen, the identity
    transform to it, latched on the stack's /tf_static (its publishers kept alive); None: sent as it is.
    """

    def __init__(
        self,
        node: GraphNode,
        targets: list[str],
        tf_static: topics.TopicSpec,
        reframe: Callable[[bytes], tuple[bytes, Msg | None]] | None,  # the sweep, and a TFMessage or None
        then: Callable[[bytes], None],
    ) -> None:
        self.node, self.tf_static, self.reframe, self.then = node, tf_static, reframe, then
        self.publishers = [to_stack_publisher(node, dataclasses.replace(topics.LIDAR, name=t)) for t in targets]
        self.tf_static_publishers: list[Publisher] = []  # latched: kept alive

    def __call__(self, raw: bytes) -> None:
        if self.reframe is not None:
            raw, transform = self.reframe(raw)
            if transform is not None:
                self.tf_static_publishers.append(self.node.latch(self.tf_static, transform))
        for publish in self.publishers:
            publish(raw)
        self.then(raw)


class Converter(Protocol[TransformT]):
    """How the stack's answers become the contract's messages (adapters.bridge.Answers); an answer is the
    converter's own value (the plan's poses, or a frame's tracks), handed back to it as it came."""

    def decode(self, contract: topics.TopicSpec, msgtype: str, raw: bytes) -> tuple[int, object]: ...
    def arrived(self, contract: topics.TopicSpec, stamp_ns: int, answer: object) -> Iterable[Due]: ...
    def transform(self) -> TransformT: ...
    def message(
        self, contract: topics.TopicSpec, sweep_ns: int, made_ns: int, answer: object, transform: TransformT
    ) -> Msg: ...


class AnswerOutlet(Generic[TransformT]):
    """The stack's answers in, the contract's messages out: each for the sweep it answers (``Converter``)."""

    def __init__(self, node: GraphNode, converter: Converter[TransformT]) -> None:
        self.node, self.converter = node, converter
        self.publishers: dict[str, Publish] = {}  # by contract topic

    def add(self, contract: topics.TopicSpec, theirs: topics.TopicSpec, qos: QosSpec, mode: str) -> None:
        """Publish ``contract`` from the stack's ``theirs`` (read with ``qos``); ``mode``: how it is timed, logged."""
        self.publishers[contract.name] = self.node.publisher(contract)
        self.node.subscribe(theirs, lambda raw: self.on_answer(contract, theirs.msgtype, raw), raw=True, qos=qos)
        self.node.get_logger().info(f"{contract.name} <- {theirs.name} ({theirs.msgtype}, {mode})")

    def on_answer(self, contract: topics.TopicSpec, msgtype: str, raw: bytes) -> None:
        try:
            stamp, answer = self.converter.decode(contract, msgtype, raw)
        except (ScenarioError, ValueError) as error:
            self.node.get_logger().error(f"unusable answer for {contract.name}: {error}")
            return
        self.publish(self.converter.arrived(contract, stamp, answer))

    def publish(self, due: Iterable[Due]) -> None:
        """Publish the contract's message of each (contract topic, sweep stamp, made [ns], answer), in turn."""
        for contract, sweep_ns, made_ns, answer in due:
            try:
                transform = self.converter.transform()
            except ScenarioError as error:
                self.node.get_logger().error(f"{contract.name} for sweep {sweep_ns}: {error}")
                continue
            self.publishers[contract.name](self.converter.message(contract, sweep_ns, made_ns, answer, transform))
