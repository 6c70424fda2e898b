"""Test process: an unrelated rclpy node that publishes plans on the stack's plan topic, as a stray process would.

It follows /clock (when it can hear it) and every 20 ms publishes a nav_msgs/Path stamped with the
latest sim time, 50 poses 100 m away from everything, so a plan of its own arrives for every
sweep the attack sends. Whether it reaches the attack depends only on the environment it is
started with (the attack's domain with or without the graph's transport profile). It prints one
line once it publishes and runs until SIGINT.
"""

from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path
from rclpy.node import Node
from rosgraph_msgs.msg import Clock

from advsim_ros.stacks.example import run

WORLD = "world"


class PlanInjector(Node):
    def __init__(self) -> None:
        super().__init__("plan_injector")
        self.plans = self.create_publisher(Path, "/planning/trajectory", 10)
        self.latest = Clock()
        self.create_subscription(Clock, "/clock", lambda message: setattr(self.latest, "clock", message.clock), 10)
        self.sent = 0
        self.create_timer(0.02, self.inject)

    def inject(self) -> None:
        path = Path()
        path.header.stamp, path.header.frame_id = self.latest.clock, WORLD
        for step in range(1, 51):
            item = PoseStamped()
            item.header.frame_id = WORLD
            item.pose.position.x, item.pose.position.y = 100.0 + step, 100.0
            path.poses.append(item)
        self.plans.publish(path)
        self.sent += 1
        if self.sent == 1:
            print("plan injector publishing", flush=True)


if __name__ == "__main__":
    run(PlanInjector)
