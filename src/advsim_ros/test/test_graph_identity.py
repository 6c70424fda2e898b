"""Fast DDS, as the wheels ship it, writes the pid of the process that made an endpoint into the endpoint's GID.

ros.identity ties the publishers on a stack's topics to the attack's processes by it; this checks
the assumption against the real library (rclpy over rmw_fastrtps_cpp).
"""

from __future__ import annotations

import subprocess
import sys

from advsim_ros.ros.identity import endpoint_pid_bits
from advsim_ros.ros.launcher import graph_environment, reserve_domain_id


def test_fast_dds_writes_the_pid_of_the_process_that_made_an_endpoint_into_its_gid() -> None:
    script = (
        "import os, rclpy\n"
        "from std_msgs.msg import String\n"
        "rclpy.init()\n"
        "node = rclpy.create_node('gid_probe')\n"
        "node.create_publisher(String, '/gid_probe', 1)\n"
        "(info,) = node.get_publishers_info_by_topic('/gid_probe')\n"
        "print(os.getpid(), ' '.join(str(b) for b in info.endpoint_gid))\n"
    )
    with reserve_domain_id() as lease:
        env = graph_environment(lease.domain_id)
        done = subprocess.run(
            [sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=60, check=True
        )
    pid, gid = done.stdout.split(maxsplit=1)
    assert endpoint_pid_bits([int(byte) for byte in gid.split()]) == int(pid) & 0xFFFF
