"""The QoS profiles of the topic contract as plain records.

``advsim_ros.ros.qos`` renders them to rclpy profiles for the graph's publishers and
subscriptions; the bag writer renders them to the offered-QoS metadata of each recorded
topic, so ``ros2 bag play`` republishes a scenario the way the attack graph publishes it.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum


class Reliability(StrEnum):
    RELIABLE = "reliable"
    BEST_EFFORT = "best_effort"


class Durability(StrEnum):
    VOLATILE = "volatile"
    TRANSIENT_LOCAL = "transient_local"


@dataclass(frozen=True)
class QosSpec:
    """History KEEP_LAST of ``depth`` messages, with this reliability and durability."""

    reliability: Reliability
    durability: Durability
    depth: int


# LiDAR as drivers publish it and stacks subscribe to it: best effort, volatile, shallow.
SENSOR_DATA = QosSpec(Reliability.BEST_EFFORT, Durability.VOLATILE, 5)
# The re-simulated LiDAR as lidar_resim offers it: a reliable offer matches both sensor-data
# (best-effort) subscribers, which is what stacks use, and reliable ones (the player's lock-step
# check, the recorder), so nothing the graph itself counts is lost to best-effort delivery.
LIDAR = QosSpec(Reliability.RELIABLE, Durability.VOLATILE, 5)
# Per-frame data every participant must see (odometry, plans, detections, frame requests).
STREAM = QosSpec(Reliability.RELIABLE, Durability.VOLATILE, 10)
# /tf as tf2's broadcaster publishes it.
TF = QosSpec(Reliability.RELIABLE, Durability.VOLATILE, 100)
# State published once per query or per run; late joiners (a restarted stack, a recorder) still get it.
LATCHED = QosSpec(Reliability.RELIABLE, Durability.TRANSIENT_LOCAL, 1)
# What happens to each query (its perturbation, perturbed tracks, episode phases and score): the writers
# keep a whole attack's worth, so a reader that stalls for a while (the attack's monitor in a starved or
# suspended process) is sent what it missed instead of losing queries; a late joiner gets the history.
HISTORY = QosSpec(Reliability.RELIABLE, Durability.TRANSIENT_LOCAL, 5000)
# /clock as ROS publishes it.
CLOCK = QosSpec(Reliability.RELIABLE, Durability.VOLATILE, 1)
