#!/usr/bin/env bash
# Source ROS and the workspace, then run the given command (default: the demo).
set -e
# shellcheck disable=SC1091
source /opt/ros/jazzy/setup.bash
# shellcheck disable=SC1091
source /ws/install/setup.bash
exec "$@"
