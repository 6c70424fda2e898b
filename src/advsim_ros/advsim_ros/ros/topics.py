"""Default topic names of the attack graph (README "The topic contract"); remap with --ros-args -r."""

# Inputs of the stack under test
LIDAR = "/sensor/lidar/points"  # re-simulated sweeps (sensor_msgs/PointCloud2)
ODOM = "/ego/odom"  # ego pose (nav_msgs/Odometry)
TF = "/tf"
TF_STATIC = "/tf_static"
CLOCK = "/clock"
MAP = "/map/road"  # advsim_msgs/RoadMap, as in scenario bags
SCENARIO_INFO = "/scenario/info"  # advsim_msgs/ScenarioInfo, as in scenario bags

# Outputs of the stack under test
PLAN = "/planning/trajectory"  # nav_msgs/Path
DETECTIONS = "/perception/detections"  # advsim_msgs/ActorTrackArray
PREDICTIONS = "/prediction/tracks"  # advsim_msgs/ActorTrackArray

# Internal to the attack graph
ORIGINAL_POINTS = "/advsim/original_points"  # logged sweeps on the sim clock, for lidar_resim
ACTOR_SELECTION = "/advsim/actor_selection"  # actors the search may move (logged tracks)
PERTURBATION = "/advsim/perturbation"
PERTURBED_TRACKS = "/advsim/perturbed_tracks"
EPISODE = "/advsim/episode"
DECISION_PLAN = "/advsim/decision_plan"  # the stack's plan of each query's decision frame, forwarded (latched)
SCORE = "/advsim/score"
