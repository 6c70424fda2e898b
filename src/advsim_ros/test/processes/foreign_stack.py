"""Test process: stacks as third parties write them, attached only through a stack profile.

Two dialects, chosen by the first argument; both plan on a 10 Hz timer of their own (sim clock)
and stamp their answer with that clock, not with the sweep:

- ``gnss``: reads the LiDAR on /points_raw and its position from sensor_msgs/NavSatFix on /fix,
  anchors a `map` frame (east-north-up) at its first fix, and publishes a *spatial* nav_msgs/Path
  (poses without times, 60 m ahead along its heading from the last two fixes) in `map` on
  /gnss_planner/path, with best-effort QoS. A second argument ``headingless`` leaves the poses'
  orientations unset (identity quaternions), as many spatial planners do.
- ``autoware``: reads /sensing/lidar/concatenated/pointcloud and /localization/kinematic_state
  (nav_msgs/Odometry in `map`) and publishes autoware_planning_msgs/Trajectory (points with speeds,
  no times) on /planning/scenario_planning/trajectory, with what blocks its corridor as
  autoware_perception_msgs DetectedObjects and PredictedObjects (standing still) in `map`.

Both slow down when LiDAR points lie in a corridor ahead, so that what the attack moves matters.
"""

from __future__ import annotations

import math
import sys

import numpy as np
import pymap3d
from geometry_msgs.msg import Pose, PoseStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import NavSatFix, PointCloud2

