"""Test process: receive N messages of each given type on /exchange/<Name>, write them as JSON, exit.

Usage: receive_messages.py EXPECTED_JSON OUTPUT_JSON   (EXPECTED maps 'pkg/msg/Name' to a message count).
Exits 0 once everything arrived; the test bounds how long it may take.
"""

import json
import os
import sys
from pathlib import Path

import rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from advsim_ros.ros.messages import message_class, message_to_dict

LATCHED = QoSProfile(depth=16, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def main() -> None:
    expected: dict[str, int] = json.loads(Path(sys.argv[1]).read_text())
    output = Path(sys.argv[2])
    received: dict[str, list[dict]] = {type_name: [] for type_name in expected}
    rclpy.init()
    node = Node("exchange_receiver")
    for type_name in expected:
        message_type = message_class(type_name)

        def on_message(message, type_name=type_name):
            received[type_name].append(message_to_dict(message))

        node.create_subscription(message_type, f"/exchange/{message_type.__name__}", on_message, LATCHED)
    while not all(len(received[name]) >= count for name, count in expected.items()):
        rclpy.spin_once(node, timeout_sec=0.5)
    partial = output.with_suffix(".partial")
    partial.write_text(json.dumps(received))
    os.replace(partial, output)
    node.destroy_node()
    rclpy.try_shutdown()


if __name__ == "__main__":
    main()
