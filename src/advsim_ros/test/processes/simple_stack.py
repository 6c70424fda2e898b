"""Test process: the example stack with faults, each happening once per marker file.

`crash_at_sweep` makes the process exit with code 3 at that sweep (a hard crash),
`hang_at_sweep` makes it stop answering for `hang_seconds` (stuck in its own computation).
`flaky_probability` makes it plan from a randomly wrong speed that often (an unseeded,
non-deterministic stack, as users' stacks can be).
`wrong_first_sweeps` makes it plan from a wrong speed for the first that many sweeps of its life (a
stack whose start-up is late, as one whose first inputs arrive stale: its first query differs).
`crash_after_plans` makes every run of it exit with code 3 after that many plans (a stack that
keeps crashing, however often it is restarted); `plans` makes its plans unusable: `none` (it
never publishes one), `nan_poses` (NaN positions), `empty` (no poses), `frame` (in a frame of its own).
`escape_seconds` > 0 starts a `sleep` of that many seconds in a session of its own, as a stack's
daemon would: it must not outlive the attack.
"""

import math
import os
import random
import subprocess
import time
from pathlib import Path

from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from sensor_msgs.msg import PointCloud2

from advsim_ros.stacks.example import ExampleStack, run


class FaultyStack(ExampleStack):
    def __init__(self) -> None:
        super().__init__("simple_stack")
        self.crash_at = self.declare_parameter("crash_at_sweep", -1).value
        self.hang_at = self.declare_parameter("hang_at_sweep", -1).value
        self.hang_seconds = self.declare_parameter("hang_seconds", 30.0).value
        self.marker_dir = Path(self.declare_parameter("marker_dir", "/tmp").value)
        self.flaky_probability = self.declare_parameter("flaky_probability", 0.0).value
        self.noise = random.Random()  # deliberately unseeded: the point is to be non-deterministic
        self.wrong_first = self.declare_parameter("wrong_first_sweeps", 0).value
        self.crash_after = self.declare_parameter("crash_after_plans", -1).value
        self.plans = self.declare_parameter("plans", "normal").value
        self.published = 0
        escape = self.declare_parameter("escape_seconds", 0.0).value
        if escape > 0:
            subprocess.Popen(["sleep", str(escape)], start_new_session=True)  # as a stack starts a daemon

    def _fault_once(self, name: str) -> bool:
        marker = self.marker_dir / f"{name}.done"
        if marker.exists():
            return False
        marker.write_text("done")
        return True

    def on_sweep(self, cloud: PointCloud2) -> None:
        if self.sweeps + 1 == self.crash_at and self._fault_once("crash"):
            os._exit(3)
        if self.sweeps + 1 == self.hang_at and self._fault_once("hang"):
            time.sleep(self.hang_seconds)
        super().on_sweep(cloud)

    def plan(self, cloud: PointCloud2, odometry: Odometry) -> None:
        if self.noise.random() < self.flaky_probability:
            odometry.twist.twist.linear.x *= self.noise.uniform(0.5, 1.5)
        if self.sweeps <= self.wrong_first:
            odometry.twist.twist.linear.x *= 0.5
        if self.plans == "none":
            return
        if self.plans == "frame":
            odometry.header.frame_id = "stack_frame"  # the example stack plans in the odometry's frame
        if self.plans in ("normal", "frame"):
            super().plan(cloud, odometry)
        else:
            path = PathMsg(header=cloud.header)  # poses unstamped: 0.1 s apart after the header, by the contract
            path.header.frame_id = odometry.header.frame_id
            if self.plans == "nan_poses":
                path.poses = [PoseStamped() for _ in range(50)]
                for item in path.poses:
                    item.pose.position.x = math.nan
            self.plan_publisher.publish(path)
        self.published += 1
        if self.published == self.crash_after:
            os._exit(3)


if __name__ == "__main__":
    run(FaultyStack)
