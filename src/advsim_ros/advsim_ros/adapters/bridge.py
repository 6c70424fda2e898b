"""What the stack_adapter node does for a profile, decided and computed without ROS (pure).

The node is started by ``advsim attack`` when the stack profile (``--stack-profile``, or
``--remap`` rules) differs from the contract. It never changes what the stack is told, only how
it is said:

- renamed topics of the contract's types are relayed byte for byte with the contract's QoS
  (latched stay latched): inputs under the stack's names, answers under the contract's (``relays``);
- the pose is re-published in the stack's type (Odometry in another frame, PoseStamped,
  PoseWithCovarianceStamped, NavSatFix from the profile's datum) from the contract's odometry
  (``pose_target``);
- the LiDAR sweep gets the stack's sensor frame name, with an identity transform to it on
  /tf_static (``sweep_targets``, ``reframed``);
- detections and predictions in the stack's types (Autoware objects, MarkerArray cubes) become
  the contract's ActorTrackArray, in the world frame, predictions on one time base from the sweep;
- the plan, in the stack's type and frame, becomes the contract's plan (adapters.plans). A stack
  planning per sweep stamps its answer with the sweep; a stack planning on its own timer (the
  player then steps /clock) is answered with the plan in force at the sweep's decision time
  (adapters.timing). ``Answers`` keeps what this needs and builds the contract's messages.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from advsim_ros.adapters import messages as foreign
from advsim_ros.adapters.plans import PlanarTransform, contract_plan, ego_before, frame_transform
from advsim_ros.adapters.profile import PoseInput, StackProfile
from advsim_ros.adapters.timing import PlanBook
from advsim_ros.contract import codec, names, topics
from advsim_ros.contract.codec import ContractError, Msg
from advsim_ros.contract.plan import path_msg
from advsim_ros.contract.qos import QosSpec, Reliability
from advsim_ros.contract.spatial import odometry_msg, tf_message, transforms_of
from advsim_ros.contract.tracks import track_array_msg
from advsim_ros.core.metrics import NS_PER_S
from advsim_ros.core.types import FloatArray

KEPT_ODOMETRY = 200  # the ego's recent odometry remembered (where a plan without times is driven from)
# message classes made once before any endpoint exists (besides the pose conversion's)
WARM_MSGTYPES = (*foreign.POSE_MSGTYPES.values(), *foreign.PLAN_MSGTYPES.values())


@dataclass(frozen=True)
class Relay:
    """A contract topic the stack calls otherwise, relayed byte for byte from ``source`` to ``target``."""

    contract: topics.TopicSpec
    source: topics.TopicSpec
    target: topics.TopicSpec
    to_stack: bool  # an input of the stack (else an answer, relayed under the contract's name)


@dataclass(frozen=True)
class AnswerRoute:
    """An answer the adapter converts: the stack's topic and type, and the contract topic it becomes."""

    contract: topics.TopicSpec
    theirs: topics.TopicSpec  # the stack's topic, its type, offered as the contract's
    converted: bool  # False: relayed as it is when renamed


def converted_topics(profile: StackProfile) -> set[str]:
    """The contract topics the adapter converts (type, frame or timing): never relayed as they are."""
    converted = {topics.ODOM.name}
    if profile.inputs.lidar.frame_id or profile.inputs.lidar.also:
        converted.add(topics.LIDAR.name)
    outputs = profile.outputs
    if profile.plan_converted():
        converted.add(topics.PLAN.name)
    if profile.objects_converted(outputs.detections, topics.DETECTIONS.name):
        converted.add(topics.DETECTIONS.name)
    if profile.objects_converted(outputs.predictions, topics.PREDICTIONS.name):
        converted.add(topics.PREDICTIONS.name)
    return converted


def relays(profile: StackProfile, renamed: dict[str, str]) -> list[Relay]:
    """Topics of the contract's types the stack only calls otherwise, in the order of ``renamed``."""
    converted = converted_topics(profile)
    found = []
    for contract_name, stack_name in renamed.items():
        if contract_name in converted:
            continue
        spec = topics.stack_topic(contract_name)
        theirs = dataclasses.replace(spec, name=stack_name)
        to_stack = spec in topics.STACK_INPUTS
        source, target = (spec, theirs) if to_stack else (theirs, spec)
        found.append(Relay(spec, source, target, to_stack))
    return found


def read_qos(profile: StackProfile, contract_name: str, source: topics.TopicSpec) -> QosSpec:
    """How the adapter reads a topic: as offered, but best effort where the stack publishes so."""
    outputs = profile.outputs
    reliability = {
        topics.PLAN.name: outputs.plan.reliability,
        topics.DETECTIONS.name: outputs.detections.reliability,
        topics.PREDICTIONS.name: outputs.predictions.reliability,
    }.get(contract_name, "reliable")
    if reliability == "reliable":
        return source.offered
    return dataclasses.replace(source.offered, reliability=Reliability.BEST_EFFORT)


