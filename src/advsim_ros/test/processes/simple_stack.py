"""Test process: the example stack with faults, each happening once per marker file.

`crash_at_sweep` makes the process exit with code 3 at that sweep (a hard crash),
`hang_at_sweep` makes it stop answering for `hang_seconds` (stuck in its own computation).
`flaky_probability` makes it plan from a randomly wrong speed that often (an unseeded,
non-deterministic stack, as users' stacks can be).
"""

import os
import random
import time
from pathlib import Path

from nav_msgs.msg import Odometry
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
        super().plan(cloud, odometry)


if __name__ == "__main__":
    run(FaultyStack)
