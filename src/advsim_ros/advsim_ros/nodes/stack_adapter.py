"""stack_adapter: bridges the contract's topics to a stack with names, types, frames and timing of its own.

Started by ``advsim attack`` when the stack profile (``--stack-profile``, or ``--remap`` rules)
differs from the contract. It never changes what the stack is told, only how it is said: renamed
topics are relayed byte for byte, the pose and the sweep's frame are given in the stack's terms, its
answers become the contract's (adapters.bridge says which and how; a timer-driven stack is answered
with the plan in force at the sweep's decision time, adapters.timing). Its publishers to the stack
wait for the stack's readers (ros.stack_io).

Parameters: ``profile_file`` (the profile as the attack wrote it, JSON), ``run_id``.
"""

from __future__ import annotations

from pathlib import Path

from advsim_ros import graph
from advsim_ros.adapters import bridge
from advsim_ros.adapters import messages as foreign
from advsim_ros.adapters.profile import StackProfile, load_profile
from advsim_ros.adapters.timing import FrameRelay
from advsim_ros.contract import codec, names, topics
from advsim_ros.core.types import ScenarioError
from advsim_ros.ros.graph_node import GraphNode, run_node
from advsim_ros.ros.messages import message_class
from advsim_ros.ros.stack_io import Acknowledgements, AnswerOutlet, SweepOutlet, relay_topic, to_stack_publisher

NODE_NAME = graph.STACK_ADAPTER.name


class StackAdapter(GraphNode):
    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        path = str(self.declare_parameter("profile_file", "").value)
        if not path:
            raise ScenarioError(f"/{NODE_NAME}: the profile_file parameter is required")
        self.profile: StackProfile = load_profile(Path(path))
        self.timing = self.profile.timing
        self.answers = bridge.Answers(self.profile)  # what was heard, the answers owed per sweep
        self.answer_outlet = AnswerOutlet(self, self.answers)
        self.relay = FrameRelay()  # timer: which frames' inputs went to the stack in full
        self.acknowledge = Acknowledgements(self, self.relay.passed_on if self.timing.timer else None)
        # warmed up before the stack's endpoints exist: the first query's inputs are not held up by first uses
        bridge.convert_pose_once(self.profile.inputs.pose)
        for msgtype in bridge.WARM_MSGTYPES:
            message_class(msgtype)
        renamed = self.profile.renamed()
        for relay in bridge.relays(self.profile, renamed):  # the topics only renamed
            sweeps = relay.contract is topics.LIDAR
            if sweeps:
                self.relay.relays_sweeps = True
            # timer: the player paces /clock by the sweeps passed on
            then = self.acknowledge.sweep if sweeps and self.timing.timer else None
            qos = bridge.read_qos(self.profile, relay.contract.name, relay.source)
            relay_topic(self, relay.source, relay.target, relay.to_stack, qos, then)
        self._adapt_inputs(renamed)
        self._adapt_answers()

    def _adapt_inputs(self, renamed: dict[str, str]) -> None:
        pose_spec = bridge.pose_target(self.profile)
        self.publish_pose = to_stack_publisher(self, pose_spec) if pose_spec is not None else None
        if pose_spec is not None:
            self.get_logger().info(f"pose: {topics.ODOM.name} -> {pose_spec.name} ({pose_spec.msgtype})")
        self.subscribe(topics.ODOM, self.on_odometry, raw=True)  # also the ego's speed and the frames' stamps
        self.subscribe(topics.CLOCK, self.on_clock, raw=True)
        if self.profile.outputs.plan.frame_origin == "tf":
            for spec in (topics.TF, topics.TF_STATIC):
                self.subscribe(bridge.under_stack_name(spec, renamed), self.on_tf, raw=True)
        targets = bridge.sweep_targets(self.profile)
        if targets is not None:
            frame, seen = self.profile.inputs.lidar.frame_id, set[str]()  # the sweeps' own frames seen
            reframe = (lambda raw: bridge.reframed(raw, frame, seen)) if frame else None
            tf_static = bridge.under_stack_name(topics.TF_STATIC, renamed)
            self.on_sweep = SweepOutlet(self, targets, tf_static, reframe, self.acknowledge.sweep)
            self.subscribe(topics.LIDAR, self.on_sweep, raw=True)
            self.relay.relays_sweeps = True
            in_frame = f" in frame {frame}" if frame else ""
            self.get_logger().info(f"LiDAR: {topics.LIDAR.name} -> {', '.join(targets)}{in_frame}")

    def _adapt_answers(self) -> None:
        """Subscribe to every answer the profile converts; each becomes its contract topic's message."""
        mode = f"timer (decision delay {self.timing.decision_delay} s)" if self.timing.timer else "per sweep"
        for route in bridge.answer_routes(self.profile):
            if route.converted:  # else relayed as it is when renamed
                qos = bridge.read_qos(self.profile, route.contract.name, route.theirs)
                self.answer_outlet.add(route.contract, route.theirs, qos, mode)

    def on_tf(self, raw: bytes) -> None:
        self.answers.heard_tf(codec.decode(raw, names.TF_MESSAGE))

    def on_clock(self, raw: bytes) -> None:
        self.answers.clock_ns = codec.stamp_ns(codec.decode(raw, names.CLOCK).clock)
        if self.timing.timer:
            self.answer_outlet.publish(self.answers.due())

    def on_odometry(self, raw: bytes) -> None:
        odometry = codec.decode(raw, names.ODOMETRY)
        stamp = self.answers.heard_odometry(odometry)
        if self.publish_pose is not None:
            pose = self.profile.inputs.pose
            self.publish_pose(foreign.pose_input(pose.type, odometry, pose.frame_id, pose.datum))
        self.answers.sweep(stamp)
        self.acknowledge(stamp, "pose")


def main() -> None:
    run_node(StackAdapter)


if __name__ == "__main__":
    main()
