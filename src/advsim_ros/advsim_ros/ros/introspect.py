"""What the stack under test is on the ROS graph: its nodes, and each one's topics, types and QoS.

Read by the monitor when the stack connects (or does not): written to OUTDIR/run/stack_graph.json,
said in the connect-timeout message, and tabulated by `advsim doctor`.
"""

from __future__ import annotations

from typing import TypedDict

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy


class QosInfo(TypedDict):
    reliability: str  # "reliable" or "best_effort"
    durability: str  # "transient_local" or "volatile"
    depth: int


class Endpoint(TypedDict):
    topic: str
    type: str  # the first of the topic's types ("" when none)
    qos: QosInfo | None  # None when the node's own endpoint was not found


class StackNodeInfo(TypedDict):
    node: str  # namespace/name
    subscribes: list[Endpoint]
    publishes: list[Endpoint]


def _qos(profile: QoSProfile) -> QosInfo:
    reliability = "reliable" if profile.reliability == ReliabilityPolicy.RELIABLE else "best_effort"
    durability = "transient_local" if profile.durability == DurabilityPolicy.TRANSIENT_LOCAL else "volatile"
    return {"reliability": reliability, "durability": durability, "depth": int(profile.depth)}


def _endpoints(node: Node, name: str, namespace: str, publishers: bool) -> list[Endpoint]:
    by_node = node.get_publisher_names_and_types_by_node if publishers else node.get_subscriber_names_and_types_by_node
    found: list[Endpoint] = []
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


def stack_graph(node: Node, graph_nodes: frozenset[str]) -> list[StackNodeInfo]:
    """Every node on the domain that is not the attack graph's (``graph_nodes``), with what it subscribes to and
    publishes."""
    nodes: list[StackNodeInfo] = []
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


def describe(graph: list[StackNodeInfo]) -> str:
    """One line: what each of the stack's nodes subscribes to and publishes."""
    if not graph:
        return "no node of the stack is on the ROS graph"
    return "; ".join(
        f"node {entry['node']} subscribes {[e['topic'] for e in entry['subscribes']] or 'nothing'}, "
        f"publishes {[e['topic'] for e in entry['publishes']] or 'nothing'}"
        for entry in graph
    )
