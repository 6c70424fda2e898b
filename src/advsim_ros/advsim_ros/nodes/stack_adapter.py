"""stack_adapter: bridges the contract's topics to a stack with names, types, frames and timing of its own.

Started by ``advsim attack`` when the stack profile (``--stack-profile``, or ``--remap`` rules)
differs from the contract. It never changes what the stack is told, only how it is said:

- renamed topics of the contract's types are relayed byte for byte with the contract's QoS
  (latched stay latched): inputs under the stack's names, answers under the contract's;
- the pose is re-published in the stack's type (Odometry in another frame, PoseStamped,
  PoseWithCovarianceStamped, NavSatFix from the profile's datum) from the contract's odometry;
- the LiDAR sweep gets the stack's sensor frame name, with an identity transform to it on /tf_static;
- the plan, in the stack's type and frame, becomes the contract's plan (adapters.plans). A stack
  planning per sweep stamps its answer with the sweep; a stack planning on its own timer (the
  player then steps /clock) is answered with the plan in force at the sweep's decision time
  (adapters.timing).

Parameters: ``profile_file`` (the profile as the attack wrote it, JSON), ``run_id``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np

from advsim_ros.adapters import messages as foreign
from advsim_ros.adapters.plans import Poses, contract_plan, frame_transform
from advsim_ros.adapters.profile import StackProfile, load_profile
from advsim_ros.adapters.timing import PlanBook
from advsim_ros.contract import codec, names, topics
from advsim_ros.contract.codec import ContractError
from advsim_ros.contract.plan import path_msg
from advsim_ros.contract.spatial import tf_message
from advsim_ros.core.types import ScenarioError
from advsim_ros.ros.graph_node import GraphNode, run_node

NODE_NAME = "stack_adapter"
KEPT_ODOMETRY = 200


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
        self.speeds: dict[int, float] = {}  # odometry stamp -> ego speed
        self.first_fix_xy: np.ndarray | None = None
        self.book: PlanBook[Poses] = PlanBook(self.timing)  # timer mode: which plan answers which sweep
        self.sensor_frames: set[str] = set()
        renamed = self.profile.renamed()
        self._relay(renamed)
        self._adapt_inputs(renamed)
        self._adapt_plan()

    # ------------------------------------------------------------------ relays and inputs

    def _relay(self, renamed: dict[str, str]) -> None:
        """Topics of the contract's types the stack only calls otherwise: relayed byte for byte."""
        converted = {topics.ODOM.name}
        if self.profile.inputs.lidar.frame_id:
            converted.add(topics.LIDAR.name)
        if self._plan_converted():
            converted.add(topics.PLAN.name)
        for contract_name, stack_name in renamed.items():
            if contract_name in converted:
                continue
            spec = topics.stack_topic(contract_name)
            theirs = dataclasses.replace(spec, name=stack_name)
            source, target = (spec, theirs) if spec in topics.STACK_INPUTS else (theirs, spec)
            self.subscribe(source, self.publisher(target), raw=True)
            self.get_logger().info(f"relaying {source.name} -> {target.name} ({spec.msgtype})")

    def _adapt_inputs(self, renamed: dict[str, str]) -> None:
        pose = self.profile.inputs.pose
        self.publish_pose: Any = None
        if pose.type != "odometry" or pose.frame_id or pose.topic != topics.ODOM.name:
            pose_spec = topics.TopicSpec(pose.topic, foreign.POSE_MSGTYPES[pose.type], topics.ODOM.offered)
            self.publish_pose = self.publisher(pose_spec)
            self.get_logger().info(f"pose: {topics.ODOM.name} -> {pose.topic} ({pose_spec.msgtype})")
        self.subscribe(topics.ODOM, self.on_odometry, raw=True)  # also the ego's speed and the frames' stamps
        self.subscribe(topics.CLOCK, self.on_clock, raw=True)
        lidar = self.profile.inputs.lidar
        if lidar.frame_id:
            self.publish_sweep = self.publisher(dataclasses.replace(topics.LIDAR, name=lidar.topic))
            tf_static_name = renamed.get(topics.TF_STATIC.name, topics.TF_STATIC.name)
            self.tf_static_spec = dataclasses.replace(topics.TF_STATIC, name=tf_static_name)
            self.tf_static_publishers: list[Any] = []  # latched: kept alive
            self.subscribe(topics.LIDAR, self.on_sweep, raw=True)
            self.get_logger().info(f"LiDAR: {topics.LIDAR.name} -> {lidar.topic} in frame {lidar.frame_id}")

    def on_clock(self, raw: bytes) -> None:
        self.clock_ns = codec.stamp_ns(codec.decode(raw, names.CLOCK).clock)
        if self.timing.timer:
            self._answer_due()

    def on_odometry(self, raw: bytes) -> None:
        odometry = codec.decode(raw, names.ODOMETRY)
        stamp = codec.stamp_ns(odometry.header.stamp)
        self.world_frame = odometry.header.frame_id
        self.speeds[stamp] = foreign.odometry_speed(odometry)
        while len(self.speeds) > KEPT_ODOMETRY:
            del self.speeds[min(self.speeds)]
        pose = self.profile.inputs.pose
        if pose.type == "navsatfix" and self.first_fix_xy is None:
            self.first_fix_xy = foreign.odometry_xy(odometry)
        if self.publish_pose is not None:
            self.publish_pose(foreign.pose_input(pose.type, odometry, pose.frame_id, pose.datum))
        if self.timing.timer:
            self.book.sweep(stamp)

    def on_sweep(self, raw: bytes) -> None:
        cloud = codec.decode(raw, names.POINTCLOUD2)
        frame = self.profile.inputs.lidar.frame_id
        if cloud.header.frame_id not in self.sensor_frames:  # the stack's frame is where the sweep's is
            self.sensor_frames.add(cloud.header.frame_id)
            transform = tf_message(codec.stamp_ns(cloud.header.stamp), cloud.header.frame_id, frame, np.eye(4))
            self.tf_static_publishers.append(self.latch(self.tf_static_spec, transform))
        cloud = dataclasses.replace(cloud, header=codec.header_msg(codec.stamp_ns(cloud.header.stamp), frame))
        self.publish_sweep(codec.encode(cloud))

    # ------------------------------------------------------------------ the plan

    def _adapt_plan(self) -> None:
        if not self._plan_converted():
            return  # relayed as it is when renamed
        output = self.plan_output
        theirs = topics.TopicSpec(output.topic, foreign.PLAN_MSGTYPES[output.type], topics.PLAN.offered)
        self.publish_plan = self.publisher(topics.PLAN)
        self.subscribe(theirs, self.on_plan, raw=True)
        mode = f"timer (decision delay {self.timing.decision_delay} s)" if self.timing.timer else "per sweep"
        self.get_logger().info(f"plan: {output.topic} ({output.type}, frame {output.frame_id or 'world'}, {mode})")

    def _plan_converted(self) -> bool:
        return self.plan_output.type != "path" or self.plan_output.frame_origin != "world" or self.timing.timer

    def on_plan(self, raw: bytes) -> None:
        output = self.plan_output
        try:
            msg = codec.decode(raw, foreign.PLAN_MSGTYPES[output.type])
            frame = msg.header.frame_id
            if output.frame_id and frame and frame != output.frame_id:
                raise ContractError(f"the plan is in frame {frame!r}, the profile says {output.frame_id!r}")
            poses = foreign.plan_poses(output.type, msg)
        except (ScenarioError, ValueError) as error:
            self.get_logger().error(f"unusable plan on {output.topic}: {error}")
            return
        stamp = codec.stamp_ns(msg.header.stamp)
        if not self.timing.timer:
            self._publish(stamp, stamp, poses)
            return
        made = self.clock_ns if self.timing.plan_stamp == "arrival" else stamp
        self.book.plan(made, poses)
        self._answer_due()

    def _answer_due(self) -> None:
        for sweep, made, poses in self.book.due(self.clock_ns):
            self._publish(sweep, made, poses)

    def _publish(self, sweep_ns: int, made_ns: int, poses: Poses) -> None:
        output = self.plan_output
        try:
            transform = frame_transform(output, self.profile.inputs.pose.datum, self.first_fix_xy)
        except ScenarioError as error:
            self.get_logger().error(f"plan for sweep {sweep_ns}: {error}")
            return
        known = [s for s in self.speeds if s <= made_ns]
        speed = self.speeds[max(known)] if known else 0.0
        plan = contract_plan(poses, made_ns, sweep_ns, speed, output, transform)
        self.publish_plan(path_msg(plan, sweep_ns, self.world_frame or "world"))


def main() -> None:
    run_node(StackAdapter)


if __name__ == "__main__":
    main()
