"""`advsim attack` as a launch file, for full ROS 2 Jazzy installs (a colcon workspace, the docker image).

    ros2 launch advsim_ros attack.launch.py bag:=logs/kitti_0000 out:=out/kitti \\
        stack_profile:=my_stack.yaml algo:=bo queries:=75
    ros2 launch advsim_ros attack.launch.py --show-args   # every argument; defaults are the command's

It runs the `advsim attack` orchestrator as one process with the arguments as its options, so the
graph (on a ROS_DOMAIN_ID of its own), the journal (the same launch again resumes) and the outputs
in `out` are the command's. Ctrl-C stops it as it stops the command. `remap` and `param` take
space-separated items: param:="perturber.num_candidates=20000 search.bo.initial_points=5".
The arguments and the command line: advsim_ros.launch_files.
"""

from advsim_ros.launch_files import generate


def generate_launch_description():
    return generate("attack")
