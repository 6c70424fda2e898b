"""advsim_ros: AdvSim (Wang et al., CVPR 2021) as a ROS 2 Jazzy node graph."""

__version__ = "0.1.0"
