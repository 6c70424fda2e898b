"""A minimal stack under test, written the way a user writes one with plain rclpy: a template.

It honours the topic contract (README, "Connecting your own stack"): for every LiDAR sweep on
/sensor/lidar/points it publishes a nav_msgs/Path on /planning/trajectory, stamped with the sweep's
stamp, 50 poses 0.1 s apart in the odometry's frame. Its "planning" is a constant-velocity
rollout of the latest /ego/odom that slows down when LiDAR points lie in a corridor ahead, so
what the attack does to the LiDAR changes its plan. Run it alone with
`python -m advsim_ros.stacks.example --ros-args -p use_sim_time:=true`.
"""

import math
from collections.abc import Callable

import numpy as np
import rclpy
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header

from advsim_ros.contract.pointcloud import cloud_to_points


class ExampleStack(Node):
    def __init__(
        self,
        name: str = "example_stack",
        lidar_topic: str = "/sensor/lidar/points",
        odometry_topic: str = "/ego/odom",
        plan_topic: str = "/planning/trajectory",
    ) -> None:
        super().__init__(name)
        self.sweeps = 0
        # sweeps and odometry come on different topics, in either order: pair them by stamp
        self.odometry: dict[int, Odometry] = {}
        self.pending: dict[int, PointCloud2] = {}
        self.plan_publisher = self.create_publisher(PathMsg, plan_topic, 10)
        self.create_subscription(Odometry, odometry_topic, self.on_odometry, 10)
        self.create_subscription(PointCloud2, lidar_topic, self.on_sweep, qos_profile_sensor_data)

    def on_odometry(self, message: Odometry) -> None:
        stamp = _stamp_ns(message.header)
        self.odometry[stamp] = message
        if stamp in self.pending:
            self.plan(self.pending.pop(stamp), message)
        for old in [s for s in self.odometry if s < stamp - 2_000_000_000]:  # keep 2 s
            del self.odometry[old]

    def on_sweep(self, cloud: PointCloud2) -> None:
        self.sweeps += 1
        stamp = _stamp_ns(cloud.header)
        if stamp in self.odometry:
            self.plan(cloud, self.odometry[stamp])
        else:
            self.pending = {s: c for s, c in self.pending.items() if s > stamp - 2_000_000_000}
            self.pending[stamp] = cloud

    def plan(self, cloud: PointCloud2, odometry: Odometry) -> None:
        pose = odometry.pose.pose
        yaw = 2.0 * math.atan2(pose.orientation.z, pose.orientation.w)
        speed = math.hypot(odometry.twist.twist.linear.x, odometry.twist.twist.linear.y)
        points = cloud_to_points(cloud)
        xyz = np.stack([points["x"], points["y"], points["z"]], axis=-1).astype(np.float64)
        ahead = (xyz[:, 0] > 2.0) & (xyz[:, 0] < 20.0) & (np.abs(xyz[:, 1]) < 1.5) & (xyz[:, 2] > -1.2)
        if np.count_nonzero(ahead) > 30:  # something in the corridor: stop within the horizon
            speed *= 0.3
        path = PathMsg()
        path.header = cloud.header
        path.header.frame_id = odometry.header.frame_id
        stamp_ns = _stamp_ns(cloud.header)
        for step in range(1, 51):
            t = 0.1 * step
            item = PoseStamped()
            future = stamp_ns + step * 100_000_000
            item.header.stamp.sec, item.header.stamp.nanosec = divmod(future, 1_000_000_000)
            item.header.frame_id = path.header.frame_id
            item.pose.position.x = pose.position.x + speed * t * math.cos(yaw)
            item.pose.position.y = pose.position.y + speed * t * math.sin(yaw)
            item.pose.orientation = pose.orientation
            path.poses.append(item)
        self.plan_publisher.publish(path)


def _stamp_ns(header: Header) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def main() -> None:
    run(ExampleStack)


def run(factory: Callable[[], Node]) -> None:
    """Spin a stack node until SIGINT/SIGTERM."""
    rclpy.init()
    node = factory()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()  # type: ignore[attr-defined]  # rclpy re-exports it without listing it in __all__


if __name__ == "__main__":
    main()
