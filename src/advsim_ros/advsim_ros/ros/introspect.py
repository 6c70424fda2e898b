"""What the stack under test is on the ROS graph: its nodes, and each one's topics, types and QoS.

Read by the monitor when the stack connects (or does not): written to OUTDIR/run/stack_graph.json,
said in the connect-timeout message, and tabulated by `advsim doctor`.
"""

from __future__ import annotations

from typing import Any

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, ReliabilityPolicy


def _qos(profile: Any) -> dict[str, Any]:
    reliability = "reliable" if profile.reliability == ReliabilityPolicy.RELIABLE else "best_effort"
    durability = "transient_local" if profile.durability == DurabilityPolicy.TRANSIENT_LOCAL else "volatile"
    return {"reliability": reliability, "durability": durability, "depth": int(profile.depth)}


def _endpoints(node: Node, name: str, namespace: str, publishers: bool) -> list[dict[str, Any]]:
    by_node = node.get_publisher_names_and_types_by_node if publishers else node.get_subscriber_names_and_types_by_node
    found = []
    for topic, types in sorted(by_node(name, namespace)):
        infos = node.get_publishers_info_by_topic(topic) if publishers else node.get_subscriptions_info_by_topic(topic)
        mine = [info for info in infos if info.node_name == name and info.node_namespace == namespace]
        found.append(
            {
                "topic": topic,
                "type": types[0] if types else "",
                "qos": _qos(mine[0].qos_profile) if mine else None,
            }
        )
    return found


def stack_graph(node: Node, graph_nodes: frozenset[str]) -> list[dict[str, Any]]:
    """Every node on the domain that is not the attack graph's (``graph_nodes``), with what it subscribes to and
    publishes."""
    nodes = []
    for name, namespace in sorted(node.get_node_names_and_namespaces()):
        if name in graph_nodes:
            continue
        nodes.append(
            {
                "node": f"{namespace.rstrip('/')}/{name}",
                "subscribes": _endpoints(node, name, namespace, publishers=False),
                "publishes": _endpoints(node, name, namespace, publishers=True),
            }
        )
    return nodes


def describe(graph: list[dict[str, Any]]) -> str:
    """One line: what each of the stack's nodes subscribes to and publishes."""
    if not graph:
        return "no node of the stack is on the ROS graph"
    return "; ".join(
        f"node {entry['node']} subscribes {[e['topic'] for e in entry['subscribes']] or 'nothing'}, "
        f"publishes {[e['topic'] for e in entry['publishes']] or 'nothing'}"
        for entry in graph
    )
