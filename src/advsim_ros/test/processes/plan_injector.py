"""Test process: an unrelated rclpy node that publishes plans on the stack's plan topic, as a stray process would.

It follows /clock (when it can hear it) and every 20 ms publishes a nav_msgs/Path stamped with the
latest sim time, 50 poses 100 m away from everything, so a plan of its own arrives for every
sweep the attack sends. Whether it reaches the attack depends only on the environment it is
started with (the attack's domain with or without the graph's transport profile). It prints one
line once it publishes and runs until SIGINT.
"""

import rclpy
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from rclpy.executors import ExternalShutdownException
from rosgraph_msgs.msg import Clock

WORLD = "world"


def main() -> None:
    rclpy.init()
    node = rclpy.create_node("plan_injector")
    publish = node.create_publisher(Path, "/planning/trajectory", 10).publish
    latest = Clock()
    node.create_subscription(Clock, "/clock", lambda message: setattr(latest, "clock", message.clock), 10)
    sent = [0]

    def inject() -> None:
        path = Path()
        path.header.stamp, path.header.frame_id = latest.clock, WORLD
        for step in range(1, 51):
            item = PoseStamped()
            item.header.frame_id = WORLD
            item.pose.position.x, item.pose.position.y = 100.0 + step, 100.0
            path.poses.append(item)
        publish(path)
        sent[0] += 1
        if sent[0] == 1:
            print("plan injector publishing", flush=True)

    node.create_timer(0.02, inject)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
