"""The topic contract, defined once: what travels between the attack graph, the stack and the bags.

Nothing here imports rclpy: the ROS layer (``advsim_ros.ros``) and the bag layer
(``advsim_ros.io.bag``) both build and parse messages through these modules, so a message a
node publishes is byte for byte what a bag records.

- ``names``    message type names
- ``qos``      the QoS profiles as plain records (rendered to rclpy profiles and to bag metadata)
- ``topics``   every topic: default name, type and QoS (the README's topic table)
- ``enums``    episode phases and outcomes, query statuses
- ``codec``    the typestore (ROS 2 Jazzy + advsim_msgs + Autoware), CDR encode/decode, stamps and headers
- ``spatial``  poses, transforms, odometry, TF
- ``scenario`` scenario messages: PointCloud2, RoadMap, ScenarioInfo, drivable-area grid
- ``tracks``   ActorTrack / ActorTrackArray
- ``plan``     nav_msgs/Path <-> Plan
- ``protocol`` the attack protocol: Perturbation, ActorSelection, FrameRequest, Episode, QueryScore
"""
