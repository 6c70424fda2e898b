"""Test process: the example stack with topic names of its own, as third-party stacks have them.

It reads the LiDAR on /points_raw and odometry on /localization/odom and publishes its plan on
/my_planner/path; nothing in it knows the contract's names. run_own_names_stack.sh starts it the
way users' scripts often do: without passing any arguments on, so `--ros-args` cannot reach it.
"""

from advsim_ros.stacks.example import ExampleStack, run

LIDAR, ODOMETRY, PLAN = "/points_raw", "/localization/odom", "/my_planner/path"


class OwnNamesStack(ExampleStack):
    def __init__(self) -> None:
        super().__init__("own_names_stack", lidar_topic=LIDAR, odometry_topic=ODOMETRY, plan_topic=PLAN)


if __name__ == "__main__":
    run(OwnNamesStack)
