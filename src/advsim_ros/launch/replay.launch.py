"""`advsim replay` as a launch file, for full ROS 2 Jazzy installs (a colcon workspace, the docker image).

    ros2 launch advsim_ros replay.launch.py bag:=out/kitti/adversarial stack_profile:=my_stack.yaml \\
        check:=true runs:=3
    ros2 launch advsim_ros replay.launch.py --show-args   # every argument; defaults are the command's

It runs `advsim replay` as one process with the arguments as its options (outputs in `out`, default
BAG-replay). The launch fails (exit 1) when the command does, e.g. check:=true and a score that did
not reproduce. The arguments and the command line: advsim_ros.launch_files.
"""

from advsim_ros.launch_files import generate


def generate_launch_description():
    return generate("replay")
