"""Test process: a stack that keeps a time gap to what is ahead, the example stack's way (per sweep, contract).

It plans at the ego's speed, or braking at 8 m/s^2 while the nearest LiDAR return in its lane
corridor is closer than 6 m plus 0.5 s at its speed (parameters standstill_gap, time_gap). It
reacts to what the sweep shows *now*: a lead that will brake is not in its plan, so the plan made
before the braking runs into it (open loop), while replanning every sweep it brakes in time
(closed loop).
"""

import math

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from sensor_msgs.msg import PointCloud2

from advsim_ros.contract.pointcloud import cloud_to_points
from advsim_ros.stacks.example import ExampleStack, run

BRAKE = 8.0  # [m/s^2]
STANDSTILL_GAP, TIME_GAP = 6.0, 0.5  # [m], [s]


class GapKeepingStack(ExampleStack):
    def __init__(self) -> None:
        super().__init__("gap_keeping_stack")
        self.standstill_gap = float(self.declare_parameter("standstill_gap", STANDSTILL_GAP).value)
        self.time_gap = float(self.declare_parameter("time_gap", TIME_GAP).value)

    def plan(self, cloud: PointCloud2, odometry: Odometry) -> None:
        pose = odometry.pose.pose
        yaw = 2.0 * math.atan2(pose.orientation.z, pose.orientation.w)
        speed = math.hypot(odometry.twist.twist.linear.x, odometry.twist.twist.linear.y)
        points = cloud_to_points(cloud)
        x, y, z = (np.asarray(points[axis], dtype=np.float64) for axis in "xyz")
        ahead = (x > 2.0) & (x < 60.0) & (np.abs(y) < 1.2) & (z > -1.2)
        gap = float(np.min(x[ahead])) if np.count_nonzero(ahead) > 5 else math.inf
        accel = -BRAKE if gap < self.standstill_gap + self.time_gap * speed else 0.0
        path = PathMsg()
        path.header = cloud.header
        path.header.frame_id = odometry.header.frame_id
        stamp_ns = int(cloud.header.stamp.sec) * 1_000_000_000 + int(cloud.header.stamp.nanosec)
        travelled = 0.0
        for step in range(1, 51):
            t = 0.1 * step
            stop = speed / BRAKE if accel < 0 else math.inf
            travelled = speed * min(t, stop) + 0.5 * accel * min(t, stop) ** 2
            item = PoseStamped()
            item.header.stamp.sec, item.header.stamp.nanosec = divmod(stamp_ns + step * 100_000_000, 1_000_000_000)
            item.header.frame_id = path.header.frame_id
            item.pose.position.x = pose.position.x + travelled * math.cos(yaw)
            item.pose.position.y = pose.position.y + travelled * math.sin(yaw)
            item.pose.orientation = pose.orientation
            path.poses.append(item)
        self.plan_publisher.publish(path)


if __name__ == "__main__":
    run(GapKeepingStack)