def under_stack_name(spec: topics.TopicSpec, renamed: dict[str, str]) -> topics.TopicSpec:
    """The contract topic under the stack's name for it (its own where the stack keeps it)."""
    return dataclasses.replace(spec, name=renamed.get(spec.name, spec.name))


def pose_target(profile: StackProfile) -> topics.TopicSpec | None:
    """Where the pose goes in the stack's type; None when the stack reads the contract's odometry as it is."""
    pose = profile.inputs.pose
    if pose.type != "odometry" or pose.frame_id or pose.topic != topics.ODOM.name:
        return topics.TopicSpec(pose.topic, foreign.POSE_MSGTYPES[pose.type], topics.ODOM.offered)
    return None


def sweep_targets(profile: StackProfile) -> list[str] | None:
    """The topics the adapter publishes each sweep on; None when it does not touch the sweeps (relayed or read
    as they are). The contract's own LiDAR topic is never one: the player publishes there."""
    lidar = profile.inputs.lidar
    if not (lidar.frame_id or lidar.also):
        return None
    return [topic for topic in (lidar.topic, *lidar.also) if topic != topics.LIDAR.name]


def reframed(raw: bytes, frame: str, seen: set[str]) -> tuple[bytes, Msg | None]:
    """The sweep (CDR) in the stack's sensor frame ``frame``, and the tf_static message from the sweep's own frame
    to it when that frame is not in ``seen`` yet (then added); None when it is."""
    cloud = codec.decode(raw, names.POINTCLOUD2)
    stamp = codec.stamp_ns(cloud.header.stamp)
    transform = None
    if cloud.header.frame_id not in seen:  # the stack's frame is where the sweep's is
        seen.add(cloud.header.frame_id)
        transform = tf_message(stamp, cloud.header.frame_id, frame, np.eye(4))
    return codec.encode(dataclasses.replace(cloud, header=codec.header_msg(stamp, frame))), transform


def convert_pose_once(pose: PoseInput) -> None:
    """Run the pose conversion once (type stores, message classes, geodesy): a timer-driven stack is stepped
    at real time, and a first decode of ~1 s made its first fixes arrive late in query 0."""
    odometry = codec.decode(codec.encode(odometry_msg(0, "world", "base_link", np.eye(4), np.zeros(3), 0.0)),
                            names.ODOMETRY)  # fmt: skip
    codec.encode(foreign.pose_input(pose.type, odometry, pose.frame_id, pose.datum))


def answer_routes(profile: StackProfile) -> list[AnswerRoute]:
    """Every answer the stack gives (plan, detections, predictions), whether the adapter converts it."""
    outputs = profile.outputs
    answers = (
        (topics.PLAN, outputs.plan.topic, foreign.PLAN_MSGTYPES[outputs.plan.type], profile.plan_converted()),
        (topics.DETECTIONS, outputs.detections.topic, foreign.DETECTION_MSGTYPES[outputs.detections.type],
         profile.objects_converted(outputs.detections, topics.DETECTIONS.name)),
        (topics.PREDICTIONS, outputs.predictions.topic, foreign.PREDICTION_MSGTYPES[outputs.predictions.type],
         profile.objects_converted(outputs.predictions, topics.PREDICTIONS.name)),
    )  # fmt: skip
    return [
        AnswerRoute(contract, topics.TopicSpec(topic, msgtype, contract.offered), converted)
        for contract, topic, msgtype, converted in answers
    ]


# contract topic, sweep stamp, made [ns], answer. An answer is the plan's Poses or (frame, tracks), by its topic:
# Any, as the topic (a value) says which, where these are read
Due = tuple[topics.TopicSpec, int, int, Any]


