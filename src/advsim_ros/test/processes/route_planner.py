"""Test process: a GNSS route planner as a third party writes one (plain rclpy, started by path).

Its route is a GeoJSON LineString of longitude,latitude waypoints in its working directory
($ROUTE_FILE, default route.geojson), as `advsim export route ... -o route.geojson` writes one. It
localises from sensor_msgs/NavSatFix on /gps/fix and, on a 10 Hz timer of the sim clock, publishes
a spatial nav_msgs/Path (positions only) along the route from the waypoint nearest to it, 60 m
ahead or 6 m when lidar_clusterer.py says the corridor is blocked, in an east-north-up `map` frame
anchored at its first fix. A route it cannot read is logged and it never plans, as the user's
planner did when started from another folder.
"""

import json
import math
import os

import numpy as np
import pymap3d
import rclpy
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path as PathMsg
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from sensor_msgs.msg import NavSatFix
from std_msgs.msg import Bool


class RoutePlanner(Node):
    def __init__(self) -> None:
        super().__init__("route_planner")
        self.origin: tuple[float, float, float] | None = None  # the first fix
        self.position: tuple[float, float] | None = None  # in `map` [m]
        self.route: np.ndarray | None = None  # (N, 2) east, north in `map` [m]
        self.failed = False
        self.blocked = False
        self.publisher = self.create_publisher(PathMsg, "/route_planner/path", 10)
        self.create_subscription(NavSatFix, "/gps/fix", self.on_fix, 10)
        self.create_subscription(Bool, "/clusterer/blocked", self.on_blocked, 10)
        self.create_timer(0.1, self.on_timer)

    def on_fix(self, fix: NavSatFix) -> None:
        if self.origin is None:
            self.origin = (fix.latitude, fix.longitude, fix.altitude)
        east, north, _ = pymap3d.geodetic2enu(fix.latitude, fix.longitude, fix.altitude, *self.origin)
        self.position = (float(east), float(north))

    def on_blocked(self, message: Bool) -> None:
        self.blocked = message.data

    def load_route(self) -> None:
        name = os.environ.get("ROUTE_FILE", "route.geojson")
        try:
            with open(name) as file:
                line = next(f for f in json.load(file)["features"] if f["geometry"]["type"] == "LineString")
            waypoints = [(float(lat), float(lon)) for lon, lat in line["geometry"]["coordinates"]]
        except (OSError, ValueError, KeyError, StopIteration) as error:
            self.failed = True
            self.get_logger().error(f"cannot read the route {name} in {os.getcwd()}: {error!r}")
            return
        assert self.origin is not None
        east, north, _ = pymap3d.geodetic2enu(*np.array(waypoints).T, self.origin[2], *self.origin)
        self.route = np.column_stack([east, north])
        self.get_logger().info(f"route {name}: {len(waypoints)} waypoints")

    def on_timer(self) -> None:
        if self.position is None or self.failed:
            return
        if self.route is None:
            self.load_route()
            if self.route is None:
                return
        nearest = int(np.argmin(np.hypot(*(self.route - self.position).T)))
        reach, travelled = (6.0 if self.blocked else 60.0), 0.0
        points = [self.position]
        for waypoint in self.route[nearest + 1 :]:
            travelled += math.dist(points[-1], waypoint)
            points.append((float(waypoint[0]), float(waypoint[1])))
            if travelled >= reach:
                break
        path = PathMsg()
        path.header.stamp, path.header.frame_id = self.get_clock().now().to_msg(), "map"
        for x, y in points:
            pose = PoseStamped()
            pose.header.frame_id = "map"
            pose.pose.position.x, pose.pose.position.y = x, y
            path.poses.append(pose)
        self.publisher.publish(path)


def main() -> None:
    rclpy.init()
    node = RoutePlanner()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