from advsim_ros.contract.pointcloud import cloud_to_points
from advsim_ros.stacks.example import run

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
        self.headingless = "headingless" in sys.argv[2:]
        self.blocked = False  # something in the corridor ahead in the latest sweep
        self.obstacle: tuple[float, float] | None = None  # its centroid in the sensor frame [m]
        self.position: tuple[float, float] | None = None  # in `map` [m]
        self.previous: tuple[float, float] | None = None
        self.yaw = 0.0
        self.speed = 0.0
        self.origin: tuple[float, float, float] | None = None  # the first fix (gnss)
        self.counts = {"sweeps": 0, "poses": 0, "ticks": 0, "plans": 0}  # logged at the first of each, for diagnosis
        if dialect == "gnss":
            self.create_subscription(PointCloud2, "/points_raw", self.on_sweep, qos_profile_sensor_data)
            self.create_subscription(NavSatFix, "/fix", self.on_fix, 10)
            # best effort, as some planners publish: the profile says so and the adapter reads it that way
            self.publisher = self.create_publisher(PathMsg, "/gnss_planner/path", qos_profile_sensor_data)
        else:
            from autoware_planning_msgs.msg import Trajectory

            self.create_subscription(
                PointCloud2, "/sensing/lidar/concatenated/pointcloud", self.on_sweep, qos_profile_sensor_data
            )
            self.create_subscription(Odometry, "/localization/kinematic_state", self.on_state, 10)
            self.create_subscription(PointCloud2, "/sensing/lidar/top/pointcloud", self.on_top, qos_profile_sensor_data)
            self.top_sweeps = 0
            from autoware_perception_msgs.msg import DetectedObjects, PredictedObjects

            self.publisher = self.create_publisher(Trajectory, "/planning/scenario_planning/trajectory", 10)
            objects = "/perception/object_recognition"
            self.detections = self.create_publisher(DetectedObjects, f"{objects}/detection/objects", 10)
            self.predictions = self.create_publisher(PredictedObjects, f"{objects}/objects", 10)
        self.create_timer(0.1, self.on_timer)  # on the sim clock (use_sim_time from the profile)

    def _count(self, event: str) -> None:
        """Logs the 1st, 50th and every 200th of each event, so that a run that answered nothing says how far it got."""
        self.counts[event] += 1
        if self.counts[event] in (1, 50) or self.counts[event] % 200 == 0:
            now = self.get_clock().now().nanoseconds / 1e9
            self.get_logger().info(f"{event} {self.counts} at clock {now:.2f} s")

    def on_sweep(self, cloud: PointCloud2) -> None:
        self._count("sweeps")
        points = cloud_to_points(cloud)
        x, y, z = (np.asarray(points[axis], dtype=np.float64) for axis in "xyz")
        ahead = (x > 2.0) & (x < 20.0) & (np.abs(y) < 1.5) & (z > -1.2)
        self.blocked = int(np.count_nonzero(ahead)) > 30
        # a car-sized box behind the nearest returns ahead (what a rear bumper's returns belong to)
        self.obstacle = (float(np.min(x[ahead])) + 2.25, float(np.mean(y[ahead]))) if self.blocked else None

    def on_top(self, cloud: PointCloud2) -> None:
        """The per-sensor topic, as Autoware's concatenation node reads it: counted, to show it is fed."""
        self.top_sweeps += 1
        if self.top_sweeps == 1:
            self.get_logger().info(f"per-sensor sweep received in frame {cloud.header.frame_id}")

    def on_fix(self, fix: NavSatFix) -> None:
        self._count("poses")
        if self.origin is None:
            self.origin = (fix.latitude, fix.longitude, fix.altitude)
        east, north, _ = pymap3d.geodetic2enu(fix.latitude, fix.longitude, fix.altitude, *self.origin)
        self._moved_to(float(east), float(north))

    def on_state(self, state: Odometry) -> None:
        self._count("poses")
        self._moved_to(state.pose.pose.position.x, state.pose.pose.position.y)
        self.speed = math.hypot(state.twist.twist.linear.x, state.twist.twist.linear.y)

    def _moved_to(self, x: float, y: float) -> None:
        if self.position is not None and math.hypot(x - self.position[0], y - self.position[1]) > 0.05:
            self.previous = self.position
            self.yaw = math.atan2(y - self.position[1], x - self.position[0])
        self.position = (x, y)

    def on_timer(self) -> None:
        self._count("ticks")
        if self.position is None or self.previous is None:
            return  # no heading yet
        reach = 6.0 if self.blocked else LOOKAHEAD  # a spatial plan that ends early is one that stops
        distances = np.arange(0.0, reach + 1e-9, SPACING)
        x0, y0 = self.position
        poses = [_pose(x0 + d * math.cos(self.yaw), y0 + d * math.sin(self.yaw), self.yaw) for d in distances]
        stamp = self.get_clock().now().to_msg()
        self._count("plans")
        if self.dialect == "gnss":
            path = PathMsg()
            path.header.stamp, path.header.frame_id = stamp, "map"
            for pose in poses:
                item = PoseStamped()
                item.header.frame_id = "map"  # no per-pose times: a spatial path
                item.pose.position = pose.position  # orientation left as it comes (identity) when headingless
                if not self.headingless:
                    item.pose.orientation = pose.orientation
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
        self.publish_objects(stamp)

    def publish_objects(self, stamp: object) -> None:
        """What blocks the corridor as one car-sized object in `map`, predicted to stand still for 5 s."""
        from autoware_perception_msgs.msg import (
            DetectedObject,
            DetectedObjects,
            ObjectClassification,
            PredictedObject,
            PredictedObjects,
            PredictedPath,
        )

        detected, predicted = DetectedObjects(), PredictedObjects()
        for message in (detected, predicted):
            message.header.stamp, message.header.frame_id = stamp, "map"
        if self.obstacle is not None and self.position is not None:
            ahead, left = self.obstacle
            x0, y0 = self.position
            pose = _pose(
                x0 + ahead * math.cos(self.yaw) - left * math.sin(self.yaw),
                y0 + ahead * math.sin(self.yaw) + left * math.cos(self.yaw),
                self.yaw,
            )
            label = ObjectClassification(label=ObjectClassification.CAR, probability=1.0)
            item = DetectedObject(existence_probability=0.9, classification=[label])
            item.kinematics.pose_with_covariance.pose = pose
            item.shape.dimensions.x, item.shape.dimensions.y, item.shape.dimensions.z = 4.5, 1.8, 1.5
            detected.objects.append(item)
            path = PredictedPath(path=[pose] * 11, confidence=1.0)
            path.time_step.nanosec = 500_000_000
            future = PredictedObject(existence_probability=0.9, classification=[label], shape=item.shape)
            future.kinematics.initial_pose_with_covariance.pose = pose
            future.kinematics.predicted_paths.append(path)
            predicted.objects.append(future)
        self.detections.publish(detected)
        self.predictions.publish(predicted)


def main() -> None:
    dialect = sys.argv[1] if len(sys.argv) > 1 and not sys.argv[1].startswith("-") else "gnss"
    run(lambda: ForeignStack(dialect))


if __name__ == "__main__":
    main()
