"""Test process: publish messages given as JSON on /exchange/<Name> (transient local), until interrupted.

Usage: publish_messages.py MESSAGES_JSON   where the JSON maps 'pkg/msg/Name' to a list of message dicts.
"""

import json
import sys
from pathlib import Path

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from advsim_ros.ros.messages import dict_to_message, message_class

LATCHED = QoSProfile(depth=16, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def main() -> None:
    batches = json.loads(Path(sys.argv[1]).read_text())
    rclpy.init()
    node = Node("exchange_publisher")
    publishers = []
    for type_name, samples in batches.items():
        message_type = message_class(type_name)
        publisher = node.create_publisher(message_type, f"/exchange/{message_type.__name__}", LATCHED)
        for sample in samples:
            publisher.publish(dict_to_message(message_type, sample))
        publishers.append(publisher)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
