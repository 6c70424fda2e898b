"""What every node of the attack graph shares: raw CDR topics, the window and scenario, the main loop."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile

from advsim_ros.core.episode import EpisodeClock, WindowConfig
from advsim_ros.core.types import Scenario, ScenarioError
from advsim_ros.io.bag import BagConfig, read_scenario_bag
from advsim_ros.ros.messages import message_class
from advsim_ros.ros.params import declare_config
from advsim_ros.ros.wire import Wire


class GraphNode(Node):
    """A node that speaks CDR through the shared Wire and knows the attack's window."""

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.wire = Wire()
        self.window = declare_config(self, WindowConfig, "window.")
        self.bag_config = declare_config(self, BagConfig, "bag.")

    def raw_publisher(self, type_name: str, topic: str, qos: QoSProfile) -> Callable[[Any], None]:
        """A publish function taking a rosbags message object or ready CDR bytes."""
        publisher = self.create_publisher(message_class(type_name), topic, qos)

        def publish(message: Any) -> None:
            publisher.publish(message if isinstance(message, bytes) else self.wire.encode(message))

        return publish

    def raw_subscription(
        self, type_name: str, topic: str, qos: QoSProfile, callback: Callable[[Any], None], *, decode: bool = True
    ) -> None:
        """Subscribe; the callback gets the decoded rosbags message (or the CDR bytes with decode=False)."""

        def on_message(raw: bytes) -> None:
            callback(self.wire.decode(raw, type_name) if decode else raw)

        self.create_subscription(message_class(type_name), topic, on_message, qos, raw=True)

    def load_scenario(self, *, load_sweeps: bool) -> tuple[Scenario, EpisodeClock]:
        """The window's scenario from the bag, and the episode clock all nodes share."""
        if not self.window.scenario_bag:
            raise ScenarioError(f"/{self.get_name()}: parameter window.scenario_bag is not set")
        scenario = read_scenario_bag(Path(self.window.scenario_bag), config=self.bag_config, load_sweeps=load_sweeps)
        return scenario, self.window.clock(scenario.frame_stamps_ns.tolist())


def run_node(factory: Callable[[], Node], *, threads: int = 2) -> None:
    """Create the node and spin it until SIGINT/SIGTERM; a start-up error exits 1 with its message."""
    rclpy.init()
    node: Node | None = None
    exit_code = 0
    try:
        node = factory()
        executor = MultiThreadedExecutor(num_threads=threads)
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ScenarioError, OSError) as error:
        print(f"{sys.argv[0]}: error: {error}", file=sys.stderr)
        exit_code = 1
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    if exit_code:
        sys.exit(exit_code)
