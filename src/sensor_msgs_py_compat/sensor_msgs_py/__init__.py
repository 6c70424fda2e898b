"""sensor_msgs_py for the ROS 2 wheels: the point-cloud helpers of advsim_ros.ros.point_cloud2 (see there)."""
