"""The ROS node around a reference stack: topics in, one stack step per sweep, topics out.

Subscribes to the LiDAR (sensor-data QoS), the ego odometry, /tf_static (for the ego ->
sensor mount) and the road map; a sweep is planned from as soon as the odometry for its
stamp is there (sweeps may arrive before or after their odometry) and the sensor mount is
known (from /tf_static, or the io.sensor_mount parameter with io.mount_source: parameter). Publishes for every
sweep a nav_msgs/Path in the odometry's world frame stamped with the sweep's stamp and,
when the stack makes them, its detections and predictions. Parameters are the stack's
config sections, declared as dotted ROS parameters (params/stack_*.yaml).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from typing import Generic, Protocol, TypeVar

from nav_msgs.msg import Odometry, Path
from rclpy.clock import Clock
from rclpy.clock_type import ClockType
from rclpy.node import Node
from sensor_msgs.msg import PointCloud2
from tf2_msgs.msg import TFMessage

from advsim_msgs.msg import ActorTrackArray, RoadMap
from advsim_ros.contract import qos, topics
from advsim_ros.contract.codec import stamp_ns
from advsim_ros.contract.pointcloud import cloud_to_points
from advsim_ros.contract.scenario import road_map_from_msg
from advsim_ros.contract.spatial import transforms_of
from advsim_ros.core.types import FloatArray, ScenarioError
from advsim_ros.ros.graph_node import TypedNode
from advsim_ros.ros.params import declare_config
from advsim_ros.ros.qos import profile
from advsim_ros.ros.trace import Trace
from advsim_ros.stacks.interface import AutonomyStack, EgoMotion, StackFrame, TopicIoConfig, points_xyz
from advsim_ros.stacks.params import section_types
from advsim_ros.stacks.ros_io import PoseBuffer, mount_matrix, output_messages


class StackConfig(Protocol):
    """A reference stack's sectioned config: its sections, the topic I/O among them."""

    @property
    def io(self) -> TopicIoConfig: ...


ConfigT = TypeVar("ConfigT", bound=StackConfig)


def declare_sections(node: Node, config_type: type[ConfigT]) -> ConfigT:
    """A sectioned stack config from ROS parameters `<section>.<key>` (defaults: the dataclasses')."""
    return config_type(
        **{name: declare_config(node, section, f"{name}.") for name, section in section_types(config_type).items()}
    )


