"""stack_adapter: bridges the contract's topics to a stack with names, types, frames and timing of its own.

Started by ``advsim attack`` when the stack profile (``--stack-profile``, or ``--remap`` rules)
differs from the contract. It never changes what the stack is told, only how it is said:

- renamed topics of the contract's types are relayed byte for byte with the contract's QoS
  (latched stay latched): inputs under the stack's names, answers under the contract's;
- the pose is re-published in the stack's type (Odometry in another frame, PoseStamped,
  PoseWithCovarianceStamped, NavSatFix from the profile's datum) from the contract's odometry;
- the LiDAR sweep gets the stack's sensor frame name, with an identity transform to it on /tf_static;
- detections and predictions in the stack's types (Autoware objects, MarkerArray cubes) become
  the contract's ActorTrackArray, in the world frame, predictions on one time base from the sweep;
- the plan, in the stack's type and frame, becomes the contract's plan (adapters.plans). A stack
  planning per sweep stamps its answer with the sweep; a stack planning on its own timer (the
  player then steps /clock) is answered with the plan in force at the sweep's decision time
  (adapters.timing).

Parameters: ``profile_file`` (the profile as the attack wrote it, JSON), ``run_id``.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from advsim_ros.adapters import messages as foreign
from advsim_ros.adapters.plans import contract_plan, ego_before, frame_transform
from advsim_ros.adapters.profile import StackProfile, load_profile
from advsim_ros.adapters.timing import FrameRelay, PlanBook
from advsim_ros.contract import codec, names, topics
from advsim_ros.contract.codec import ContractError
from advsim_ros.contract.plan import path_msg
from advsim_ros.contract.qos import QosSpec, Reliability
from advsim_ros.contract.spatial import odometry_msg, tf_message, transforms_of
from advsim_ros.contract.tracks import track_array_msg
from advsim_ros.core.metrics import NS_PER_S
from advsim_ros.core.types import ScenarioError
from advsim_ros.ros.graph_node import GraphNode, run_node
from advsim_ros.ros.messages import message_class
from advsim_ros.ros.qos import profile

NODE_NAME = "stack_adapter"
KEPT_ODOMETRY = 200
MATCH_WAIT = 2.0  # longest wait for the stack's readers to match before a message is relayed to them [s]


class StackAdapter(GraphNode):
    def __init__(self) -> None:
        super().__init__(NODE_NAME)
        path = str(self.declare_parameter("profile_file", "").value)
        if not path:
            raise ScenarioError(f"/{NODE_NAME}: the profile_file parameter is required")
        self.profile: StackProfile = load_profile(Path(path))
        self.plan_output = self.profile.outputs.plan
        self.timing = self.profile.timing
        self.clock_ns = 0
        self.world_frame = ""
        self.odometry: dict[int, tuple[float, np.ndarray]] = {}  # odometry stamp -> ego speed, world xy
        self.first_fix_xy: np.ndarray | None = None
        self.books: dict[str, PlanBook[Any]] = {}  # by contract answer topic: which answer goes with which sweep
        self.answer_publishers: dict[str, Callable[[Any], None]] = {}
        self.sensor_frames: set[str] = set()
        self.relay = FrameRelay()  # timer: which frames' inputs went to the stack in full
        self.publish_relayed = self.publisher(topics.RELAYED)
        self._warm_up()  # before any endpoint exists: the first query's inputs are not held up by first uses
        renamed = self.profile.renamed()
        self._relay(renamed)
        self._adapt_inputs(renamed)
        self._adapt_answers()

    # ------------------------------------------------------------------ relays and inputs

    def _relay(self, renamed: dict[str, str]) -> None:
        """Topics of the contract's types the stack only calls otherwise: relayed byte for byte."""
        converted = {topics.ODOM.name}
        if self.profile.inputs.lidar.frame_id or self.profile.inputs.lidar.also:
            converted.add(topics.LIDAR.name)
        outputs = self.profile.outputs
        if self.profile.plan_converted():
            converted.add(topics.PLAN.name)
        if self.profile.objects_converted(outputs.detections, topics.DETECTIONS.name):
            converted.add(topics.DETECTIONS.name)
        if self.profile.objects_converted(outputs.predictions, topics.PREDICTIONS.name):
            converted.add(topics.PREDICTIONS.name)
        for contract_name, stack_name in renamed.items():
            if contract_name in converted:
                continue
            spec = topics.stack_topic(contract_name)
            theirs = dataclasses.replace(spec, name=stack_name)
            to_stack = spec in topics.STACK_INPUTS
            source, target = (spec, theirs) if to_stack else (theirs, spec)
            publish = self._to_stack(target) if to_stack else self.publisher(target)
            if spec is topics.LIDAR:
                self.relay.relays_sweeps = True
                if self.timing.timer:  # the player paces /clock by the sweeps passed on
                    publish = self._then_passed_on(publish)
            self.subscribe(source, publish, raw=True, qos=self._read_qos(contract_name, source))
            self.get_logger().info(f"relaying {source.name} -> {target.name} ({spec.msgtype})")

    def _adapt_inputs(self, renamed: dict[str, str]) -> None:
        pose = self.profile.inputs.pose
        self.publish_pose: Any = None
        if pose.type != "odometry" or pose.frame_id or pose.topic != topics.ODOM.name:
            pose_spec = topics.TopicSpec(pose.topic, foreign.POSE_MSGTYPES[pose.type], topics.ODOM.offered)
            self.publish_pose = self._to_stack(pose_spec)
            self.get_logger().info(f"pose: {topics.ODOM.name} -> {pose.topic} ({pose_spec.msgtype})")
        self.subscribe(topics.ODOM, self.on_odometry, raw=True)  # also the ego's speed and the frames' stamps
        self.subscribe(topics.CLOCK, self.on_clock, raw=True)
        self.tf_edges: dict[tuple[str, str], np.ndarray] = {}  # frame_origin tf: the latest transforms seen
        if self.profile.outputs.plan.frame_origin == "tf":
            for spec in (topics.TF, topics.TF_STATIC):
                name = renamed.get(spec.name, spec.name)
                self.subscribe(dataclasses.replace(spec, name=name), self.on_tf, raw=True)
        lidar = self.profile.inputs.lidar
        if lidar.frame_id or lidar.also:
            targets = [topic for topic in (lidar.topic, *lidar.also) if topic != topics.LIDAR.name]
            self.sweep_publishers = [self._to_stack(dataclasses.replace(topics.LIDAR, name=t)) for t in targets]
            tf_static_name = renamed.get(topics.TF_STATIC.name, topics.TF_STATIC.name)
            self.tf_static_spec = dataclasses.replace(topics.TF_STATIC, name=tf_static_name)
            self.tf_static_publishers: list[Any] = []  # latched: kept alive
            self.subscribe(topics.LIDAR, self.on_sweep, raw=True)
            self.relay.relays_sweeps = True
            frame = f" in frame {lidar.frame_id}" if lidar.frame_id else ""
            self.get_logger().info(f"LiDAR: {topics.LIDAR.name} -> {', '.join(targets)}{frame}")

    def _warm_up(self) -> None:
        """Run the pose conversion once (type stores, message classes, geodesy): a timer-driven stack is
        stepped at real time, and a first decode of ~1 s made its first fixes arrive late in query 0."""
        pose = self.profile.inputs.pose
        odometry = codec.decode(codec.encode(odometry_msg(0, "world", "base_link", np.eye(4), np.zeros(3), 0.0)),
                                names.ODOMETRY)  # fmt: skip
        codec.encode(foreign.pose_input(pose.type, odometry, pose.frame_id, pose.datum))
        for msgtype in (*foreign.POSE_MSGTYPES.values(), *foreign.PLAN_MSGTYPES.values()):
            message_class(msgtype)

    def _to_stack(self, spec: topics.TopicSpec) -> Callable[[Any], None]:
        """A publisher to the stack whose first message waits (bounded) for the stack's readers to match.

        The player's readiness sees its own writers matched, not this hop's: a volatile reader of the
        stack still matching (or not yet discovered here) would lose the first sweep or pose.
        """
        publisher = self.create_publisher(message_class(spec.msgtype), spec.name, profile(spec.offered))
        first = [True]

        def publish(value: Any) -> None:
            if first[0]:
                first[0] = False
                deadline = time.monotonic() + MATCH_WAIT
                while publisher.get_subscription_count() < max(1, self.count_subscribers(spec.name)):
                    if time.monotonic() > deadline:
                        break  # nobody reads it (a renamed topic the stack does not use): never wait again
                    time.sleep(0.005)  # matching happens on the middleware's threads
            publisher.publish(value if isinstance(value, bytes) else codec.encode(value))

        return publish

    def _then_passed_on(self, relay: Callable[[bytes], None]) -> Callable[[bytes], None]:
        def relay_sweep(raw: bytes) -> None:
            relay(raw)
            self._passed_on(codec.header_stamp_ns(raw), "sweep")

        return relay_sweep

    def _passed_on(self, stamp_ns: int, kind: str) -> None:
        """Timer-driven stack: once a frame's pose and sweep went to the stack, tell the player, which moves
        /clock to the frame only then. Publishing is synchronous and a process's shared-memory port is read
        in order, so the stack has them before that /clock: a timer firing on it sees this frame's inputs."""
        if self.timing.timer and self.relay.passed_on(stamp_ns, kind):
            self.publish_relayed(codec.header_msg(stamp_ns, ""))

    def on_tf(self, raw: bytes) -> None:
        self.tf_edges.update(transforms_of(codec.decode(raw, names.TF_MESSAGE)))

    def on_clock(self, raw: bytes) -> None:
        self.clock_ns = codec.stamp_ns(codec.decode(raw, names.CLOCK).clock)
        if self.timing.timer:
            self._answer_due()

    def on_odometry(self, raw: bytes) -> None:
        odometry = codec.decode(raw, names.ODOMETRY)
        stamp = codec.stamp_ns(odometry.header.stamp)
        self.world_frame = odometry.header.frame_id
        self.odometry[stamp] = (foreign.odometry_speed(odometry), foreign.odometry_xy(odometry))
        while len(self.odometry) > KEPT_ODOMETRY:
            del self.odometry[min(self.odometry)]
        pose = self.profile.inputs.pose
        if pose.type == "navsatfix" and self.first_fix_xy is None:
            self.first_fix_xy = foreign.odometry_xy(odometry)
        if self.publish_pose is not None:
            self.publish_pose(foreign.pose_input(pose.type, odometry, pose.frame_id, pose.datum))
        for book in self.books.values():
            book.sweep(stamp)
        self._passed_on(stamp, "pose")

    def on_sweep(self, raw: bytes) -> None:
        frame = self.profile.inputs.lidar.frame_id
        if frame:
            cloud = codec.decode(raw, names.POINTCLOUD2)
            if cloud.header.frame_id not in self.sensor_frames:  # the stack's frame is where the sweep's is
                self.sensor_frames.add(cloud.header.frame_id)
                transform = tf_message(codec.stamp_ns(cloud.header.stamp), cloud.header.frame_id, frame, np.eye(4))
                self.tf_static_publishers.append(self.latch(self.tf_static_spec, transform))
            raw = codec.encode(
                dataclasses.replace(cloud, header=codec.header_msg(codec.stamp_ns(cloud.header.stamp), frame))
            )
        for publish in self.sweep_publishers:
            publish(raw)
        self._passed_on(codec.header_stamp_ns(raw), "sweep")

    # ------------------------------------------------------------------ the answers

    def _adapt_answers(self) -> None:
        """Subscribe to every answer the profile converts; each becomes its contract topic's message."""
        outputs = self.profile.outputs
        answers = (
            (topics.PLAN, outputs.plan.topic, foreign.PLAN_MSGTYPES[outputs.plan.type], self.profile.plan_converted()),
            (topics.DETECTIONS, outputs.detections.topic, foreign.DETECTION_MSGTYPES[outputs.detections.type],
             self.profile.objects_converted(outputs.detections, topics.DETECTIONS.name)),
            (topics.PREDICTIONS, outputs.predictions.topic, foreign.PREDICTION_MSGTYPES[outputs.predictions.type],
             self.profile.objects_converted(outputs.predictions, topics.PREDICTIONS.name)),
        )  # fmt: skip
        mode = f"timer (decision delay {self.timing.decision_delay} s)" if self.timing.timer else "per sweep"
        for contract, topic, msgtype, converted in answers:
            if not converted:
                continue  # relayed as it is when renamed
            if self.timing.timer:
                self.books[contract.name] = PlanBook(self.timing)
            self.answer_publishers[contract.name] = self.publisher(contract)
            theirs = topics.TopicSpec(topic, msgtype, contract.offered)
            qos = self._read_qos(contract.name, theirs)
            self.subscribe(theirs, lambda raw, c=contract, t=msgtype: self.on_answer(c, t, raw), raw=True, qos=qos)
            self.get_logger().info(f"{contract.name} <- {topic} ({msgtype}, {mode})")

    def _read_qos(self, contract_name: str, source: topics.TopicSpec) -> QosSpec:
        """How the adapter reads a topic: as offered, but best effort where the stack publishes so."""
        outputs = self.profile.outputs
        reliability = {
            topics.PLAN.name: outputs.plan.reliability,
            topics.DETECTIONS.name: outputs.detections.reliability,
            topics.PREDICTIONS.name: outputs.predictions.reliability,
        }.get(contract_name, "reliable")
        if reliability == "reliable":
            return source.offered
        return dataclasses.replace(source.offered, reliability=Reliability.BEST_EFFORT)

    def on_answer(self, contract: topics.TopicSpec, msgtype: str, raw: bytes) -> None:
        outputs = self.profile.outputs
        try:
            msg = codec.decode(raw, msgtype)
            stamp, frame = foreign.header_of(msg) or (self.clock_ns, "")  # an empty MarkerArray: now
            if contract is topics.PLAN:
                if outputs.plan.frame_id and frame and frame != outputs.plan.frame_id:
                    raise ContractError(f"the plan is in frame {frame!r}, the profile says {outputs.plan.frame_id!r}")
                answer: Any = foreign.plan_poses(outputs.plan.type, msg)
            elif contract is topics.DETECTIONS:
                answer = (frame, foreign.detection_tracks(outputs.detections.type, msg))
            else:
                answer = (frame, foreign.prediction_tracks(outputs.predictions.type, msg))
        except (ScenarioError, ValueError) as error:
            self.get_logger().error(f"unusable answer for {contract.name}: {error}")
            return
        if not self.timing.timer:
            self._publish(contract, stamp, stamp, answer)
            return
        made = self.clock_ns if self.timing.plan_stamp == "arrival" else stamp
        self.books[contract.name].plan(made, answer)
        self._answer_due()

    def _answer_due(self) -> None:
        for name, book in self.books.items():
            for sweep, made, answer in book.due(self.clock_ns):
                self._publish(topics.stack_topic(name), sweep, made, answer)

    def _publish(self, contract: topics.TopicSpec, sweep_ns: int, made_ns: int, answer: Any) -> None:
        """The contract's message for the sweep stamped sweep_ns from an answer the stack made at made_ns."""
        plan_output = self.profile.outputs.plan
        try:
            tf = (self.world_frame, self.tf_edges)
            transform = frame_transform(plan_output, self.profile.inputs.pose.datum, self.first_fix_xy, tf)
        except ScenarioError as error:
            self.get_logger().error(f"{contract.name} for sweep {sweep_ns}: {error}")
            return
        world = self.world_frame or "world"
        if contract is topics.PLAN:
            speed, ego = ego_before(self.odometry, made_ns)  # a path without times is driven from there
            plan = contract_plan(answer, made_ns, sweep_ns, speed, plan_output, transform, ego)
            self.answer_publishers[contract.name](path_msg(plan, sweep_ns, world))
            return
        frame, tracks = answer
        in_plan_frame = bool(plan_output.frame_id) and frame == plan_output.frame_id  # else: the world frame
        tracks = [foreign.moved(track, transform) for track in tracks] if in_plan_frame else tracks
        if contract is topics.PREDICTIONS:  # one time base for all, from the sweep on (the scorer needs it)
            step_ns = round(plan_output.step * NS_PER_S)
            grid = sweep_ns + step_ns * np.arange(plan_output.num_steps + 1, dtype=np.int64)
            tracks = [foreign.on_grid(track, grid) for track in tracks]
        else:
            tracks = [foreign.on_grid(track, [sweep_ns]) for track in tracks]
        self.answer_publishers[contract.name](track_array_msg(tracks, sweep_ns, world))


def main() -> None:
    run_node(StackAdapter)


if __name__ == "__main__":
    main()
