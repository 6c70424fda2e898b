"""Test process: the example stack with faults, each happening once per marker file.

`crash_at_sweep` makes the process exit with code 3 at that sweep (a hard crash),
`hang_at_sweep` makes it stop answering for `hang_seconds` (stuck in its own computation).
"""

import os
import time
from pathlib import Path

from sensor_msgs.msg import PointCloud2

from advsim_ros.stacks.example import ExampleStack, run


class FaultyStack(ExampleStack):
    def __init__(self) -> None:
        super().__init__("simple_stack")
        self.crash_at = self.declare_parameter("crash_at_sweep", -1).value
        self.hang_at = self.declare_parameter("hang_at_sweep", -1).value
        self.hang_seconds = self.declare_parameter("hang_seconds", 30.0).value
        self.marker_dir = Path(self.declare_parameter("marker_dir", "/tmp").value)

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


if __name__ == "__main__":
    run(FaultyStack)