@dataclass
class Answers:
    """What the adapter heard of the graph and the stack, and the contract's messages made from the answers."""

    profile: StackProfile
    clock_ns: int = 0  # the sim clock, last heard
    world_frame: str = ""
    odometry: dict[int, tuple[float, FloatArray]] = field(default_factory=dict)  # stamp -> ego speed, world xy
    first_fix_xy: FloatArray | None = None  # navsatfix: where the first fix sent to the stack was
    tf_edges: dict[tuple[str, str], FloatArray] = field(default_factory=dict)  # frame_origin tf: latest seen
    books: dict[str, PlanBook[Any]] = field(default_factory=dict)  # timer, by contract topic: answer per sweep

    def __post_init__(self) -> None:
        if self.profile.timing.timer:
            for route in answer_routes(self.profile):
                if route.converted:
                    self.books[route.contract.name] = PlanBook(self.profile.timing)

    def heard_odometry(self, odometry: Msg) -> int:
        """The contract's odometry (decoded) of a frame: the ego's speed, where it is, the world frame; its stamp."""
        stamp = codec.stamp_ns(odometry.header.stamp)
        self.world_frame = odometry.header.frame_id
        self.odometry[stamp] = (foreign.odometry_speed(odometry), foreign.odometry_xy(odometry))
        while len(self.odometry) > KEPT_ODOMETRY:
            del self.odometry[min(self.odometry)]
        if self.profile.inputs.pose.type == "navsatfix" and self.first_fix_xy is None:
            self.first_fix_xy = foreign.odometry_xy(odometry)
        return stamp

    def sweep(self, stamp_ns: int) -> None:
        """A frame went to the stack: timer-driven, each converted answer is owed for it."""
        for book in self.books.values():
            book.sweep(stamp_ns)

    def heard_tf(self, message: Msg) -> None:
        self.tf_edges.update(transforms_of(message))

    def decode(self, contract: topics.TopicSpec, msgtype: str, raw: bytes) -> tuple[int, Any]:
        """(stamp [ns], answer) of a stack's answer: the plan's poses, or (frame, tracks); ScenarioError or
        ValueError when it is unusable."""
        outputs = self.profile.outputs
        msg = codec.decode(raw, msgtype)
        stamp, frame = foreign.header_of(msg) or (self.clock_ns, "")  # an empty MarkerArray: now
        if contract is topics.PLAN:
            if outputs.plan.frame_id and frame and frame != outputs.plan.frame_id:
                raise ContractError(f"the plan is in frame {frame!r}, the profile says {outputs.plan.frame_id!r}")
            return stamp, foreign.plan_poses(outputs.plan.type, msg)
        if contract is topics.DETECTIONS:
            return stamp, (frame, foreign.detection_tracks(outputs.detections.type, msg))
        return stamp, (frame, foreign.prediction_tracks(outputs.predictions.type, msg))

    def arrived(self, contract: topics.TopicSpec, stamp_ns: int, answer: Any) -> Iterator[Due]:
        """The answers to publish now that this one came: per sweep itself, for its own stamp; timer-driven,
        every answer whose sweep's answer time came (``due``)."""
        timing = self.profile.timing
        if not timing.timer:
            yield contract, stamp_ns, stamp_ns, answer
            return
        made = self.clock_ns if timing.plan_stamp == "arrival" else stamp_ns
        self.books[contract.name].plan(made, answer)
        yield from self.due()

    def due(self) -> Iterator[Due]:
        """Timer-driven: the answers whose sweep's answer time the clock has reached (adapters.timing)."""
        for name, book in self.books.items():
            for sweep, made, answer in book.due(self.clock_ns):
                yield topics.stack_topic(name), sweep, made, answer

    def transform(self) -> PlanarTransform:
        """world_T_plan-frame now; ScenarioError while it is not known (no fix, no transform on /tf yet)."""
        tf = (self.world_frame, self.tf_edges)
        return frame_transform(self.profile.outputs.plan, self.profile.inputs.pose.datum, self.first_fix_xy, tf)

    def message(
        self, contract: topics.TopicSpec, sweep_ns: int, made_ns: int, answer: Any, transform: PlanarTransform
    ) -> Msg:
        """The contract's message for the sweep stamped sweep_ns from an answer the stack made at made_ns."""
        plan_output = self.profile.outputs.plan
        world = self.world_frame or "world"
        if contract is topics.PLAN:
            speed, ego = ego_before(self.odometry, made_ns)  # a path without times is driven from there
            plan = contract_plan(answer, made_ns, sweep_ns, speed, plan_output, transform, ego)
            return path_msg(plan, sweep_ns, world)
        frame, tracks = answer
        in_plan_frame = bool(plan_output.frame_id) and frame == plan_output.frame_id  # else: the world frame
        tracks = [foreign.moved(track, transform) for track in tracks] if in_plan_frame else tracks
        if contract is topics.PREDICTIONS:  # one time base for all, from the sweep on (the scorer needs it)
            step_ns = round(plan_output.step * NS_PER_S)
            grid = sweep_ns + step_ns * np.arange(plan_output.num_steps + 1, dtype=np.int64)
            tracks = [foreign.on_grid(track, grid) for track in tracks]
        else:
            tracks = [foreign.on_grid(track, [sweep_ns]) for track in tracks]
        return track_array_msg(tracks, sweep_ns, world)
