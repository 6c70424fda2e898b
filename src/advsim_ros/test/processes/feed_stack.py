"""Test process: play real KITTI sweeps and odometry to a stack over the topic contract, record its answers.

Usage: feed_stack.py KITTI_ROOT FIRST_FRAME NUM_SWEEPS OUTPUT_JSON [objects]
  ("objects": the stack also publishes detections and predictions; wait for the last sweep's)

Publishes /tf_static (ego -> Velodyne), then for each sweep /clock, /ego/odom and the
PointCloud2 on /sensor/lidar/points, and waits for the stack's Path stamped with that
sweep's stamp before the next one (lock-step, as the scenario player does). Writes every
Path, detection and prediction message received, then exits 0. A sweep whose plan does
not come is sent again (the LiDAR topic is best effort); the test bounds the total time.
"""

import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import rclpy
from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import PointCloud2, PointField
from tf2_msgs.msg import TFMessage

from advsim_msgs.msg import ActorTrackArray
from advsim_ros.contract import qos, topics
from advsim_ros.contract.pointcloud import points_are_bigendian, points_to_cloud_fields
from advsim_ros.io.kitti import load_kitti_tracking
from advsim_ros.ros.messages import message_to_dict
from advsim_ros.ros.qos import profile

WORLD, EGO, SENSOR = "world", "base_link", "velodyne"
RESEND_AFTER = 5.0  # [s] without the plan for the current sweep: send it again (a lost best-effort sample)


def _time(stamp_ns: int):
    from builtin_interfaces.msg import Time

    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


def _pose(target, matrix) -> None:
    x, y, z, w = Rotation.from_matrix(matrix[:3, :3]).as_quat()
    target.orientation.x, target.orientation.y, target.orientation.z, target.orientation.w = x, y, z, w


def _cloud(points: np.ndarray, stamp_ns: int) -> PointCloud2:
    specs, point_step = points_to_cloud_fields(points)
    message = PointCloud2()
    message.header.stamp = _time(stamp_ns)
    message.header.frame_id = SENSOR
    message.height, message.width = 1, int(points.shape[0])
    message.fields = [PointField(name=s.name, offset=s.offset, datatype=s.datatype, count=s.count) for s in specs]
    message.is_bigendian = points_are_bigendian(points)
    message.point_step = point_step
    message.row_step = point_step * int(points.shape[0])
    message.data = points.tobytes()
    message.is_dense = True
    return message


def _odometry(pose: np.ndarray, stamp_ns: int) -> Odometry:
    message = Odometry()
    message.header.stamp = _time(stamp_ns)
    message.header.frame_id = WORLD
    message.child_frame_id = EGO
    position = message.pose.pose.position
    position.x, position.y, position.z = (float(v) for v in pose[:3, 3])
    _pose(message.pose.pose, pose)
    return message


def main() -> None:
    root, first, count, output = Path(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), Path(sys.argv[4])
    expect_objects = sys.argv[5:] == ["objects"]
    scenario = load_kitti_tracking(root, "0000")
    rclpy.init()
    node = Node("stack_feeder")
    publish_cloud = node.create_publisher(PointCloud2, topics.LIDAR.name, profile(qos.SENSOR_DATA))
    publish_odometry = node.create_publisher(Odometry, topics.ODOM.name, profile(qos.STREAM))
    publish_clock = node.create_publisher(Clock, topics.CLOCK.name, profile(qos.CLOCK))
    publish_static = node.create_publisher(TFMessage, topics.TF_STATIC.name, profile(qos.LATCHED))
    received: dict[str, list] = {"plans": [], "detections": [], "predictions": []}
    node.create_subscription(
        PathMsg, topics.PLAN.name, lambda m: received["plans"].append(message_to_dict(m)), profile(qos.STREAM)
    )
    for key, topic in (("detections", topics.DETECTIONS.name), ("predictions", topics.PREDICTIONS.name)):
        node.create_subscription(
            ActorTrackArray, topic, lambda m, key=key: received[key].append(message_to_dict(m)), profile(qos.STREAM)
        )
    mount = TransformStamped()
    mount.header.frame_id, mount.child_frame_id = EGO, SENSOR
    mount.transform.translation.x, mount.transform.translation.y, mount.transform.translation.z = (
        float(v) for v in scenario.ego_T_sensor[:3, 3]
    )
    x, y, z, w = Rotation.from_matrix(scenario.ego_T_sensor[:3, :3]).as_quat()
    mount.transform.rotation.x, mount.transform.rotation.y, mount.transform.rotation.z, mount.transform.rotation.w = (
        x, y, z, w,
    )  # fmt: skip
    publish_static.publish(TFMessage(transforms=[mount]))
    # The stack is there once it listens to the LiDAR and advertises the plan (as the scenario player checks).
    print("feed_stack: waiting for the stack", file=sys.stderr, flush=True)
    while publish_cloud.get_subscription_count() < 1 or node.count_publishers(topics.PLAN.name) < 1:
        rclpy.spin_once(node, timeout_sec=0.1)
    print("feed_stack: the stack is up", file=sys.stderr, flush=True)
    sent = []
    for index in range(first, first + count):
        stamp = int(scenario.frame_stamps_ns[index])
        sweep = scenario.sweeps[index]
        while True:
            publish_clock.publish(Clock(clock=_time(stamp)))
            publish_odometry.publish(_odometry(scenario.ego.poses[index], stamp))
            publish_cloud.publish(_cloud(sweep.points, stamp))
            print(f"feed_stack: sent frame {index} stamped {stamp}", file=sys.stderr, flush=True)
            deadline = time.monotonic() + RESEND_AFTER
            answered = False
            while time.monotonic() < deadline:
                rclpy.spin_once(node, timeout_sec=0.05)
                if any(_stamp(plan["header"]["stamp"]) == stamp for plan in received["plans"]):
                    answered = True
                    break
            if answered:
                break
        sent.append({"frame": index, "stamp_ns": stamp, "ego_xy": scenario.ego.poses[index][:2, 3].tolist()})
    # Detections and predictions of the last sweep may trail its plan by a moment.
    deadline = time.monotonic() + 5.0
    while expect_objects and time.monotonic() < deadline and len(received["predictions"]) < count:
        rclpy.spin_once(node, timeout_sec=0.05)
    partial = output.with_suffix(".partial")
    partial.write_text(json.dumps({"sent": sent, **received}))
    os.replace(partial, output)
    node.destroy_node()
    rclpy.try_shutdown()


def _stamp(stamp: dict) -> int:
    return int(stamp["sec"]) * 1_000_000_000 + int(stamp["nanosec"])


if __name__ == "__main__":
    main()
