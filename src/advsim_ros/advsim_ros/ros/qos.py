"""QoS profiles of the attack graph's topics (see the topic table in README.md)."""

from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

# LiDAR as drivers publish it: best effort, volatile, shallow queue. A reliable subscriber would not match.
SENSOR = qos_profile_sensor_data

# The re-simulated LiDAR as lidar_resim offers it: reliable, volatile, shallow. A reliable offer matches
# both sensor-data (best-effort) subscribers, which is what stacks use, and reliable ones (the player's
# lock-step check, the recorder), so nothing the graph itself counts is lost to best-effort delivery.
LIDAR_OUT = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=5,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)

# Per-frame data every participant must see (odometry, plans, detections, logged sweeps for re-simulation).
STREAM = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)

# State published once per query or once per run; late joiners (a restarted stack, a recorder) still get it.
LATCHED = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)

# Episode phases and scores: a late joiner gets the recent history, not only the last message.
HISTORY = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)

# /clock as ROS publishes it.
CLOCK = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
