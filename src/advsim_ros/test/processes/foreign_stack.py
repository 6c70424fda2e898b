"""Test process: stacks as third parties write them, attached only through a stack profile.

Two dialects, chosen by the first argument; both plan on a 10 Hz timer of their own (sim clock)
and stamp their answer with that clock, not with the sweep:

- ``gnss``: reads the LiDAR on /points_raw and its position from sensor_msgs/NavSatFix on /fix,
  anchors a `map` frame (east-north-up) at its first fix, and publishes a *spatial* nav_msgs/Path
  (poses without times, 20 m ahead along its heading from the last two fixes) in `map` on
  /gnss_planner/path.
- ``autoware``: reads /sensing/lidar/concatenated/pointcloud and /localization/kinematic_state
  (nav_msgs/Odometry in `map`) and publishes autoware_planning_msgs/Trajectory (points with speeds,
  no times) on /planning/scenario_planning/trajectory.

Both slow down when LiDAR points lie in a corridor ahead, so that what the attack moves matters.
"""

from __future__ import annotations

import math
import sys

import numpy as np
import pymap3d
import rclpy
from geometry_msgs.msg import Pose, PoseStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import NavSatFix, PointCloud2

from advsim_ros.contract.pointcloud import cloud_to_points

LOOKAHEAD = 60.0  # [m]
SPACING = 1.0  # [m] between path poses


def _pose(x: float, y: float, yaw: float) -> Pose:
    pose = Pose()
    pose.position.x, pose.position.y = x, y
    pose.orientation.z, pose.orientation.w = math.sin(yaw / 2.0), math.cos(yaw / 2.0)
    return pose


class ForeignStack(Node):
    def __init__(self, dialect: str) -> None:
        super().__init__(f"{dialect}_planner")
        self.dialect = dialect
        self.blocked = False  # something in the corridor ahead in the latest sweep
        self.position: tuple[float, float] | None = None  # in `map` [m]
        self.previous: tuple[float, float] | None = None
        self.yaw = 0.0
        self.speed = 0.0
        self.origin: tuple[float, float, float] | None = None  # the first fix (gnss)
        if dialect == "gnss":
            self.create_subscription(PointCloud2, "/points_raw", self.on_sweep, qos_profile_sensor_data)
            self.create_subscription(NavSatFix, "/fix", self.on_fix, 10)
            self.publisher = self.create_publisher(PathMsg, "/gnss_planner/path", 10)
        else:
            from autoware_planning_msgs.msg import Trajectory

            self.create_subscription(
                PointCloud2, "/sensing/lidar/concatenated/pointcloud", self.on_sweep, qos_profile_sensor_data
            )
            self.create_subscription(Odometry, "/localization/kinematic_state", self.on_state, 10)
            self.publisher = self.create_publisher(Trajectory, "/planning/scenario_planning/trajectory", 10)
        self.create_timer(0.1, self.on_timer)  # on the sim clock (use_sim_time from the profile)

    def on_sweep(self, cloud: PointCloud2) -> None:
        points = cloud_to_points(cloud)
        x, y, z = (np.asarray(points[axis], dtype=np.float64) for axis in "xyz")
        ahead = (x > 2.0) & (x < 20.0) & (np.abs(y) < 1.5) & (z > -1.2)
        self.blocked = int(np.count_nonzero(ahead)) > 30

    def on_fix(self, fix: NavSatFix) -> None:
        if self.origin is None:
            self.origin = (fix.latitude, fix.longitude, fix.altitude)
        east, north, _ = pymap3d.geodetic2enu(fix.latitude, fix.longitude, fix.altitude, *self.origin)
        self._moved_to(float(east), float(north))

    def on_state(self, state: Odometry) -> None:
        self._moved_to(state.pose.pose.position.x, state.pose.pose.position.y)
        self.speed = math.hypot(state.twist.twist.linear.x, state.twist.twist.linear.y)

    def _moved_to(self, x: float, y: float) -> None:
        if self.position is not None and math.hypot(x - self.position[0], y - self.position[1]) > 0.05:
            self.previous = self.position
            self.yaw = math.atan2(y - self.position[1], x - self.position[0])
        self.position = (x, y)

    def on_timer(self) -> None:
        if self.position is None or self.previous is None:
            return  # no heading yet
        reach = 6.0 if self.blocked else LOOKAHEAD  # a spatial plan that ends early is one that stops
        distances = np.arange(0.0, reach + 1e-9, SPACING)
        x0, y0 = self.position
        poses = [_pose(x0 + d * math.cos(self.yaw), y0 + d * math.sin(self.yaw), self.yaw) for d in distances]
        stamp = self.get_clock().now().to_msg()
        if self.dialect == "gnss":
            path = PathMsg()
            path.header.stamp, path.header.frame_id = stamp, "map"
            for pose in poses:
                item = PoseStamped()
                item.header.frame_id = "map"  # no per-pose times: a spatial path
                item.pose = pose
                path.poses.append(item)
            self.publisher.publish(path)
            return
        from autoware_planning_msgs.msg import Trajectory, TrajectoryPoint

        trajectory = Trajectory()
        trajectory.header.stamp, trajectory.header.frame_id = stamp, "map"
        for index, pose in enumerate(poses):
            point = TrajectoryPoint()
            point.pose = pose
            last = index == len(poses) - 1
            point.longitudinal_velocity_mps = 0.0 if last and self.blocked else float(self.speed)
            trajectory.points.append(point)
        self.publisher.publish(trajectory)


def main() -> None:
    rclpy.init()
    node = ForeignStack(sys.argv[1] if len(sys.argv) > 1 and not sys.argv[1].startswith("-") else "gnss")
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
