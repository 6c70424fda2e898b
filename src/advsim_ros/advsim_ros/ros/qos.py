"""The contract's QoS records (advsim_ros.contract.qos) as rclpy profiles."""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from advsim_ros.contract.qos import Durability, QosSpec, Reliability


def profile(spec: QosSpec) -> QoSProfile:
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=spec.depth,
        reliability=ReliabilityPolicy.RELIABLE
        if spec.reliability == Reliability.RELIABLE
        else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL
        if spec.durability == Durability.TRANSIENT_LOCAL
        else DurabilityPolicy.VOLATILE,
    )
