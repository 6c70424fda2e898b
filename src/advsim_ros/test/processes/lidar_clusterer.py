"""Test process: a LiDAR clustering node as a third party writes one (plain rclpy, sensor_msgs_py, started by path).

It reads the sweeps on /velodyne_points with ``sensor_msgs_py.point_cloud2.read_points_numpy`` (the
module ROS installs have and the ROS 2 wheels lack), groups the returns in the corridor ahead of the
sensor into 1 m cells, and publishes on /clusterer/blocked whether an object-sized cluster blocks it
(std_msgs/Bool). route_planner.py stops for it. It knows nothing of advsim.
"""

import numpy as np
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import PointCloud2
from sensor_msgs_py import point_cloud2
from std_msgs.msg import Bool

MIN_CLUSTER = 30  # returns in a cell and its neighbours that make an object


class LidarClusterer(Node):
    def __init__(self) -> None:
        super().__init__("lidar_clusterer")
        self.sweeps = 0
        self.publisher = self.create_publisher(Bool, "/clusterer/blocked", 10)
        self.create_subscription(PointCloud2, "/velodyne_points", self.on_sweep, qos_profile_sensor_data)

    def on_sweep(self, cloud: PointCloud2) -> None:
        xyz = point_cloud2.read_points_numpy(cloud, field_names=("x", "y", "z"), skip_nans=True)
        ahead = xyz[(xyz[:, 0] > 2.0) & (xyz[:, 0] < 20.0) & (np.abs(xyz[:, 1]) < 1.5) & (xyz[:, 2] > -1.2)]
        cells = np.floor(ahead[:, :2]).astype(np.int64)
        keys, counts = np.unique(cells[:, 0], return_counts=True)  # 1 m slices along the corridor
        # a cluster: consecutive slices holding returns, summed
        blocked = any(counts[max(0, i - 1) : i + 2].sum() > MIN_CLUSTER for i in range(len(keys)))
        self.publisher.publish(Bool(data=bool(blocked)))
        self.sweeps += 1
        if self.sweeps == 1:
            self.get_logger().info(f"first sweep: {len(xyz)} points read with sensor_msgs_py, blocked {blocked}")


def main() -> None:
    rclpy.init()
    node = LidarClusterer()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