class StackNode(TypedNode, Generic[ConfigT]):
    """One reference stack as a ROS node."""

    def __init__(self, name: str, make_stack: Callable[[ConfigT], AutonomyStack], config_type: type[ConfigT]) -> None:
        super().__init__(name)
        self.config = declare_sections(self, config_type)
        io: TopicIoConfig = self.config.io
        self._io = io
        self.stack = make_stack(self.config)
        self._poses = PoseBuffer(io.odometry_buffer)
        self._pending: deque[PointCloud2] = deque()
        self._static: dict[tuple[str, str], FloatArray] = {}
        self._fallback_mount = mount_matrix(io.sensor_mount)
        self._warned_mount = False
        self._first_cloud_at: float | None = None  # wall clock of the first sweep, for io.mount_wait_s
        self.trace = Trace(name)
        # outputs are published as CDR built by the contract's builders
        self._publish_plan = self.create_publisher(Path, topics.PLAN.name, profile(topics.PLAN.offered)).publish
        # detections and predictions only from a stack that has them: the player waits for what is offered
        self._publish_detections = self._publish_predictions = None
        if self.stack.perceives:
            self._publish_detections = self.create_publisher(
                ActorTrackArray, topics.DETECTIONS.name, profile(topics.DETECTIONS.offered)
            ).publish
            self._publish_predictions = self.create_publisher(
                ActorTrackArray, topics.PREDICTIONS.name, profile(topics.PREDICTIONS.offered)
            ).publish
        self.create_subscription(TFMessage, topics.TF_STATIC.name, self._on_tf_static, profile(qos.LATCHED))
        self.create_subscription(RoadMap, topics.MAP.name, self._on_map, profile(qos.LATCHED))
        self.create_subscription(Odometry, topics.ODOM.name, self._on_odometry, profile(qos.STREAM))
        self.create_subscription(PointCloud2, topics.LIDAR.name, self._on_cloud, profile(qos.SENSOR_DATA))
        # Sweeps waiting for /tf_static must be planned from once the wait is over, even if nothing else arrives.
        self.create_timer(0.1, self._process_pending, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(f"{self.stack.name} stack ready")

    def _on_tf_static(self, message: TFMessage) -> None:
        self._static.update(transforms_of(message))
        self._process_pending()  # sweeps that waited for the mount

    def _on_map(self, message: RoadMap) -> None:
        try:
            self.stack.set_road_map(road_map_from_msg(message))
        except ScenarioError as error:
            self.get_logger().error(f"road map ignored: {error}")

    def _on_odometry(self, message: Odometry) -> None:
        try:
            self._poses.add_odometry(message)
        except ScenarioError as error:
            self.get_logger().error(f"odometry ignored: {error}")
            return
        self._process_pending()

    def _on_cloud(self, message: PointCloud2) -> None:
        self.trace("sweep_received")
        if self._first_cloud_at is None:
            self._first_cloud_at = time.monotonic()
        self._pending.append(message)
        while len(self._pending) > self._io.max_pending:
            dropped = self._pending.popleft()
            self.get_logger().warning(f"no odometry for the sweep at {stamp_ns(dropped.header.stamp)} ns: dropped")
        self._process_pending()

    def _static_mount(self, sensor_frame: str) -> FloatArray | None:
        """ego -> sensor from /tf_static (direct, or through one intermediate frame)."""
        ego_frame = self._poses.ego_frame
        if (ego_frame, sensor_frame) in self._static:
            return self._static[(ego_frame, sensor_frame)]
        for (parent, child), first in self._static.items():
            if parent == ego_frame and (child, sensor_frame) in self._static:
                result: FloatArray = first @ self._static[(child, sensor_frame)]
                return result
        return None

    def _mount(self, sensor_frame: str) -> FloatArray | None:
        """ego -> sensor from /tf_static (None: wait for it), or io.sensor_mount when io.mount_source says so.

        Never a timed fallback: a plan must not depend on whether /tf_static happened to arrive in time.
        """
        if self._io.mount_source == "parameter":
            return self._fallback_mount
        found = self._static_mount(sensor_frame)
        waited = time.monotonic() - (self._first_cloud_at or time.monotonic())
        if found is None and waited >= self._io.mount_wait_s and not self._warned_mount:
            self.get_logger().warning(
                f"still no /tf_static transform {self._poses.ego_frame} -> {sensor_frame} after "
                f"{self._io.mount_wait_s} s: sweeps wait for it (or set io.mount_source: parameter)"
            )
            self._warned_mount = True
        return found

    def _process_pending(self) -> None:
        tolerance = int(self._io.pose_tolerance_s * 1e9)
        while self._pending:
            cloud = self._pending[0]
            stamp = stamp_ns(cloud.header.stamp)
            mount = self._mount(str(cloud.header.frame_id))
            if mount is None:
                return  # wait for /tf_static a little longer
            found = self._poses.lookup(stamp, tolerance)
            if found is None:
                newest = self._poses.newest_ns
                if newest is not None and newest > stamp + tolerance:
                    self._pending.popleft()  # its odometry is past and was never seen
                    self.get_logger().warning(f"no odometry at the sweep's stamp {stamp} ns: dropped")
                    continue
                return  # wait for the odometry of this stamp
            self._pending.popleft()
            self._plan(cloud, stamp, mount, *found)

    def _plan(
        self, cloud: PointCloud2, stamp: int, mount: FloatArray, world_T_ego: FloatArray, motion: EgoMotion
    ) -> None:
        self.trace("planning")
        try:
            frame = StackFrame(
                stamp_ns=stamp,
                xyz=points_xyz(cloud_to_points(cloud)),
                world_T_ego=world_T_ego,
                ego_T_sensor=mount,
                motion=motion,
            )
            output = self.stack.step(frame)
        except ScenarioError as error:
            self.get_logger().error(f"sweep at {stamp} ns: {error}")
            return
        plan, detections, predictions = output_messages(output, stamp, self._poses.world_frame)
        self.trace("stepped")
        self._publish_plan(plan)
        if detections is not None and self._publish_detections is not None:
            self._publish_detections(detections)
        if predictions is not None and self._publish_predictions is not None:
            self._publish_predictions(predictions)
        self.trace("published")
        total = output.timings_s.get("total", float("nan"))
        self.get_logger().debug(f"planned from the sweep at {stamp} ns in {1000.0 * total:.1f} ms")
