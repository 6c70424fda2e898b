"""Test process: a minimal stack under test, written the way a user would write one with rclpy.

It plans, for every LiDAR sweep, a constant-velocity path from the latest odometry, stamped with
the sweep's stamp; it brakes when LiDAR points lie in a corridor ahead, so perturbed actors matter.
Faults for tests, each happening once per marker file: `crash_at_sweep` makes the process exit
with code 3 at that sweep, `hang_at_sweep` makes it stop answering for `hang_seconds`.
"""

import math
import os
import time
from pathlib import Path

import numpy as np
import rclpy
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import PointCloud2

from advsim_ros.io.pointcloud import cloud_to_points


class SimpleStack(Node):
    def __init__(self) -> None:
        super().__init__("simple_stack")
        self.crash_at = self.declare_parameter("crash_at_sweep", -1).value
        self.hang_at = self.declare_parameter("hang_at_sweep", -1).value
        self.hang_seconds = self.declare_parameter("hang_seconds", 30.0).value
        self.marker_dir = Path(self.declare_parameter("marker_dir", "/tmp").value)
        self.sweeps = 0
        self.odometry: Odometry | None = None
        self.plan_publisher = self.create_publisher(PathMsg, "/planning/trajectory", 10)
        self.create_subscription(Odometry, "/ego/odom", self.on_odometry, 10)
        self.create_subscription(PointCloud2, "/sensor/lidar/points", self.on_sweep, qos_profile_sensor_data)

    def on_odometry(self, message: Odometry) -> None:
        self.odometry = message

    def _fault_once(self, name: str) -> bool:
        marker = self.marker_dir / f"{name}.done"
        if marker.exists():
            return False
        marker.write_text("done")
        return True

    def on_sweep(self, cloud: PointCloud2) -> None:
        self.sweeps += 1
        if self.sweeps == self.crash_at and self._fault_once("crash"):
            os._exit(3)  # a hard crash: no clean shutdown
        if self.sweeps == self.hang_at and self._fault_once("hang"):
            time.sleep(self.hang_seconds)  # a stack stuck in its own computation
        odometry = self.odometry
        if odometry is None:
            return
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
        stamp_ns = cloud.header.stamp.sec * 1_000_000_000 + cloud.header.stamp.nanosec
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


def main() -> None:
    rclpy.init()
    node = SimpleStack()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
