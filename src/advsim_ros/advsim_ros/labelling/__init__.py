"""Auto-labelling of unlabelled LiDAR logs (pure Python, no rclpy): detection, offline tracking, gates.

Modules: ``config`` (``LabellingConfig``, params/labelling.yaml), ``detection`` (per-sweep
candidate boxes), ``tracking`` (offline multi-object tracking with a Rauch-Tung-Striebel
smoother), ``refine`` (size, heading, class, confidence and quality gates per track),
``pipeline`` (``label_scenario``), ``odometry`` (KISS-ICP ego poses), ``perception``
(tracks taken from a perception topic of the bag), ``evaluation`` (scores against labels).
"""
